#include "svo/store/view_stream.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <optional>

#include <nlohmann/json.hpp>

namespace svo::stream {
namespace {

using nlohmann::json;

[[noreturn]] void fail(const std::string& what) {
  throw ProtocolError(what);
}

const json& field(const json& message, const char* name) {
  const auto it = message.find(name);
  if (it == message.end()) fail(std::string("no \"") + name + "\" field");
  return *it;
}

double finiteNumber(const json& value, const std::string& name) {
  if (!value.is_number()) fail(name + ": not a number");
  const double x = value.get<double>();
  if (!std::isfinite(x)) fail(name + ": not finite");
  return x;
}

double numberIn(const json& message, const char* name, double lowest, double highest) {
  const double x = finiteNumber(field(message, name), name);
  if (!(x >= lowest && x <= highest))
    fail(std::string(name) + ": " + std::to_string(x) + " is outside [" + std::to_string(lowest) + ", " +
         std::to_string(highest) + "]");
  return x;
}

std::uint64_t unsignedField(const json& message, const char* name) {
  const json& value = field(message, name);
  if (!value.is_number_unsigned()) fail(std::string(name) + ": not a non-negative integer");
  return value.get<std::uint64_t>();
}

std::vector<std::uint32_t> sliceIds(const json& value, const char* name, std::size_t sliceCount) {
  if (!value.is_array()) fail(std::string(name) + ": not an array");
  if (value.size() > sliceCount) fail(std::string(name) + ": more ids than the store has slices");
  std::vector<std::uint32_t> ids;
  ids.reserve(value.size());
  for (const json& id : value) {
    if (!id.is_number_unsigned() || id.get<std::uint64_t>() >= sliceCount)
      fail(std::string(name) + ": " + id.dump() + " is not a slice of this store (it has " +
           std::to_string(sliceCount) + ")");
    ids.push_back(std::uint32_t(id.get<std::uint64_t>()));
  }
  return ids;
}

json parseObject(std::string_view text) {
  json message = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (message.is_discarded()) fail("not JSON");
  if (!message.is_object()) fail("not a JSON object");
  return message;
}

ViewQuery query(const json& message) {
  ViewQuery q;
  const json& eye = field(message, "eye");
  if (!eye.is_array() || eye.size() != 3) fail("eye: not an array of 3 numbers");
  for (int a = 0; a < 3; ++a) {
    q.eye[a] = finiteNumber(eye[a], "eye");
    if (std::abs(q.eye[a]) > kMaxEyeCoordinate) fail("eye: farther than 1e12 from the scene");
  }
  // Pixel angles of a real camera lie far inside these: a pixel is less than the whole sphere of view.
  q.pixelAngle = numberIn(message, "pixelAngle", 1e-12, std::numbers::pi);
  q.lodPixels = numberIn(message, "lodPixels", 0.0, 1e9);  // 0: the finest level everywhere
  q.outsideWeight = numberIn(message, "outsideWeight", 0.0, 1.0);
  const json& frustum = field(message, "frustum");
  if (!frustum.is_array()) fail("frustum: not an array");
  if (frustum.size() > kMaxFrustumPlanes)
    fail("frustum: more than " + std::to_string(kMaxFrustumPlanes) + " planes");
  for (const json& plane : frustum) {
    if (!plane.is_array() || plane.size() != 4) fail("frustum: a plane is not 4 numbers");
    std::array<double, 4> p{};
    for (int k = 0; k < 4; ++k) p[k] = finiteNumber(plane[k], "frustum");
    q.frustum.push_back(p);
  }
  return q;
}

std::uint32_t readLe32(const std::byte* p) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | std::uint32_t(p[i]);
  return v;
}

}  // namespace

std::size_t maxClientMessageBytes(std::size_t sliceCount) {
  return kViewFixedBytes + 2 * kViewBytesPerHeldSlice * sliceCount;
}

std::string encodeView(const View& view) {
  json frustum = json::array();
  for (const auto& p : view.query.frustum) frustum.push_back({p[0], p[1], p[2], p[3]});
  const json message = {{"view", view.id},
                        {"eye", {view.query.eye.x, view.query.eye.y, view.query.eye.z}},
                        {"pixelAngle", view.query.pixelAngle},
                        {"lodPixels", view.query.lodPixels},
                        {"frustum", frustum},
                        {"outsideWeight", view.query.outsideWeight},
                        {"budget", view.budgetBytes},
                        {"held", view.held},
                        {"first", view.first}};
  return message.dump();
}

std::string encodeAck(std::uint64_t receivedBytes) {
  return json{{"ack", receivedBytes}}.dump();
}

std::string encodeWant(std::span<const std::uint32_t> slices) {
  return json{{"want", std::vector<std::uint32_t>(slices.begin(), slices.end())}}.dump();
}

