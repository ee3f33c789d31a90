// The view-driven stream's messages (docs/architecture.md, "The view stream"): a client opens a WebSocket to
// svo serve's /NAME/stream and sends its view; the server runs scheduleSlices for it and pushes the slices it
// plans, most valuable first, as stored (compressed, checked by the client against its own directory). A
// newer view supersedes the older one's plan. Shared by the server and the client, so both speak one format;
// pure functions over bytes, so the fuzz target (tests/fuzz/fuzz_view.cpp) runs them on anything.
//
//   client -> server, text:
//   {"view":N,"eye":[x,y,z],"pixelAngle":a,"lodPixels":p,"frustum":[[nx,ny,nz,d],...],
//                              "outsideWeight":w,"budget":bytes,"held":[ids],"first":[ids]}  a view (N grows)
//                             {"ack":bytes}           slice bytes received so far (the server's send window)
//                             {"want":[ids]}          slices a fetch waits for: sent next (the pager's own order,
//                                                     ray feedback included, goes before the server's plan)
//   server -> client, text:   {"view":N,"plan":[ids]}  what the server sends for view N, in order
//                             {"view":N,"slice":id,"error":"..."}   a planned slice it cannot send
//   server -> client, binary: a 16-byte SliceFrameHeader, then the slice's compressed bytes as stored
#pragma once

#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "svo/store/schedule.hpp"
#include "svo/store/store_index.hpp"

namespace svo::stream {

// A message that does not follow the format; what() is one line naming the field.
class ProtocolError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// The largest budget a view may name: 1 TiB, far beyond any pool (the pager's own limit is 16 GiB); more
// is a client bug, not a wish.
inline constexpr std::uint64_t kMaxBudgetBytes = std::uint64_t(1) << 40;
// Frustum planes a view may carry: six bound a camera's view, the rest leave room for clip planes.
inline constexpr std::size_t kMaxFrustumPlanes = 16;
// The eye may be anywhere, yet finite and within this distance of the scene cube (octree space, where the
// cube is 1 wide): beyond it every slice is finer than a pixel in any view.
inline constexpr double kMaxEyeCoordinate = 1e12;
// A view message's size: its fixed fields in this many bytes, plus up to kViewBytesPerHeldSlice per slice
// of the store in each of `held` and `first`.
inline constexpr std::size_t kViewFixedBytes = 16 * 1024;
inline constexpr std::size_t kViewBytesPerHeldSlice = 12;  // "4294967295," and slack
std::size_t maxClientMessageBytes(std::size_t sliceCount);

struct View {
  std::uint64_t id = 0;  // the client's sequence number: a larger one supersedes
  ViewQuery query;
  std::uint64_t budgetBytes = 0;    // the client's pool: the plan's decoded bytes stay within it
  std::vector<std::uint32_t> held;  // slices the client has (sent once, on a new connection)
  std::vector<std::uint32_t> first;  // slices the client wants before the rest of the plan, in order
};

// One message from a client: a view, an acknowledgement or slices wanted first.
struct ClientMessage {
  enum class Kind { View, Ack, Want } kind = Kind::View;
  View view;
  std::uint64_t ackedBytes = 0;
  std::vector<std::uint32_t> wanted;
};

std::string encodeView(const View& view);
std::string encodeAck(std::uint64_t receivedBytes);
std::string encodeWant(std::span<const std::uint32_t> slices);
// Throws ProtocolError: not JSON, an unknown shape, a missing or non-finite number, a budget of 0 or above
// kMaxBudgetBytes, a slice id not below `sliceCount`, more than kMaxFrustumPlanes planes.
ClientMessage parseClientMessage(std::string_view text, std::size_t sliceCount);

// The slices the server plans for `query` and a client pool of `budgetBytes`: scheduleSlices' order while
// the wanted slices' decoded bytes fit the budget (a block is never smaller than its slices' decoded
// bytes, so the pool cannot hold more), each followed at once by the planned slices that continue its cube's
// chain (the pager fetches a region's consecutive slices as one request, and decodes none before all came).
std::vector<std::uint32_t> planSlices(const StoreIndex& index, const ViewQuery& query,
                                      std::uint64_t budgetBytes);

// One message from the server: a plan, or a slice it could not send.
struct ServerMessage {
  enum class Kind { Plan, SliceError } kind = Kind::Plan;
  std::uint64_t view = 0;
  std::vector<std::uint32_t> plan;
  std::uint32_t slice = 0;
  std::string error;
};
std::string encodePlan(std::uint64_t view, std::span<const std::uint32_t> plan);
std::string encodeSliceError(std::uint64_t view, std::uint32_t slice, std::string_view error);
// Throws ProtocolError as parseClientMessage.
ServerMessage parseServerMessage(std::string_view text, std::size_t sliceCount);

// The head of a binary message: which slice follows and for which view. Little-endian on the wire.
inline constexpr std::uint32_t kSliceFrameMagic = 0x4C535653;  // "SVSL"
inline constexpr std::size_t kSliceFrameHeaderBytes = 16;
struct SliceFrameHeader {
  std::uint32_t slice = 0;
  std::uint64_t view = 0;
};
void writeSliceFrameHeader(const SliceFrameHeader& header, std::span<std::byte, kSliceFrameHeaderBytes> out);
// Throws ProtocolError when `frame` is shorter than a header or its magic is wrong; the bytes after the
// header are the slice's.
SliceFrameHeader readSliceFrameHeader(std::span<const std::byte> frame);

}  // namespace svo::stream
