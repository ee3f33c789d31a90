#include "measure.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <glm/geometric.hpp>

namespace svo::tools {

Camera closeUp(const BlockView& root, const SceneTransform& scene, int size, double distance,
               glm::dvec3 viewDirection) {
  // Aim at the surface the centre pixel of a framing view sees, and stand a few percent of the scene away.
  const Camera framing = Camera::framing(scene, viewDirection, size, size);
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
