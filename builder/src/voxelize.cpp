// Top-down voxelization (paper sec. 5): each voxel keeps the triangles that overlap its cube (exact
// separating-axis test), fits a contour from their clipped pieces, and hands each child the triangles that
// overlap the child. Leaves average color and normal over their clipped geometry, weighted by area; inner
// voxels aggregate their children. The top levels fan out as independent oneTBB tasks whose results are
// concatenated in slot order, so the output does not depend on scheduling.
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include "voxelizer.hpp"

namespace svo {
namespace {

// Margin around the mesh bounds when fitting the scene cube, so no triangle lies on the outer boundary.
constexpr double kSceneMargin = 1.0 / 64.0;

}  // namespace

using namespace voxel;

SceneTransform fitSceneCube(glm::dvec3 lower, glm::dvec3 upper) {
  const double extent = std::max({upper.x - lower.x, upper.y - lower.y, upper.z - lower.z});
  if (!(extent > 0.0)) throw std::runtime_error("mesh has no extent: all vertices coincide");
  SceneTransform t;
  t.size = extent * (1.0 + 2.0 * kSceneMargin);
  t.origin = 0.5 * (lower + upper) - 0.5 * t.size;
  return t;
}

SceneTransform fitSceneCube(const Mesh& mesh) {
  if (mesh.triangles.empty()) throw std::runtime_error("mesh has no triangles");
  dvec3 lo(1e308), hi(-1e308);
  for (const glm::uvec3& t : mesh.triangles)
    for (int k = 0; k < 3; ++k)
      lo = glm::min(lo, mesh.positions[t[k]]), hi = glm::max(hi, mesh.positions[t[k]]);
  return fitSceneCube(lo, hi);
}

VoxelTree voxelize(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options,
                   BuildStats* stats) {
  checkLevels(options);
  const auto start = std::chrono::steady_clock::now();
  VoxelTree tree = Voxelizer(mesh, transform, options, mesh.hasColor()).run(stats);
  if (stats) stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return tree;
}

void addTreeStats(const VoxelTree& tree, int rootLevel, BuildStats& stats) {
  std::vector<std::pair<std::uint32_t, int>> stack{{0u, rootLevel}};
  while (!stack.empty()) {
    const auto [v, level] = stack.back();
    stack.pop_back();
    if (stats.voxelsPerLevel.size() <= std::size_t(level))
      stats.voxelsPerLevel.resize(std::size_t(level) + 1);
    ++stats.voxelsPerLevel[std::size_t(level)];
    const VoxelRecord& r = tree.voxels[v];
    stats.contours += r.hasContour;
    if (r.childMask == 0) ++stats.leafVoxels;
    for (int c = 0; c < std::popcount(unsigned(r.childMask)); ++c)
      stack.push_back({r.firstChild + c, level + 1});
  }
}

Octree buildOctree(const Mesh& mesh, const BuildOptions& options, BuildStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  Octree octree;
  octree.transform = fitSceneCube(mesh);
  octree.parameters = storedParameters(options);
  const VoxelTree tree = voxelize(mesh, octree.transform, options, stats);
  octree.block = layoutBlock(tree, options.layout, stats ? &stats->layout : nullptr);
  if (stats) stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return octree;
}

}  // namespace svo
