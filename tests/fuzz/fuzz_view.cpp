// libFuzzer target over the view stream's message parsers (store/include/svo/store/view_stream.hpp): the
// client's views, acknowledgements and wants as the server reads them, the server's plans and slice errors and the
// slice frame's head as the client reads them. Any bytes must give a message that keeps the parsers'
// promises or a ProtocolError, never another exception, a crash, a hang or a sanitizer report.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <span>
#include <string_view>

#include "svo/store/view_stream.hpp"

namespace {

using namespace svo::stream;

// A store of this many slices: ids at or above it must be refused.
constexpr std::size_t kSliceCount = 100;

void check(bool promise) {
  if (!promise) std::abort();
}

void fuzzClient(std::string_view text) {
  try {
    const ClientMessage m = parseClientMessage(text, kSliceCount);
    if (m.kind == ClientMessage::Kind::Ack) return;
    if (m.kind == ClientMessage::Kind::Want) {
      for (const std::uint32_t id : m.wanted) check(id < kSliceCount);
      return;
    }
    const svo::ViewQuery& q = m.view.query;
    for (int a = 0; a < 3; ++a) check(std::isfinite(q.eye[a]) && std::abs(q.eye[a]) <= kMaxEyeCoordinate);
    check(q.pixelAngle > 0.0 && q.lodPixels >= 0.0 && q.outsideWeight >= 0.0 && q.outsideWeight <= 1.0);
    check(q.frustum.size() <= kMaxFrustumPlanes);
    check(m.view.budgetBytes >= 1 && m.view.budgetBytes <= kMaxBudgetBytes);
    for (const std::uint32_t id : m.view.held) check(id < kSliceCount);
    // What the client encodes, the server reads back the same.
    const ClientMessage again = parseClientMessage(encodeView(m.view), kSliceCount);
    check(again.view.id == m.view.id && again.view.held == m.view.held && again.view.query.eye == q.eye);
  } catch (const ProtocolError&) {
  }
}

void fuzzServer(std::string_view text) {
  try {
    const ServerMessage m = parseServerMessage(text, kSliceCount);
    for (const std::uint32_t id : m.plan) check(id < kSliceCount);
    if (m.kind == ServerMessage::Kind::SliceError) check(m.slice < kSliceCount);
  } catch (const ProtocolError&) {
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  fuzzClient(text);
  fuzzServer(text);
  try {
    const auto* bytes = reinterpret_cast<const std::byte*>(data);
    const SliceFrameHeader h = readSliceFrameHeader(std::span(bytes, size));
    std::array<std::byte, kSliceFrameHeaderBytes> out{};
    writeSliceFrameHeader(h, out);
    check(std::equal(out.begin(), out.end(), bytes));
  } catch (const ProtocolError&) {
  }
  return 0;
}
