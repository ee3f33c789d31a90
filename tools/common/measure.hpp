// What the commands and benches share to set up and measure views: a close-up camera, a frame's error
// against a converged one, percentiles, byte sizes for messages, and a cold page cache for benchmarks.
#pragma once

#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include "svo/client/render.hpp"

namespace svo::tools {

// A close-up of the surface the centre pixel of a framing view of `root` along `viewDirection` sees, from
// `distance` times the scene size away (a few percent: a view that needs the finest levels).
Camera closeUp(const BlockView& root, const SceneTransform& scene, int size, double distance,
               glm::dvec3 viewDirection = kDefaultViewDirection);

// Error of a frame against the converged frame of the same camera: RMSE of linear RGB over all pixels and the
// share of pixels that one hits and the other misses.
struct FrameError {
  double rmse = 0.0;
  double silhouettePercent = 0.0;
};
FrameError frameError(const Frame& frame, const Frame& converged);

// Drops the file's pages from the page cache (posix_fadvise), so the next reads come from the disk. Only
// benchmarks do this: a user's page cache is theirs.
void dropFileCache(const std::filesystem::path& path);

// The q-quantile (0..1) of the samples, nearest rank; NaN for none.
double percentile(std::vector<double> samples, double q);

// "64M" style sizes in messages.
std::string formatBytes(std::size_t bytes);

}  // namespace svo::tools
