// ESVO ray casting (raycast.hpp) over an octree held as arrays per level (level_arrays.hpp) instead of a
// block: the same loop (continueRay), finding a voxel's children by counting the child masks before it and
// its contour, color and normal by counting presence bits. Its hits, and the values hitAttribute finds for
// them, are the block's bit for bit on the same octree. The octree may be one region or regions linked at
// their deepest levels, as a pager holds them. Rays are cast one at a time or in packets (castPacket).
#pragma once

#include <bit>
#include <cassert>
#include <cstdint>
#include <cstring>
#include <vector>

#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
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
  PresentValues(const PresenceBits& bits, std::vector<Value>&& present);
  // The values present before voxel i: its value's index, where it has one.
  std::uint32_t rank(std::uint32_t i) const {
    return counts[i / 64] +
           std::uint32_t(std::popcount(words[i / 64] & ((std::uint64_t(1) << (i % 64)) - 1)));
  }
  // Voxel i's value, where it has one.
  bool find(std::uint32_t i, Value& value) const {
    if (!((words[i / 64] >> (i % 64)) & 1u)) return false;
    value = values[rank(i)];
    return true;
  }
};

// One level's arrays with the counts a descent finds children and values by (level_arrays.hpp's groups).
struct IndexedLevel {
  // Per voxel, then a group of zeros (a whole group's load). None where no voxel has children: a level at the
  // store's finest, or a region's deepest until it grows, holds no masks and no counts.
  std::vector<std::uint8_t> childMasks;
  std::vector<std::uint32_t> childCounts;         // children of the voxels before each kChildCountGroup
  PresentValues<std::uint32_t> contours, colors;  // colors ABGR
  PresentValues<std::uint16_t> normals;           // lattice codes (format.hpp)

  IndexedLevel() = default;
  // A decoded level's arrays, moved in; its parts without presence bits (a store without colors or normals)
  // stay empty. Throws std::invalid_argument when a part's values are not as many as its presence bits.
  explicit IndexedLevel(OctreeLevel&& level);
  std::uint32_t voxels() const { return voxels_; }
  // Voxel i's child mask (0 on a level without masks).
  std::uint8_t childMask(std::uint32_t i) const { return i < childMasks.size() ? childMasks[i] : 0; }
  // Sets the child masks (one per voxel, as many as there are) and counts them; returns the children.
  std::uint64_t setChildMasks(std::vector<std::uint8_t>&& masks);
  // No less than what setChildMasks(masks) makes the level hold for its masks and counts.
  static std::size_t childMaskBytes(const std::vector<std::uint8_t>& masks);
  // The level below's index of the first child of voxel i (a level with masks), and all the children its
  // masks count.
  std::uint32_t firstChild(std::uint32_t i) const;
  std::uint32_t children() const;
  std::size_t bytes() const;  // what its arrays hold

 private:
  std::uint32_t voxels_ = 0;
};

// Inline: the caster asks it on every PUSH and POP.
static_assert(kChildCountGroup == 8, "firstChild loads a group's masks as one 64-bit word");
inline std::uint32_t IndexedLevel::firstChild(std::uint32_t i) const {
  assert(i < voxels_ && !childMasks.empty());
  const std::uint32_t group = i / kChildCountGroup * kChildCountGroup;
  std::uint64_t masks;
  std::memcpy(&masks, childMasks.data() + group, sizeof masks);
  const unsigned before = 8 * (i - group);  // bits of the masks before voxel i in its group
  masks = before ? masks & ((std::uint64_t(1) << before) - 1) : 0;
  return childCounts[i / kChildCountGroup] + std::uint32_t(std::popcount(masks));
}

// A part of an octree as level arrays: the levels below a cube (or a run of its sub-cubes) from its *base*,
// the level its first slice's parents are on, down to the deepest level it holds. The base's voxels are a
// Morton range of the parent region's deepest level, which holds their values; the base holds their child
// masks. Regions reached from its deepest level's voxels are linked by voxel range (a block pool's link
// descriptors, pager.hpp), so a descent sees one octree. A whole octree is one region, based at the root.
struct LevelRegion {
  struct Link {
    std::uint32_t first = 0, end = 0;  // the deepest level's voxels [first, end): the region's base
    const LevelRegion* region = nullptr;
  };
  int baseLevel = 0;                    // the octree level of levels[0]
  const LevelRegion* parent = nullptr;  // none for the root's region
  std::uint32_t baseStart = 0;          // levels[0]'s voxel i is the parent's deepest voxel baseStart + i
  std::vector<IndexedLevel> levels;
  std::vector<Link> links;  // sorted, disjoint

  int deepestLevel() const { return baseLevel + int(levels.size()) - 1; }
  // Whether its base has children to descend into (a descent from the root region asks first).
  bool hasChildren() const { return !levels.empty() && !levels[0].childMasks.empty(); }
  // The region entered at deepest-level voxel i, if one is linked there.
  const Link* linkAt(std::uint32_t i) const;
  std::size_t bytes() const;
};

