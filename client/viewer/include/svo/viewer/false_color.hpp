// The viewer's false colors, which show where detail is still missing: the octree level a pixel stopped at,
// the ray caster's iterations per pixel, and what is resident against what the view wants.
#pragma once

#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/client/pager.hpp"
#include "svo/client/render.hpp"

namespace svo::viewer {

enum class FalseColor { Shaded, OctreeLevel, Iterations, Detail };
inline constexpr FalseColor kFalseColors[] = {FalseColor::Shaded, FalseColor::OctreeLevel,
                                              FalseColor::Iterations, FalseColor::Detail};
const char* nameOf(FalseColor mode);

// Iterations per pixel at the hot end of the ramp; rays of a few dozen iterations are typical of the paper's
// scenes (sec. 8: 30-60 per ray), so this leaves room above them.
inline constexpr int kIterationsRampTop = 128;

// Replace the frame's (linear) colors; the shading's brightness is kept so the shape stays readable.
void paintLevels(Frame& frame, const Camera& camera, double sceneSize);
void paintIterations(Frame& frame);  // needs RenderOptions::diagnostics
void paintDetail(Frame& frame, const std::vector<PixelDetail>& detail);

// The deepest octree level any pixel stopped at (0 = the root); -1 when no ray hit.
int deepestLevel(const Frame& frame, const Camera& camera, double sceneSize);

struct LegendEntry {
  std::string label;
  glm::vec3 color;  // linear
};
// What the mode's colors mean, for the overlay; `deepest` bounds the levels listed.
std::vector<LegendEntry> legendOf(FalseColor mode, int deepest);

}  // namespace svo::viewer
