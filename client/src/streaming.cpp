#include "svo/client/streaming.hpp"

#include <malloc.h>

#include <algorithm>
#include <chrono>

#include <xxhash.h>

namespace svo {
namespace {

std::uint64_t frameHash(const Frame& frame) {
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset(state);
  XXH3_64bits_update(state, frame.color.data(), frame.color.size() * sizeof(frame.color[0]));
  XXH3_64bits_update(state, frame.depth.data(), frame.depth.size() * sizeof(frame.depth[0]));
  const std::uint64_t hash = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  return hash;
}

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

}  // namespace

void keepFreedMemoryForReuse() {
#ifdef __GLIBC__
  // Allocations up to this size come from the heap instead of fresh mappings: glibc's largest setting, above
  // any single allocation of a pager load on the stores measured (malloc(3), M_MMAP_THRESHOLD).
  constexpr int kHeapAllocationBytes = 32 << 20;
  // Free memory a heap keeps before returning any to the OS (glibc default 128 KB, malloc(3),
  // M_TRIM_THRESHOLD): enough for a load's transient arrays on the stores measured (svo bench stream).
  constexpr int kKeptFreeBytes = 256 << 20;
  mallopt(M_MMAP_THRESHOLD, kHeapAllocationBytes);
  mallopt(M_TRIM_THRESHOLD, kKeptFreeBytes);
  // Every thread allocates from the main heap, which keeps kKeptFreeBytes free. A thread's own arena
  // returns each of its heaps to the OS once it is empty, whatever the trim threshold, so a pager worker
  // would page-fault its next load's arrays in again.
  // The workers allocate a few large arrays per load, so they seldom wait for one another's lock.
  mallopt(M_ARENA_MAX, 1);
#endif
}

StreamedFrame streamFrame(Pager& pager, const Camera& camera, const RenderOptions& options,
                          const PoolRenderer& renderer) {
  StreamedFrame out;
  const auto start = std::chrono::steady_clock::now();
  out.stats = pager.update(viewOf(pager.transform(), camera, options.lodPixels));
  out.updateSeconds = secondsSince(start);
  {
    const Pager::FrameScope rendering(pager);
    out.frame = renderer ? renderer(pager, camera, options) : render(pager, camera, options);
  }
  pager.feedback(out.frame, camera, options.lodPixels);
  return out;
}

Convergence convergeView(Pager& pager, const Camera& camera, const RenderOptions& options,
                         double timeoutSeconds, StreamedFrame* last,
                         const std::function<void(double, StreamedFrame&)>& each,
                         const PoolRenderer& renderer) {
  const auto start = std::chrono::steady_clock::now();
  const ViewQuery view = viewOf(pager.transform(), camera, options.lodPixels);
  // Each frame's hash and time; the run of frames equal to the last one tells when the image became final.
  std::uint64_t lastHash = 0;
  Convergence out;
  while (true) {
    StreamedFrame step = streamFrame(pager, camera, options, renderer);
    const bool done = pager.converged();
    const double t = secondsSince(start);
    if (out.viewSeconds < 0.0 && (done || pager.viewConverged())) {
      out.viewSeconds = t;
      out.viewBytesRead = pager.bytesRead();
      out.viewResidentSlices = pager.residentSlices();
      out.viewWorkerCpu = pager.workerCpu();
    }
    const std::uint64_t hash = frameHash(step.frame);
    if (hash != lastHash) lastHash = hash, out.imageFinalSeconds = t;
    if (each) each(t, step);
    if (last) *last = std::move(step);
    if (done) {
      out.seconds = t;
      return out;
    }
    if (t > timeoutSeconds) return {};
    // Until the next frame is due, only commit what the workers finish and ask for what follows; the frame
    // comes at once when the view, or everything, has converged.
    const double nextFrame = std::max(t - step.seconds() + kStillViewFrameSeconds,
                                      t + step.seconds() * kStillViewWaitPerRenderSecond);
    const bool viewDone = out.viewSeconds >= 0.0;
    for (double now = secondsSince(start);
         now < nextFrame && !pager.converged() && (viewDone || !pager.viewConverged());
         now = secondsSince(start)) {
      pager.waitForWork(nextFrame - now);
      pager.update(view);
    }
  }
}

bool loadEverything(Pager& pager, double timeoutSeconds) {
  // A view that wants every slice: no frustum, and a level-of-detail target no voxel reaches.
  constexpr double kNoVoxelIsSmallEnough = 1e-9;
  ViewQuery everything;
  everything.eye = glm::dvec3(1.5);
  everything.lodPixels = kNoVoxelIsSmallEnough;
  const auto start = std::chrono::steady_clock::now();
  while (true) {
    pager.update(everything);
    if (pager.converged()) break;
    if (secondsSince(start) > timeoutSeconds) return false;
    pager.waitForWork(0.05);
  }
  return pager.residentSlices().size() == pager.index().slices().size();
}

TrunkBlock::TrunkBlock(const Pager& pager) : pager_(pager) {
  if (pager.layout() == PoolLayout::Levels) blocks_ = std::make_unique<Pager>(pager.source());
}

}  // namespace svo
