// The streaming loop every client of the pager runs: one streamed frame (pager update, render of what is
// resident, ray feedback), a still view converged frame by frame, and the allocator policy of a streaming
// process.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <vector>

#include "svo/client/pager.hpp"
#include "svo/client/render.hpp"

namespace svo {

// The allocator policy of a streaming process, set once before its first pager: freed memory is kept for
// reuse, in the one heap every thread allocates from. The pager's workers allocate and free a region's voxel
// arrays and its new block for every load; glibc's defaults hand freed memory back to the OS and map every
// allocation over 128 KB afresh, so each load would pay a page fault per 4 KB it had just freed. The process
// keeps at most its peak transient use; the pool and its budget are unaffected. glibc only (a no-op
// elsewhere).
void keepFreedMemoryForReuse();

struct StreamedFrame {
  Frame frame;
  PagerStats stats;
  double updateSeconds = 0.0;  // pager update (commits, evictions, requests) on the render thread
  double seconds() const { return updateSeconds + frame.seconds; }
};

// A still view is rendered at most this often while it converges; between frames the loop only commits
// finished loads and asks for the next ones (Pager::update), so the workers get the cores that rendering the
// same view again would take. Chosen by a sweep of 5, 10 and 15 frames/s and back-to-back frames on the
// 20M terrain close-up (256^2, 2 cores): 10/s converged fastest.
inline constexpr double kStillViewFrameSeconds = 0.1;
// And at least this long after a frame for each second it took, so that where frames slow down (other
// programs on the cores) the workers still get a share of the time.
inline constexpr double kStillViewWaitPerRenderSecond = 1.0;

// How a frame is rendered from the pager's pool: svo::render over the trunk when empty; the GPU caster's
// mirror of the pool for `--device gpu` (client/gpu).
using PoolRenderer = std::function<Frame(Pager&, const Camera&, const RenderOptions&)>;

// One frame while streaming: update the pager for the camera's view, render, feed the rays back.
StreamedFrame streamFrame(Pager& pager, const Camera& camera, const RenderOptions& options,
                          const PoolRenderer& renderer = nullptr);

// Streams frames of one camera until its view has converged. `last` receives the final frame when given;
// `each` sees every frame with the seconds since the start.
struct Convergence {
  double seconds = -1.0;  // until the pager had nothing left to load for the view; negative: timed out
  // Until nothing inside the view frustum was left to load (Pager::viewConverged), with the bytes read and
  // the slices resident then; the rest of `seconds` loads the slices around the view.
  double viewSeconds = -1.0;
  std::uint64_t viewBytesRead = 0;
  std::vector<std::uint32_t> viewResidentSlices;
  WorkerCpu viewWorkerCpu;
  // When the frames stopped changing: the first frame from which on every frame equals the converged one
  // bit for bit (later loads refined nothing this view shows). Negative when timed out.
  double imageFinalSeconds = -1.0;
  bool converged() const { return seconds >= 0.0; }
};
Convergence convergeView(Pager& pager, const Camera& camera, const RenderOptions& options,
                         double timeoutSeconds, StreamedFrame* last = nullptr,
                         const std::function<void(double, StreamedFrame&)>& each = nullptr,
                         const PoolRenderer& renderer = nullptr);

// Loads every slice of the store that fits the pager's budget, wanted by no camera in particular: for
// measurements that compare all depths of a store beyond one block. Returns whether all of them are
// resident.
bool loadEverything(Pager& pager, double timeoutSeconds);

// The trunk as a block, for what frames a view from it (occupiedBox, close-ups): the pager's own, or where
// its pool holds level arrays, that of a pager of blocks over the same source, kept for as long as this
// lives.
class TrunkBlock {
 public:
  explicit TrunkBlock(const Pager& pager);
  BlockView view() const { return blocks_ ? blocks_->trunk() : pager_.trunk(); }

 private:
  const Pager& pager_;
  std::unique_ptr<Pager> blocks_;
};

}  // namespace svo
