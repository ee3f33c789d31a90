// The post-process filter of sec. 6.3: the kernel (a lookup table sorted by distance) and the one-pass
// gather of Fig. 19.
#include "svo/client/post_filter.hpp"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

namespace svo {
namespace {

// Sec. 6.3: 96 samples within a disc of 24 pixels.
constexpr int kKernelSamples = 96;
constexpr float kKernelRadius = 24.0f;
// Sec. 6.3: the sample density falls with the square root of distance, so the samples within radius r
// number r^(2 - 1/2) up to scale.
constexpr double kCountExponent = 1.5;
// Successive pairs turn by the golden angle, which spreads them evenly around the centre at every radius.
constexpr double kGoldenAngle = 2.399963229728653;
// Pixels per tile of the filter's parallel loop.
constexpr int kFilterTile = 32;

// Radius of the disc holding the first n of the kernel's 1 + kKernelSamples samples.
double discRadius(double n) {
  return kKernelRadius * std::pow(n / double(kKernelSamples + 1), 1.0 / kCountExponent);
}

std::vector<FilterSample> makeKernel() {
  std::vector<FilterSample> kernel;
  // The centre stands for the disc of its own share of samples; pair k for the annulus of samples
  // [1 + 2k, 3 + 2k), each sample for half of it, placed at the annulus's middle sample.
  kernel.push_back({0, 0, 0.0f, float(std::numbers::pi * discRadius(1.0) * discRadius(1.0))});
  for (int k = 0; k < kKernelSamples / 2; ++k) {
    const double inner = discRadius(1.0 + 2.0 * k), outer = discRadius(3.0 + 2.0 * k);
    const double weight = std::numbers::pi * (outer * outer - inner * inner) / 2.0;
    const double radius = discRadius(2.0 + 2.0 * k), angle = kGoldenAngle * k;
    int dx = int(std::lround(radius * std::cos(angle))), dy = int(std::lround(radius * std::sin(angle)));
    // Rounding to whole pixels may step past the disc's edge: back one pixel along the longer axis.
    while (std::hypot(double(dx), double(dy)) > double(kKernelRadius)) {
      int& longer = std::abs(dx) >= std::abs(dy) ? dx : dy;
      longer -= longer > 0 ? 1 : -1;
    }
    const float distance = float(std::hypot(double(dx), double(dy)));
    kernel.push_back({dx, dy, distance, float(weight)});
    kernel.push_back({-dx, -dy, distance, float(weight)});
  }
  std::stable_sort(kernel.begin(), kernel.end(),
                   [](const FilterSample& a, const FilterSample& b) { return a.distance < b.distance; });
  return kernel;
}

}  // namespace

const std::vector<FilterSample>& postFilterKernel() {
  static const std::vector<FilterSample> kernel = makeKernel();
  return kernel;
}

void postFilter(Frame& frame, const PostFilterOptions& options) {
  const std::size_t pixels = std::size_t(frame.width) * std::size_t(frame.height);
  if (frame.width < 0 || frame.height < 0 || frame.color.size() != pixels || frame.depth.size() != pixels ||
      frame.voxelPixels.size() != pixels)
    throw std::invalid_argument("postFilter: the frame's color, depth and voxel sizes must have " +
                                std::to_string(pixels) + " pixels each");
  if (!(options.radiusPerVoxel > 0.0f) || !std::isfinite(options.radiusPerVoxel) || options.threads < 0)
    throw std::invalid_argument("postFilter: radiusPerVoxel must be finite and > 0, threads >= 0");

  // The radius each pixel asks for: none for a miss, so no blur reaches into the background.
  std::vector<float> radius(pixels, 0.0f);
  bool anyBlur = false;
  for (std::size_t i = 0; i < pixels; ++i) {
    if (!std::isfinite(frame.depth[i])) continue;
    radius[i] = std::min(frame.voxelPixels[i] * options.radiusPerVoxel, kKernelRadius);
    anyBlur |= radius[i] > 1.0f;
  }
  if (!anyBlur) return;

  const std::vector<glm::vec4> source = frame.color;
  const std::vector<FilterSample>& kernel = postFilterKernel();
  const int width = frame.width, height = frame.height;
  forEachTile(width, height, kFilterTile, options.threads, [&](const PixelTile& tile) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) {
        const std::size_t centre = std::size_t(y) * std::size_t(width) + std::size_t(x);
        float r = radius[centre];
        if (r <= 1.0f) continue;
        glm::vec3 sum(0.0f);
        float weightSum = 0.0f;
        for (const FilterSample& s : kernel) {
          if (s.distance >= r) break;
          const int sx = x + s.dx, sy = y + s.dy;
          if (sx < 0 || sy < 0 || sx >= width || sy >= height) continue;
          const std::size_t i = std::size_t(sy) * std::size_t(width) + std::size_t(sx);
          r = std::min(r, radius[i]);
          // Fig. 19: the weight falls linearly to zero between r - 1 and r.
          const float w = s.weight * std::clamp(r - s.distance, 0.0f, 1.0f);
          sum += glm::vec3(source[i]) * w;
          weightSum += w;
        }
        // The centre sample always counts (distance 0 < r), so weightSum > 0.
        frame.color[centre] = glm::vec4(sum / weightSum, source[centre].a);
      }
  });
}

}  // namespace svo
