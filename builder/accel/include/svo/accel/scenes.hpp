// Generated test and benchmark scenes for the acceleration structures, including the papers' stress
// scenes: long thin random triangles (ORG Fig. 1), a flat field (ORG Sec. 1.1), a few huge triangles among
// many tiny ones (ORG Sec. 1.2), and a tessellated sphere. Deterministic for a given seed.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "svo/builder/mesh.hpp"

namespace svo::accel {

enum class SceneKind {
  kSphere,         // UV sphere of radius 0.5 around (0.5, 0.5, 0.5)
  kThinRandom,     // random long thin triangles in the unit cube
  kFlatField,      // a triangulated height-less field in z = 0 over [0,1]²: flat in one axis
  kHugeAmongTiny,  // about N^(1/3) triangles spanning the cube among tiny random ones
  kRandomSoup,     // random small triangles in the unit cube
};

// About `triangles` triangles (the sphere and the field round to their tessellation). Throws
// std::invalid_argument for 0 triangles.
Mesh makeScene(SceneKind kind, std::size_t triangles, std::uint64_t seed = 1);
std::string sceneName(SceneKind kind);
std::vector<SceneKind> allScenes();

}  // namespace svo::accel
