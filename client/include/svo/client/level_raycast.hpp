// ESVO ray casting (raycast.hpp) over an octree held as arrays per level (level_arrays.hpp) instead of a
// block: the same loop (continueRay), finding a voxel's children by counting the child masks before it and
// its contour by counting presence bits. Its hits are castRay's bit for bit on the same octree. Depth only:
// no attributes, no block pool yet.
#pragma once

#include <cstdint>
#include <vector>

#include "svo/client/raycast.hpp"
#include "svo/store/level_arrays.hpp"

namespace svo {

// Level arrays with the counts a descent finds children and contours by (level_arrays.hpp's groups).
class LevelOctree {
 public:
  struct Level {
    std::vector<std::uint8_t> childMasks;      // per voxel, then a group of zeros (a whole group's load)
    std::vector<std::uint32_t> childCounts;    // children of the voxels before each kChildCountGroup
    std::vector<std::uint64_t> contourWords;   // presence bits, 64 voxels a word
    std::vector<std::uint32_t> contourCounts;  // contours before each word
    std::vector<std::uint32_t> contours;

    // The level below's index of the first child of voxel i.
    std::uint32_t firstChild(std::uint32_t i) const;
    // Voxel i's contour, where it has one.
    bool contour(std::uint32_t i, std::uint32_t& bits) const;
  };

  // Throws std::invalid_argument when the levels do not make one octree: level 0 not one voxel, a level's
  // voxels not as many as the level above's child masks count, or contours not as many as their bits.
  explicit LevelOctree(const std::vector<OctreeLevel>& levels);
  const Level& level(int l) const { return levels_[std::size_t(l)]; }
  int levels() const { return int(levels_.size()); }

 private:
  std::vector<Level> levels_;
};

struct LevelCastHit {
  bool hit = false;
  bool leaf = false;  // false when stopped by level of detail
  float t = 0.0f;
  int scale = 0;  // voxel size is 2^(scale - 23) octree units, its level kMaxLevels - 1 - scale
  int childSlot = 0;
  int iterations = 0;
  std::uint32_t parent = 0;  // the hit voxel's parent: its index in its level
  glm::vec3 position{0.0f};  // clamped into the hit voxel's cube, as CastHit's
  glm::vec3 cubeMin{0.0f};
};

// castRay on level arrays; options.recordPath is ignored (no hit records a path).
LevelCastHit castRay(const LevelOctree& octree, const OctreeRay& ray, const CastOptions& options = {});

}  // namespace svo
