// svo serve's view stream as a slice source (docs/architecture.md, "The view stream"): the pager's views go
// to the server over one WebSocket and the server pushes the slices each needs, most valuable first, so a
// fetch usually finds its slice already here or on its way, without a round trip of its own. Whatever the
// stream does not bring (the server has no stream, the connection is down, a slice outside the server's
// plan) is read by range requests, as from any static server. The stream reconnects with backoff and
// resumes from the pager's latest view, telling the server which slices it already has.
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "svo/client/http_source.hpp"
#include "svo/client/slice_source.hpp"

namespace svo {

// How long a fetch waits for a slice the server has planned before reading it by range instead: a planned
// slice is late only when the link or the server stalls, and then a request of its own is the way round.
inline constexpr double kPushWaitSeconds = 5.0;

struct StreamStats {
  std::uint64_t viewsSent = 0;
  std::uint64_t pushed = 0;       // slices received on the stream
  std::uint64_t pushedBytes = 0;  // their frames' bytes
  std::uint64_t usedPushed = 0;   // fetches answered by a pushed slice
  std::uint64_t pulled = 0;       // fetches read by range request
  std::uint64_t connections = 0;  // stream connections made (reconnections included)
  bool declined = false;          // the server has no view stream (a static server): range requests only
  std::string lastError;          // why the stream last went down (it reconnects), or empty
};

class ViewStreamSource final : public SliceSource {
 public:
  // `bytes` reads the store at `url`, http://HOST:PORT/NAME (or /NAME.svo), by range requests; the index
  // is read through it (throws as StoreSliceSource), and the stream to /NAME/stream opens in the background.
  ViewStreamSource(std::shared_ptr<const ByteSource> bytes, const std::string& url,
                   const RemoteOptions& options = {});
  ~ViewStreamSource() override;
  ViewStreamSource(const ViewStreamSource&) = delete;
  ViewStreamSource& operator=(const ViewStreamSource&) = delete;

  const StoreIndex& index() const override;
  void fetch(std::uint32_t slice, SliceBytes& compressed) const override;
  // Pushed slices as they come; the others by range requests, a run of neighbours in one.
  void fetchAll(std::span<const std::uint32_t> slices, std::vector<SliceBytes>& compressed) const override;
  // Sent to the server when it differs from the last view sent, with `first`, which the server sends before
  // the rest of its plan.
  void follow(const ViewQuery& view, std::size_t budgetBytes,
              std::span<const std::uint32_t> first = {}) const override;
  StreamStats stats() const;
  // Whether the stream is connected now.
  bool streaming() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace svo
