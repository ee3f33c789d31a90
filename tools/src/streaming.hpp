// Streaming helpers shared by `svo render --budget`, `svo stress` and `svo bench stream`: one streamed frame
// (pager update, render of what is resident, ray feedback), convergence loops, and a frame's error against
// the converged frame of the same camera.
#pragma once

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "svo/client/pager.hpp"
#include "svo/client/render.hpp"

namespace svo::tools {

// The allocator policy of a streaming process, set once before its first pager: freed memory is kept for
// reuse. The pager's workers allocate and free a region's voxel arrays and its new block for every load, and
// glibc handed freed memory back to the OS (and mapped every allocation over 128 KB afresh), so each load
// paid a page fault per 4 KB it had just freed. The process keeps at most its peak transient use; the pool
// and its budget are unaffected. glibc only (a no-op elsewhere).
void keepFreedMemoryForReuse();

struct StreamedFrame {
  Frame frame;
  PagerStats stats;
  double updateSeconds = 0.0;  // pager update (commits, evictions, requests) on the render thread
  double seconds() const { return updateSeconds + frame.seconds; }
};

// One frame while streaming: update the pager for the camera's view, render, feed the rays back.
StreamedFrame streamFrame(Pager& pager, const Camera& camera, const RenderOptions& options);

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
                         const std::function<void(double, StreamedFrame&)>& each = nullptr);

// A close-up of the surface the centre pixel of a framing view of `root` sees, from `distance` times the
// scene size away (a few percent: a view that needs the finest levels).
Camera closeUp(const BlockView& root, const SceneTransform& scene, int size, double distance);

// Error of a frame against the converged frame of the same camera: RMSE of linear RGB over all pixels and the
// share of pixels that one hits and the other misses.
struct FrameError {
  double rmse = 0.0;
  double silhouettePercent = 0.0;
};
FrameError frameError(const Frame& frame, const Frame& converged);

// Drops the file's pages from the page cache (posix_fadvise), so the next reads come from the disk.
void dropFileCache(const std::filesystem::path& path);

// The q-quantile (0..1) of the samples, nearest rank; NaN for none.
double percentile(std::vector<double> samples, double q);

// "64M" style sizes in messages.
std::string formatBytes(std::size_t bytes);

}  // namespace svo::tools
