// The slice planner: which slices a voxel tree makes, and their bytes (codec.hpp). A slice is one level of
// one cube (paper sec. 7). When a cube's next level would exceed the slice size, the slice splits spatially:
// the cube's 8 sub-cubes are packed, in Morton order, into runs of about equal size that each fit, and a
// run of one sub-cube is that sub-cube's own slice, which packs its own sub-cubes in turn. Packing keeps
// slices near the slice size where one slice per sub-cube would leave most of them a fraction of it (median
// 0.2x on a terrain; packed, above 0.5x).
//
// The tree is walked level by level in Morton (breadth-first, slot) order, where every cube of any level
// holds a contiguous range of every deeper level. An out-of-core build plans the same slices from a top
// tree and its cells' totals (addCells): slices within one cell are left to that cell's own planner, and
// slices spanning several cells are assembled from each cell's part (sectionsOfLevel).
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/store/block.hpp"
#include "svo/store/codec.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

// Where a subtree's slices go in a store: its root voxel's level and cube coordinate, the effective
// attribute values its children inherit from (the root's own, or what the root itself inherited), and the
// slice holding the root voxel (kNoSlice for the store's root, which the header holds). The subtree's slices
// start with the root's cube at the root's level.
struct SubtreePlacement {
  int rootLevel = 0;
  glm::ivec3 rootCoord{0};
  std::uint32_t rootColor = 0, rootNormal = 0;
  std::uint32_t parentSlice = SliceInfo::kNoSlice;
};

// Per record of a tree: the color and normal a store holds for it, its own or the one it inherits.
struct EffectiveAttributes {
  std::vector<std::uint32_t> color, normal;
};

// Per level of a subtree, from its root's level down: its voxels, those with children, contours, and the
// attribute values its slices store (inheritance applied).
struct LevelTotals {
  std::uint64_t voxels = 0, splits = 0, contours = 0, colors = 0, normals = 0;
};

// Where the planner sends the slices, in plan order (a slice's parent slice comes first).
class SliceSink {
 public:
  virtual ~SliceSink() = default;
  // A slice of the tree's own levels: its decoded bytes and directory entry (offset, sizes and checksum
  // unset). Returns its id.
  virtual std::uint32_t emit(const std::vector<std::byte>& raw, const SliceInfo& info) = 0;
  // A slice of the cells' levels spanning the cells [firstCell, endCell): its head, its bytes to come from
  // the cells' parts. Returns its id.
  virtual std::uint32_t reserve(const SliceInfo& info, const SliceHead& head, std::size_t firstCell,
                                std::size_t endCell) = 0;
  // The rest of `cell`'s slices, from `level` on, lie within that cell: its own planner plans them.
  virtual void delegate(std::size_t cell, int level, std::uint32_t parentSlice) = 0;
};

class SlicePlanner {
 public:
  // `tree` may be a root alone (a cell of an out-of-core build without children). `inheritance` decides
  // which attribute values are left out (sec. 5.4, as the block layout does). Throws std::invalid_argument
  // for a tree the store cannot hold.
  SlicePlanner(const VoxelTree& tree, std::uint32_t sliceBytes, const LayoutOptions& inheritance,
               const SubtreePlacement& at);

  // Plans the slices and hands each one to `sink`. The root's cube is the first cube: a subtree's slices
  // start one level below its root.
  void run(SliceSink& sink) const;
  // Plans the slices from `level` on of the tree's whole cube (an out-of-core cell whose coarser levels went
  // into slices spanning several cells).
  void runFrom(int level, std::uint32_t parentSlice, SliceSink& sink) const;

  std::size_t voxelCount() const { return tree_.voxels.size(); }
  EffectiveAttributes effective() const { return {effectiveColor_, effectiveNormal_}; }
  // The tree's deepest level (absolute).
  int topLevel() const { return at_.rootLevel + int(levels_.size()) - 1; }
  // The tree's voxels of its deepest level, Morton order: an out-of-core top's cells.
  std::vector<std::pair<std::uint32_t, glm::ivec3>> deepestVoxels() const;
  std::vector<LevelTotals> totals() const;
  // Out of core: the levels below this tree's deepest come from cells, the voxels of that level, each with
  // its subtree's totals (`cells[i]`, its root's level first).
  void addCells(const std::vector<std::vector<LevelTotals>>& cells);
  // Level `level` for every parent the tree has at level - 1: a cell's part of a slice spanning cells.
  SliceSections sectionsOfLevel(int level) const;

 private:
  struct Voxel {
    std::uint32_t record;
    glm::ivec3 coord;
  };
  struct Prefix {  // per voxel of a level, in order: counts before it
    std::vector<std::uint32_t> children, splits, contours, colors, normals;
  };
  struct CellPrefix {  // per cell, in order: totals of one level below the tree's deepest
    std::vector<std::uint64_t> voxels, splits, children, contours, colors, normals;
  };
  // What a slice covers: a cube and a run of its sub-cubes (SliceInfo).
  struct Run {
    int cubeLevel;
    glm::ivec3 cube;
    int firstSlot, lastSlot;
  };

  void resolveAttributes(const LayoutOptions& inheritance);
  void countPrefixes();
  // Per-level data by absolute voxel level (the root sits at at_.rootLevel).
  const std::vector<Voxel>& voxelsAt(int level) const { return levels_[std::size_t(level - at_.rootLevel)]; }
  const Prefix& prefixAt(int level) const { return prefix_[std::size_t(level - at_.rootLevel)]; }
  int deepestLevel() const { return topLevel() + std::max(0, int(cellPrefix_.size()) - 1); }
  SliceHead headOf(int level, std::size_t a, std::size_t b) const;
  std::pair<std::size_t, std::size_t> childRange(int level, std::size_t a, std::size_t b) const;
  glm::ivec3 subCube(int level, std::size_t i, int cubeLevel) const;
  void plan(const Run& run, int level, std::size_t a, std::size_t b, std::uint32_t parentSlice,
            SliceSink& sink) const;
  void split(const Run& run, int level, std::size_t a, std::size_t b, std::uint32_t parentSlice,
             SliceSink& sink) const;
  SliceSections sections(int level, std::size_t a, std::size_t b) const;

  const VoxelTree& tree_;
  std::uint32_t sliceBytes_;
  SubtreePlacement at_;
  std::vector<std::uint32_t> effectiveColor_, effectiveNormal_;
  std::vector<std::uint8_t> storesColor_, storesNormal_;
  std::vector<std::vector<Voxel>> levels_;
  std::vector<Prefix> prefix_;
  std::vector<CellPrefix> cellPrefix_;
};

}  // namespace svo
