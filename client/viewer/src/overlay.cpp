#include "svo/viewer/overlay.hpp"

#include <cstdio>

namespace svo::viewer {
namespace {

std::string format(const char* pattern, auto... values) {
  char line[256];
  std::snprintf(line, sizeof line, pattern, values...);
  return line;
}

constexpr double kMiB = 1024.0 * 1024.0;

}  // namespace

std::vector<std::string> overlayLines(const OverlayStats& s) {
  std::vector<std::string> lines;
  lines.push_back("source " + s.source);
  if (s.opening) {
    lines.push_back("opening the store and loading its first slices ...");
    return lines;
  }
  lines.push_back(format("frame %.1f ms (render %.1f, update %.1f), %.1f frames/s", s.frameMs, s.renderMs,
                         s.updateMs, s.framesPerSecond));
  lines.push_back(format("image %d x %d (%.0f%% of the window)", s.width, s.height, s.scale * 100.0));
  lines.push_back(format("resident %.1f MB of %.1f MB, %zu slices", double(s.residentBytes) / kMiB,
                         double(s.budgetBytes) / kMiB, s.residentSlices));
  lines.push_back(format("slices in flight %u, wanted %u, %s", s.inFlight, s.wanted,
                         s.converged ? "converged" : "streaming"));
  lines.push_back(format("read %.1f MB", double(s.bytesRead) / kMiB));
  lines.push_back("ray casting on " + s.device);
  if (s.uploadedBytes > 0)
    lines.push_back(format("uploaded %.1f MB to the GPU (%.2f MB last frame)", double(s.uploadedBytes) / kMiB,
                           double(s.uploadedLastFrame) / kMiB));
  lines.push_back(s.deepestLevel < 0
                      ? format("deepest level on screen: none of %d", s.storeLevels)
                      : format("deepest level on screen %d of %d", s.deepestLevel, s.storeLevels));
  lines.push_back(format("eye %.4g %.4g %.4g, speed %.3g/s", s.eye.x, s.eye.y, s.eye.z, s.speed));
  return lines;
}

}  // namespace svo::viewer
