// The point voxelizer's parts (point_voxelize.cpp), shared by the in-core build (voxelizePoints) and the
// out-of-core one (point_out_of_core.cpp), which builds the levels below a cell from the cell's points and
// the levels above from the cells' sums, so that both make the same voxels.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <vector>

#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

#include "geometry.hpp"
#include "svo/builder/points.hpp"

namespace svo::detail {

// A voxel's points summed in the in-core build's order (by finest Morton code, then by file order).
struct PointSums {
  std::uint64_t count = 0;
  glm::dvec4 color{0.0};
  glm::dvec3 normal{0.0};
  glm::vec3 first{0.0f};  // the first point's normal: the voxel's where the normals cancel out
};

// A voxel of one level: its Morton code at that level, its run of sorted points (below a cell) and sums.
struct PointNode {
  std::uint64_t code = 0;
  std::uint32_t begin = 0, end = 0;
  std::uint8_t childMask = 0;
  PointSums sums;
};
// The level above: children with one parent code merged, their sums added in order.
std::vector<PointNode> parentNodes(const std::vector<PointNode>& children);
// The node's voxel: coordinates, child mask, mean color and normal (no contour yet).
SliceVoxel voxelOf(const PointNode& node, bool colors);

// The slabs that bound a voxel's shape from above (sec. 5.3): its ancestors' contours that still cut its
// cube, the finest few, as many as the hull uses.
struct PointBounds {
  std::array<geom::Slab, geom::kMaxHullSlabs> slabs;
  std::uint8_t count = 0;
};
// A voxel's bounds from its parent's (the parent's own contour added where it cuts the child's cube).
PointBounds boundsOf(const PointBounds& parent, const SliceVoxel& parentVoxel, int parentLevel,
                     glm::ivec3 coord, int level);

// Where points lie along a voxel's contour direction (its quantized stored normal), in voxel widths from its
// centre.
struct PointExtent {
  double lo = 1e300, hi = -1e300;
};
void extend(PointExtent& extent, const SliceVoxel& voxel, int level, glm::dvec3 octreePoint);
// The voxel's contour from its points' extent, kept where it trims at least `minCut` voxel widths off the
// hull its bounds leave (chooseContour); sets voxel.hasContour and voxel.contour.
void decideContour(SliceVoxel& voxel, int level, const PointBounds& bounds, PointExtent extent,
                   double minCut);

// The points' levels from `rootLevel` (every point in one voxel of it) down to options.levels, each level in
// Morton order, with contours where options.contours: the root's decided under `rootBounds` (a root of
// level 0 keeps none). `root` receives the root's node. Needs a normal per point.
VoxelLevels pointLevels(const PointCloud& cloud, const SceneTransform& transform, const BuildOptions& options,
                        int rootLevel, const PointBounds& rootBounds, PointNode* root = nullptr);

// pointLevels' root node alone (its sums and code), without the levels below.
PointNode pointRoot(const PointCloud& cloud, const SceneTransform& transform, int levels, int rootLevel);

// A point's voxel coordinates at `level` in the octree frame of `transform`.
glm::ivec3 pointVoxel(const SceneTransform& transform, glm::dvec3 world, int level);

}  // namespace svo::detail