// A whole octree as level arrays: one region.
class LevelOctree {
 public:
  using Level = IndexedLevel;

  // Throws std::invalid_argument when the levels do not make one octree: level 0 not one voxel, a level's
  // voxels not as many as the level above's child masks count, or a part's values not as many as its
  // presence bits.
  LevelOctree(const std::vector<OctreeLevel>& levels, const StoreHeader& header);
  const Level& level(int l) const { return region_.levels[std::size_t(l)]; }
  int levels() const { return int(region_.levels.size()); }
  const LevelRegion& region() const { return region_; }
  bool hasColors() const { return hasColors_; }
  bool hasNormals() const { return hasNormals_; }

 private:
  LevelRegion region_;
  bool hasColors_ = false, hasNormals_ = false;
};

// A voxel of level arrays: its region, and its index in its level there.
struct LevelNode {
  const LevelRegion* region;
  std::uint32_t index;

  LevelNode() = default;  // uninitialized, as a pointer is: a hit's path is written by each PUSH
  LevelNode(const LevelRegion* r, std::uint32_t i) : region(r), index(i) {}
  // Member by member: a copy of the whole 16 bytes (padding included) goes through a vector register, whose
  // load from the two scalar stores that made the node stalls the caster's PUSH (store forwarding).
  LevelNode(const LevelNode& n) : region(n.region), index(n.index) {}
  LevelNode& operator=(const LevelNode& n) {
    region = n.region, index = n.index;
    return *this;
  }
  bool operator==(const LevelNode& n) const { return region == n.region && index == n.index; }
};

struct LevelCastHit {
  bool hit = false;
  bool leaf = false;  // false when stopped by level of detail
  float t = 0.0f;
  int scale = 0;  // voxel size is 2^(scale - 23) octree units, its level kMaxLevels - 1 - scale
  int childSlot = 0;
  int iterations = 0;
  LevelNode parent{nullptr, 0};  // the hit voxel's parent
  glm::vec3 position{0.0f};      // clamped into the hit voxel's cube, as CastHit's
  glm::vec3 cubeMin{0.0f};
  // The ancestors' indices by scale, where CastOptions::recordPath: the one at scale s (in (scale, 22]) is
  // the parent of the one at scale s - 1, and pathParent[scale + 1] is `parent`'s.
  LevelNode pathParent[kMaxLevels];  // left uninitialized: written by each PUSH

  float voxelSize() const { return std::bit_cast<float>(std::uint32_t(scale - kMaxLevels + 127) << 23); }
};

// castRay on level arrays: a whole octree, or the regions linked from `root`, the root's region.
LevelCastHit castRay(const LevelRegion& root, const OctreeRay& ray, const CastOptions& options = {});
inline LevelCastHit castRay(const LevelOctree& octree, const OctreeRay& ray,
                            const CastOptions& options = {}) {
  return castRay(octree.region(), ray, options);
}
// castRay for up to kPacketLanes rays at once, in castPacket's SIMD loops (raycast.hpp): each hit is
// castRay's, bit for bit.
void castPacket(const LevelRegion& root, const OctreeRay* rays, int count, const CastOptions& options,
                LevelCastHit* hits);

// The color (ABGR) or normal (cube-encoded bits, format.hpp) a hit voxel shows: its own, else its nearest
// ancestor's (the root's at the last), as hitAttribute gives it on a raw block of the same store. Needs the
// hit's path (CastOptions::recordPath); 0 for a miss or a type the octree does not have.
std::uint32_t hitAttribute(const LevelCastHit& hit, AttachmentType type);
// Both values hitAttribute finds, the color where `colors` and the normal where `normals` (0 where not asked
// for, or for a miss), with the hit voxel found and its path walked once.
struct LevelHitValues {
  std::uint32_t color = 0, normal = 0;
};
LevelHitValues hitValues(const LevelCastHit& hit, bool colors, bool normals);
// The voxel a hit stopped at, in its parent's region (whose deepest level holds a linked region's base
// voxels' values).
LevelNode hitVoxel(const LevelCastHit& hit);
inline std::uint32_t hitAttribute(const LevelOctree& octree, const LevelCastHit& hit, AttachmentType type) {
  return (type == AttachmentType::Color ? octree.hasColors() : octree.hasNormals()) ? hitAttribute(hit, type)
                                                                                    : 0;
}

// A frame of the octree below `root` (render.hpp's render, without packets): the beam pass per tile and
// castRay per pixel, shaded as a block's frame is, so that it equals the frame of a block holding the same
// octree.
Frame render(const LevelRegion& root, const StoreHeader& header, const SceneTransform& scene,
             const Camera& camera, const RenderOptions& options);

}  // namespace svo
