#include "streaming.hpp"

#include <fcntl.h>
#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include <xxhash.h>
#include <glm/geometric.hpp>

namespace svo::tools {
namespace {

// A still view is rendered at most this often while it converges; between frames the loop only commits
// finished loads and asks for the next ones (Pager::update), so the workers get the cores that rendering the
// same view again would take. On 2 cores the 20M terrain close-up (256^2) converged in 0.43-0.45 s at 10
// frames/s, 0.43-0.51 s at 15/s and 0.59-0.69 s rendering back to back; 5/s was no faster.
constexpr double kStillViewFrameSeconds = 0.1;

std::uint64_t frameHash(const Frame& frame) {
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset(state);
  XXH3_64bits_update(state, frame.color.data(), frame.color.size() * sizeof(frame.color[0]));
  XXH3_64bits_update(state, frame.depth.data(), frame.depth.size() * sizeof(frame.depth[0]));
  const std::uint64_t hash = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  return hash;
}

}  // namespace

void keepFreedMemoryForReuse() {
#ifdef __GLIBC__
  // Allocations up to this size come from the heap instead of fresh mappings: glibc's largest setting, above
  // any single allocation of a pager load on the stores measured (malloc(3), M_MMAP_THRESHOLD).
  constexpr int kHeapAllocationBytes = 32 << 20;
  // Free memory a heap keeps before returning any to the OS (default 128 KB, malloc(3), M_TRIM_THRESHOLD).
  // Measured on the 2M terrain's 64 MiB close-up (svo bench stream, three interleaved pairs): view converged
  // 214-262 -> 196-209 ms, worker CPU 422-475 -> 374-423 ms; svo stress at 16 MiB: peak RSS 190 -> 215 MB.
  constexpr int kKeptFreeBytes = 256 << 20;
  mallopt(M_MMAP_THRESHOLD, kHeapAllocationBytes);
  mallopt(M_TRIM_THRESHOLD, kKeptFreeBytes);
#endif
}

StreamedFrame streamFrame(Pager& pager, const Camera& camera, const RenderOptions& options) {
  StreamedFrame out;
  const auto start = std::chrono::steady_clock::now();
  out.stats = pager.update(viewOf(pager.transform(), camera, options.lodPixels));
  out.updateSeconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  out.frame = render(pager.trunk(), pager.transform(), camera, options);
  pager.feedback(out.frame, camera, options.lodPixels);
  return out;
}

Convergence convergeView(Pager& pager, const Camera& camera, const RenderOptions& options,
                         double timeoutSeconds, StreamedFrame* last,
                         const std::function<void(double, StreamedFrame&)>& each) {
  const auto start = std::chrono::steady_clock::now();
  const auto elapsed = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  };
  const ViewQuery view = viewOf(pager.transform(), camera, options.lodPixels);
  // Each frame's hash and time; the run of frames equal to the last one tells when the image became final.
  std::uint64_t lastHash = 0;
  Convergence out;
  while (true) {
    StreamedFrame step = streamFrame(pager, camera, options);
    const bool done = pager.converged();
    const double t = elapsed();
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
    const double nextFrame = t - step.seconds() + kStillViewFrameSeconds;
    const bool viewDone = out.viewSeconds >= 0.0;
    for (double now = elapsed();
         now < nextFrame && !pager.converged() && (viewDone || !pager.viewConverged()); now = elapsed()) {
      pager.waitForWork(nextFrame - now);
      pager.update(view);
    }
  }
}

Camera closeUp(const BlockView& root, const SceneTransform& scene, int size, double distance) {
  // Aim at the surface the centre pixel of a framing view sees, and stand a few percent of the scene away.
  const Camera framing = Camera::framing(scene, glm::dvec3(-0.35, -0.25, -1.0), size, size);
  RenderOptions options;
  options.lodPixels = 1.0f;
  const Frame frame = render(root, scene, framing, options);
  const std::size_t centre = std::size_t(size / 2) * std::size_t(size) + std::size_t(size / 2);
  double depth = frame.depth[centre];
  if (!std::isfinite(depth)) depth = glm::length(framing.target - framing.eye);
  glm::dvec3 direction;
  Camera::pixelRay(framing, framing.basis(), size / 2, size / 2, direction);
  Camera c = framing;
  c.target = framing.eye + direction * depth;
  c.eye = c.target - direction * (distance * scene.size);
  return c;
}

FrameError frameError(const Frame& frame, const Frame& converged) {
  FrameError e;
  const std::size_t n = frame.color.size();
  if (n == 0 || converged.color.size() != n) return {NAN, NAN};
  double squares = 0.0;
  std::size_t mismatch = 0;
  for (std::size_t i = 0; i < n; ++i) {
    for (int c = 0; c < 3; ++c) {
      const double d = double(frame.color[i][c]) - double(converged.color[i][c]);
      squares += d * d;
    }
    mismatch += (frame.color[i].a > 0.0f) != (converged.color[i].a > 0.0f);
  }
  e.rmse = std::sqrt(squares / double(3 * n));
  e.silhouettePercent = 100.0 * double(mismatch) / double(n);
  return e;
}

void dropFileCache(const std::filesystem::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return;
  ::fdatasync(fd);
  ::posix_fadvise(fd, 0, 0, POSIX_FADV_DONTNEED);
  ::close(fd);
}

double percentile(std::vector<double> samples, double q) {
  if (samples.empty()) return NAN;
  std::sort(samples.begin(), samples.end());
  return samples[std::min(samples.size() - 1, std::size_t(q * double(samples.size())))];
}

std::string formatBytes(std::size_t bytes) {
  char text[32];
  if (bytes >= (std::size_t(1) << 30))
    std::snprintf(text, sizeof text, "%.2f GiB", double(bytes) / double(1 << 30));
  else if (bytes >= (std::size_t(1) << 20))
    std::snprintf(text, sizeof text, "%.1f MiB", double(bytes) / double(1 << 20));
  else
    std::snprintf(text, sizeof text, "%.1f KiB", double(bytes) / 1024.0);
  return text;
}

}  // namespace svo::tools
