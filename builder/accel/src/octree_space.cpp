#include "octree_space.hpp"

#include <algorithm>
#include <cmath>

namespace svo::accel {

void OctreeParams::validate() const {
  using detail::require;
  require(leafSize >= 1, "octree leaf size must be >= 1");
  require(maxLevel == -1 || (maxLevel >= 0 && maxLevel <= detail::kMaxOctreeLevels),
          "octree max level must be -1 or in [0, 21]");
  require(std::isfinite(maxGrowth) && maxGrowth >= 1.0, "octree max growth must be >= 1");
}

namespace detail {

Space makeSpace(const Box& bounds, std::size_t n, int maxLevel) {
  Space s;
  Box b = bounds;
  if (b.empty()) b = Box{dvec3(0.0), dvec3(1.0)};
  const dvec3 e = b.extent();
  s.size = std::max({e.x, e.y, e.z});
  if (!(s.size > 0.0)) s.size = std::max(1.0, std::abs(b.lo.x) + std::abs(b.lo.y) + std::abs(b.lo.z)) * 1e-9;
  s.lo = b.lo;
  if (maxLevel < 0) {
    // The kd-tree's 8 + 1.3·log2 N depth rule, in octree levels (three binary splits per level).
    const double lg = std::log2(double(std::max<std::size_t>(n, 2)));
    maxLevel = int(std::lround((8.0 + 1.3 * lg) / 3.0));
  }
  s.maxLevel = std::clamp(maxLevel, 0, kMaxOctreeLevels);
  s.fine = s.size / double(U64(1) << s.maxLevel);
  return s;
}

bool overlapsCell(const TriangleStore& store, std::uint32_t id, const Box& cell) {
  const Box fatCell = grow(cell, store.fat);
  return boxesOverlap(store.boxes[id], fatCell) && triangleOverlapsBox(store.tris[id], fatCell);
}

bool subdivide(const TriangleStore& store, const Space& space, const OctreeParams& p, int level, U64 code,
               const std::vector<std::uint32_t>& prims, std::vector<std::uint32_t> children[8]) {
  if (prims.size() <= p.leafSize || level >= space.maxLevel) return false;
  std::size_t total = 0;
  for (int f = 0; f < 8; ++f) {
    children[f].clear();
    const Box cell = space.worldBox(space.cell(level + 1, code * 8 + U64(f)));
    for (std::uint32_t id : prims)
      if (overlapsCell(store, id, cell)) children[f].push_back(id);
    total += children[f].size();
  }
  return double(total) <= p.maxGrowth * double(prims.size());
}

}  // namespace detail
}  // namespace svo::accel
