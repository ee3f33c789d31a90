// What the viewer's overlay says and what it lets the user change. The lines are plain text, so a script can
// print exactly what the overlay shows (`{"print": "overlay"}`).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/viewer/false_color.hpp"

namespace svo::viewer {

// The settings the overlay changes while the viewer runs.
struct ViewSettings {
  std::size_t budgetBytes = 0;  // a change reopens the pool at the new size
  float lodPixels = 1.0f;
  bool contours = true;
  bool filter = false;  // the post-process filter (sec. 6.3)
  FalseColor falseColor = FalseColor::Shaded;
  bool overlay = true;
};

struct OverlayStats {
  std::string source;   // the store's file or URL
  std::string device;   // what ray casts: "the CPU", or the GPU's name
  bool opening = true;  // the pool is still being opened (the first slices loading)
  double frameMs = 0.0, renderMs = 0.0, updateMs = 0.0;
  double framesPerSecond = 0.0;  // frames rendered in the last second
  int width = 0, height = 0;     // of the last frame
  double scale = 1.0;            // its resolution against the window's
  std::size_t residentBytes = 0, budgetBytes = 0, residentSlices = 0;
  std::uint32_t inFlight = 0, wanted = 0;  // slices, from the pager's last update
  std::uint64_t bytesRead = 0;
  std::uint64_t uploadedBytes = 0, uploadedLastFrame = 0;  // the GPU pool's pages (0 on the CPU)
  int deepestLevel = -1, storeLevels = 0;                  // on screen (-1: nothing hit), and in the store
  bool converged = false;
  glm::dvec3 eye{0.0};
  double speed = 0.0;  // world units per second
};

std::vector<std::string> overlayLines(const OverlayStats& stats);

}  // namespace svo::viewer
