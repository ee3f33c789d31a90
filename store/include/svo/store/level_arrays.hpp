// An octree as arrays per level: a candidate for what a pool holds instead of laid-out blocks (block.hpp).
// Each level's voxels are in Morton order and each of their parts is an array addressed by the voxel's index
// in its level. A voxel's children are the next level's voxels after those that the child masks before it
// count, so no child pointer is stored; its contour, color or normal is the present value after those that
// the presence bits before it count. Slices decode straight into it (decodeSliceLevel): no voxel records, no
// layout pass. svo bench store measures its bytes and its decoding against the block layout's.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "svo/store/store_types.hpp"

namespace svo {

// A bit per voxel, LSB first in 64-bit words, appended a slice's section at a time.
class PresenceBits {
 public:
  // Appends `count` bits stored LSB first from byte 0 on (a slice's presence section).
  void append(const std::byte* bits, std::size_t count);
  bool operator[](std::size_t i) const { return (words_[i / 64] >> (i % 64)) & 1u; }
  std::size_t size() const { return size_; }
  std::span<const std::uint64_t> words() const { return words_; }  // bits past size() are 0
  void clear() { words_.clear(), size_ = 0; }

 private:
  std::vector<std::uint64_t> words_;
  std::size_t size_ = 0;
};

struct OctreeLevel {
  std::size_t voxels = 0;
  std::vector<std::uint8_t> childMasks;  // per voxel (0: a leaf); written as the level below is decoded
  PresenceBits contourBits, colorBits, normalBits;
  std::vector<std::uint32_t> contours;     // the present ones, in voxel order
  std::vector<std::uint32_t> colors;       // ABGR; a voxel without one shows its parent's
  std::vector<std::uint16_t> normalCodes;  // lattice codes (format.hpp), as the store holds them
  // What the level below is decoded against, per voxel: its contour (read where contourBits has it) and the
  // lattice code of the normal it shows. A decoder's scratch, not part of the octree.
  std::vector<std::uint32_t> shownContours;
  std::vector<std::uint16_t> shownNormalCodes;

  // Empties it and keeps its arrays' memory, for the next decoding to fill without mapping pages again.
  void clear();
};

// Level 0 of a store: its root voxel, with the root's normal and no contour.
OctreeLevel rootLevel(const StoreHeader& header);

// Decodes slice bytes (codec.hpp) whose parents are voxels [firstParent, firstParent + slice.parentCount) of
// `parents`: sets their child masks and appends the new voxels to `children`, which holds the level's
// voxels of the slices before this one in Morton order. Throws SliceDecodeError where decodeSlice would.
void decodeSliceLevel(std::span<const std::byte> raw, const SliceInfo& slice, const StoreHeader& header,
                      OctreeLevel& parents, std::size_t firstParent, OctreeLevel& children);

// Where a voxel's first child is found: a 32-bit count of the level's children before every this many voxels
// (one 64-bit load of their masks and a popcount give the rest)...
inline constexpr std::size_t kChildCountGroup = 8;
// ...and a present value: a 32-bit count of the present ones before every 64 voxels (one presence word).
inline constexpr std::size_t kPresenceCountGroup = 64;

// The bytes an octree of these levels takes with those counts, by part as the block layout reports them
// (LayoutStats): hierarchy (child masks of every level but the deepest and their counts); contours, colors
// and normals (presence bits, their counts, the values).
struct LevelArrayBytes {
  std::uint64_t hierarchy = 0, contours = 0, colors = 0, normals = 0;
  std::uint64_t total() const { return hierarchy + contours + colors + normals; }
};
LevelArrayBytes bytesOf(std::span<const OctreeLevel> levels, const StoreHeader& header);

}  // namespace svo
