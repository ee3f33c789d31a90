// The view query (docs/architecture.md): which slices a view needs, in what order. Shared by the local pager
// and the server so both schedule alike. A slice of voxel level L in cube C is wanted when the
// voxels of level L - 1 in C would look larger than the target (--lod-pixels) from the eye: the view needs
// the finer level there. Its priority is the released code's 2^scale / (distance to the cube + half its
// size), in pixels: how large its parent voxels look; slices outside the view frustum are discounted. A slice
// never ranks above the slice that holds its parents, so the coarser levels always arrive first and the image
// never has holes. The query walks the slice hierarchy from its root and stops where a slice is not
// wanted: a child slice's cube lies inside its parent's and its parent voxels are half as wide, so they never
// look larger than the parent's; a view update costs the wanted slices and their children, not the store.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/store/store_index.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

struct ViewQuery {
  glm::dvec3 eye{0.0};       // octree space ([1, 2]^3 is the scene cube)
  double pixelAngle = 1e-3;  // radians per pixel
  double lodPixels = 1.0;    // target: stop refining where voxels are this many pixels wide
  // Planes n.x >= d bounding the view in octree space (inward normals); empty = everything is in view.
  std::vector<std::array<double, 4>> frustum;
  // Priority factor for slices outside the frustum: still worth loading for turns, but after what is seen
  // (released code: slices outside the view are loaded only when nothing inside is missing).
  double outsideWeight = 1.0 / 64.0;

  bool operator==(const ViewQuery&) const = default;
};

struct SliceRequest {
  std::uint32_t slice = 0;
  double priority = 0.0;      // larger first; parents never below their children
  double parentPixels = 0.0;  // how wide the slice's parent-level voxels look at the cube's nearest point
  bool inFrustum = true;
};

// The wanted slices of the store for the view, most valuable first. Ties go to the coarser level, then to
// the directory order. `visited`, when given, counts the slices the walk looked at.
std::vector<SliceRequest> scheduleSlices(const StoreIndex& index, const ViewQuery& view,
                                         std::size_t* visited = nullptr);

}  // namespace svo
