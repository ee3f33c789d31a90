// ESVO ray casting (raycast.hpp) over an octree held as arrays per level (level_arrays.hpp) instead of a
// block: the same loop (continueRay), finding a voxel's children by counting the child masks before it and
// its contour, color and normal by counting presence bits. Its hits, and the values hitAttribute finds for
// them, are the block's bit for bit on the same octree. One ray at a time: no packets, no beams, no block
// pool yet.
#pragma once

#include <bit>
#include <cstdint>
#include <vector>

#include "svo/client/raycast.hpp"
#include "svo/store/level_arrays.hpp"

namespace svo {

// One part of a level's voxels that only some have (contours, colors, normals): presence bits, 64 voxels a
// word, the values present before each word, and those values in voxel order.
template <class Value>
struct PresentValues {
  std::vector<std::uint64_t> words;
  std::vector<std::uint32_t> counts;
  std::vector<Value> values;

  PresentValues() = default;
  // Throws std::invalid_argument when `values` are not as many as the bits that are set.
  PresentValues(const PresenceBits& bits, const std::vector<Value>& present);
  // Voxel i's value, where it has one.
  bool find(std::uint32_t i, Value& value) const {
    const std::uint64_t word = words[i / 64];
    const unsigned bit = i % 64;
    if (!((word >> bit) & 1u)) return false;
    value = values[counts[i / 64] + std::uint32_t(std::popcount(word & ((std::uint64_t(1) << bit) - 1)))];
    return true;
  }
};

// Level arrays with the counts a descent finds children and values by (level_arrays.hpp's groups).
class LevelOctree {
 public:
  struct Level {
    std::vector<std::uint8_t> childMasks;           // per voxel, then a group of zeros (a whole group's load)
    std::vector<std::uint32_t> childCounts;         // children of the voxels before each kChildCountGroup
    PresentValues<std::uint32_t> contours, colors;  // colors ABGR
    PresentValues<std::uint16_t> normals;           // lattice codes (format.hpp)

    // The level below's index of the first child of voxel i.
    std::uint32_t firstChild(std::uint32_t i) const;
  };

  // Throws std::invalid_argument when the levels do not make one octree: level 0 not one voxel, a level's
  // voxels not as many as the level above's child masks count, or a part's values not as many as its
  // presence bits.
  LevelOctree(const std::vector<OctreeLevel>& levels, const StoreHeader& header);
  const Level& level(int l) const { return levels_[std::size_t(l)]; }
  int levels() const { return int(levels_.size()); }
  bool hasColors() const { return hasColors_; }
  bool hasNormals() const { return hasNormals_; }

 private:
  std::vector<Level> levels_;
  bool hasColors_ = false, hasNormals_ = false;
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
  // The ancestors' indices by scale, where CastOptions::recordPath: the one at scale s (in (scale, 22]) is
  // the parent of the one at scale s - 1, and pathParent[scale + 1] is `parent`'s.
  std::uint32_t pathParent[kMaxLevels];  // left uninitialized: written by each PUSH
};

// castRay on level arrays.
LevelCastHit castRay(const LevelOctree& octree, const OctreeRay& ray, const CastOptions& options = {});

// The color (ABGR) or normal (cube-encoded bits, format.hpp) a hit voxel shows: its own, else its nearest
// ancestor's (the root's at the last), as hitAttribute gives it on a raw block of the same store. Needs the
// hit's path (CastOptions::recordPath); 0 for a miss or a type the octree does not have.
std::uint32_t hitAttribute(const LevelOctree& octree, const LevelCastHit& hit, AttachmentType type);

}  // namespace svo
