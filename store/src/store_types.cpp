#include "svo/store/store_types.hpp"

#include <bit>
#include <cmath>

#include <glm/common.hpp>

namespace svo {

bool mortonLess(const glm::ivec3& a, const glm::ivec3& b) {
  const auto msbBelow = [](std::uint32_t x, std::uint32_t y) { return x < y && x < (x ^ y); };
  int axis = 2;
  std::uint32_t highest = std::uint32_t(a.z ^ b.z);
  for (const int k : {1, 0}) {
    const std::uint32_t d = std::uint32_t(a[k] ^ b[k]);
    if (msbBelow(highest, d)) axis = k, highest = d;
  }
  return a[axis] < b[axis];
}

SliceBox sliceBox(const SliceInfo& s) {
  const double size = std::ldexp(1.0, -s.cubeLevel);
  const glm::dvec3 corner = glm::dvec3(1.0) + glm::dvec3(s.cubeCoord) * size;
  if (s.wholeCube()) return {corner, corner + size};
  // The union of the run's sub-cubes: the slots set a bit per axis, so the run spans an axis's upper half
  // where any of its slots does (and likewise the lower half).
  glm::dvec3 lower = corner + size, upper = corner;
  for (int slot = s.firstSlot; slot <= s.lastSlot; ++slot) {
    const glm::dvec3 sub = corner + glm::dvec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1) * (0.5 * size);
    lower = glm::min(lower, sub), upper = glm::max(upper, sub + 0.5 * size);
  }
  return {lower, upper};
}

bool sliceWithin(const SliceInfo& inner, const SliceInfo& outer) {
  if (inner.cubeLevel < outer.cubeLevel) return false;
  if (inner.cubeLevel == outer.cubeLevel)
    return inner.cubeCoord == outer.cubeCoord && inner.firstSlot >= outer.firstSlot &&
           inner.lastSlot <= outer.lastSlot;
  // A finer cube: its ancestor one level below the outer cube is one of the outer run's sub-cubes.
  const glm::ivec3 sub = inner.cubeCoord >> (inner.cubeLevel - outer.cubeLevel - 1);
  if ((sub >> 1) != outer.cubeCoord) return false;
  const int slot = childSlot(sub);
  return slot >= outer.firstSlot && slot <= outer.lastSlot;
}

VoxelTree treeOfLevels(const VoxelLevels& levels, bool hasColors, bool hasNormals) {
  VoxelTree tree;
  tree.hasColors = hasColors;
  tree.hasNormals = hasNormals;
  std::size_t total = 0;
  for (const auto& l : levels) total += l.size();
  tree.voxels.reserve(total);
  std::size_t nextChild = levels.empty() ? 0 : levels[0].size();
  for (const auto& level : levels) {
    for (const SliceVoxel& n : level) {
      // Fields written in place: a record assembled on the stack and pushed back stalls on store forwarding
      // (its narrow field stores read back as one wide load), a third of the pager's tree time.
      VoxelRecord& r = tree.voxels.emplace_back();
      r.childMask = n.childMask;
      r.firstChild = n.childMask ? std::uint32_t(nextChild) : 0;
      nextChild += std::size_t(std::popcount(unsigned(n.childMask)));
      r.hasContour = n.hasContour;
      r.contour = n.contour;
      r.color = n.color;
      r.normal = n.normal;
    }
  }
  return tree;
}

SliceError::SliceError(std::uint32_t s, const std::string& message, bool transient)
    : std::runtime_error(message), slice(s), transient(transient) {}

}  // namespace svo