ClientMessage parseClientMessage(std::string_view text, std::size_t sliceCount) {
  if (text.size() > maxClientMessageBytes(sliceCount)) fail("message too large");
  const json message = parseObject(text);
  ClientMessage m;
  if (message.contains("ack")) {
    m.kind = ClientMessage::Kind::Ack;
    m.ackedBytes = unsignedField(message, "ack");
    return m;
  }
  if (message.contains("want")) {
    m.kind = ClientMessage::Kind::Want;
    m.wanted = sliceIds(message["want"], "want", sliceCount);
    return m;
  }
  m.view.id = unsignedField(message, "view");
  m.view.query = query(message);
  m.view.budgetBytes = unsignedField(message, "budget");
  if (m.view.budgetBytes == 0 || m.view.budgetBytes > kMaxBudgetBytes)
    fail("budget: " + std::to_string(m.view.budgetBytes) + " bytes is not in [1, 2^40]");
  if (message.contains("held")) m.view.held = sliceIds(message["held"], "held", sliceCount);
  if (message.contains("first")) m.view.first = sliceIds(message["first"], "first", sliceCount);
  return m;
}

std::vector<std::uint32_t> planSlices(const StoreIndex& index, const ViewQuery& query, std::uint64_t budgetBytes) {
  const std::vector<SliceInfo>& slices = index.slices();
  std::vector<std::uint32_t> wanted;
  std::uint64_t decoded = 0;
  for (const SliceRequest& r : scheduleSlices(index, query)) {
    decoded += slices[r.slice].rawBytes;
    if (decoded > budgetBytes) break;
    wanted.push_back(r.slice);
  }
  std::vector<bool> inPlan(slices.size(), false), placed(slices.size(), false);
  for (const std::uint32_t s : wanted) inPlan[s] = true;
  // The next slice of the same cube (the chain a client loads as one request), when planned.
  const auto chainNext = [&](std::uint32_t s) -> std::optional<std::uint32_t> {
    for (const std::uint32_t c : index.childSlices(s)) {
      const SliceInfo &a = slices[s], &b = slices[c];
      if (b.cubeLevel == a.cubeLevel && b.cubeCoord == a.cubeCoord && b.firstSlot == a.firstSlot &&
          b.lastSlot == a.lastSlot)
        return inPlan[c] ? std::optional<std::uint32_t>(c) : std::nullopt;
    }
    return std::nullopt;
  };
  std::vector<std::uint32_t> plan;
  plan.reserve(wanted.size());
  for (const std::uint32_t head : wanted) {
    for (std::optional<std::uint32_t> s = head; s && !placed[*s]; s = chainNext(*s)) {
      placed[*s] = true;
      plan.push_back(*s);
    }
  }
  return plan;
}

std::string encodePlan(std::uint64_t view, std::span<const std::uint32_t> plan) {
  return json{{"view", view}, {"plan", std::vector<std::uint32_t>(plan.begin(), plan.end())}}.dump();
}

std::string encodeSliceError(std::uint64_t view, std::uint32_t slice, std::string_view error) {
  return json{{"view", view}, {"slice", slice}, {"error", error}}.dump();
}

ServerMessage parseServerMessage(std::string_view text, std::size_t sliceCount) {
  const json message = parseObject(text);
  ServerMessage m;
  m.view = unsignedField(message, "view");
  if (message.contains("plan")) {
    m.plan = sliceIds(message["plan"], "plan", sliceCount);
    return m;
  }
  m.kind = ServerMessage::Kind::SliceError;
  const std::uint64_t slice = unsignedField(message, "slice");
  if (slice >= sliceCount) fail("slice: not a slice of this store");
  m.slice = std::uint32_t(slice);
  const json& error = field(message, "error");
  if (!error.is_string()) fail("error: not a string");
  m.error = error.get<std::string>();
  return m;
}

void writeSliceFrameHeader(const SliceFrameHeader& header, std::span<std::byte, kSliceFrameHeaderBytes> out) {
  const std::uint64_t words[2] = {kSliceFrameMagic | (std::uint64_t(header.slice) << 32), header.view};
  for (int w = 0; w < 2; ++w)
    for (int i = 0; i < 8; ++i) out[w * 8 + i] = std::byte((words[w] >> (8 * i)) & 0xFF);
}

SliceFrameHeader readSliceFrameHeader(std::span<const std::byte> frame) {
  if (frame.size() < kSliceFrameHeaderBytes) fail("a slice frame shorter than its 16-byte header");
  if (readLe32(frame.data()) != kSliceFrameMagic) fail("a binary frame that is not a slice frame");
  SliceFrameHeader h;
  h.slice = readLe32(frame.data() + 4);
  h.view = std::uint64_t(readLe32(frame.data() + 8)) | (std::uint64_t(readLe32(frame.data() + 12)) << 32);
  return h;
}

}  // namespace svo::stream
