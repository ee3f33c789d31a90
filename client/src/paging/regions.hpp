// The pager's regions (pager.hpp): the cubes and runs of sub-cubes of the store's slice hierarchy, each a
// chain of slices, and the block pool that holds one block per resident region. A region's block is reached
// from its parent region's block through link descriptors at its entry voxels, so the ray caster sees one
// octree (or, with PoolLayout::Levels, a LevelPool holds each resident region as level arrays instead). The
// render thread owns this table; workers read resident regions under the pager's shared lock.
#pragma once

#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/client/level_raycast.hpp"
#include "svo/client/pool.hpp"
#include "svo/store/store_types.hpp"

namespace svo::paging {

// Entry voxels and their descriptors' slots in a block, in Morton order.
using EntrySlots = std::vector<std::pair<glm::ivec3, std::uint32_t>>;

struct Region {
  std::int32_t cubeLevel = 0;
  glm::ivec3 cubeCoord{0};
  std::uint8_t firstSlot = 0, lastSlot = 7;  // the run of sub-cubes (0-7: the whole cube)
  std::vector<std::uint32_t> slices;         // by voxel level
  std::int32_t parent = -1;
  std::vector<std::uint32_t> children;
  std::uint32_t resident = 0;  // slices resident: a prefix of `slices`
  BlockPool::BlockId block = 0;
  std::size_t blockBytes = 0;                      // its block's size (the pool holds it in whole pages)
  std::uint32_t rootSlot = 0;                      // the cube's voxel in its block
  EntrySlots entries;                              // its entry voxels that have children, in its block
  std::map<std::uint32_t, EntrySlots> childSlots;  // child region -> its entry voxels in this block
  // Compressed layout: child region -> the first of its voxels among this block's exact values.
  std::map<std::uint32_t, std::uint32_t> childFrontier;
  std::map<std::uint32_t, ChildDescriptor> unlinked;  // slot -> descriptor before a link replaced it
  std::uint64_t version = 0;                          // bumped by every commit or eviction
  double priority = 0.0;                              // highest view priority of its resident slices

  bool complete() const { return resident == slices.size(); }
};

// What a worker decoded for a region held as level arrays (level_pool.hpp), for the pool to add.
struct LevelGrowth {
  std::uint32_t added = 0;  // slices decoded, a prefix of those asked for
  // A resident region: its deepest level's child masks, now that the level below is decoded. A new region:
  // empty, and levels[0] is its base.
  std::vector<std::uint8_t> deepestMasks;
  std::vector<IndexedLevel> levels;  // in order down from the region's deepest (or base) level
  std::uint32_t baseStart = 0;       // a new region's base: its first voxel on the parent's deepest level
  std::vector<std::uint16_t> baseShownNormals;  // a new region's base: the normal codes its voxels show
  std::size_t bytes() const;                    // what it adds to the pool
};

// A region's new block as a worker built it (region_loader.hpp), or the error that stopped it.
struct BuiltBlock {
  std::uint32_t slice = 0, region = 0;
  std::uint32_t requested = 0;  // slices of the request
  std::uint32_t added = 0;      // slices the block adds (fewer than requested when one failed)
  std::uint64_t version = 0;    // of the region when read
  Block block;
  std::uint32_t rootSlot = 0;
  EntrySlots entries;
  std::map<std::uint32_t, EntrySlots> childSlots;
  std::map<std::uint32_t, std::uint32_t> childFrontier;
  LevelGrowth growth;  // instead of the block, where the pool holds level arrays
  std::uint32_t failedSlice = SliceInfo::kNoSlice;
  std::string error;
  bool transient = false;  // failedSlice's source failed for a reason that may pass: ask again later
};

// Where a region is entered from its parent's block: the cube's voxel, or each sub-cube's voxel of a run
// (present or not), in Morton order, and their level.
std::pair<std::vector<glm::ivec3>, int> entryVoxels(int cubeLevel, glm::ivec3 cube, std::uint8_t firstSlot,
                                                    std::uint8_t lastSlot);

class LevelPool;

class RegionTable {
 public:
  // The regions of the store's slices, checked: one root region (the trunk), every slice after its parent
  // slice, continuing its region's previous slice one level down. Throws std::runtime_error naming `store`
  // and the slice. Given `levelArraysOf` (the store's header), the regions are held as level arrays
  // (LevelPool) instead of blocks.
  RegionTable(const std::vector<SliceInfo>& slices, std::size_t budgetBytes, const std::string& store,
              const StoreHeader* levelArraysOf = nullptr);
  ~RegionTable();

  std::uint32_t size() const { return std::uint32_t(regions_.size()); }
  Region& operator[](std::uint32_t region) { return regions_[region]; }
  std::uint32_t indexOf(const Region& region) const { return std::uint32_t(&region - regions_.data()); }
  const Region& operator[](std::uint32_t region) const { return regions_[region]; }
  std::uint32_t regionOf(std::uint32_t slice) const { return regionOf_[slice]; }
  std::uint32_t indexInRegion(std::uint32_t slice) const { return indexInRegion_[slice]; }
  BlockPool& pool() { return pool_; }
  const BlockPool& pool() const { return pool_; }
  // The regions as level arrays, where they are held so (else nullptr).
  const LevelPool* levels() const { return levels_.get(); }
  // The pool's bytes whichever way it holds the regions: what a region holds, what is free, in use, the
  // budget.
  std::size_t heldBytes(std::uint32_t region) const;
  std::size_t freeBytes() const { return capacityBytes() - usedBytes(); }
  std::size_t usedBytes() const;
  std::size_t capacityBytes() const { return pool_.capacityBytes(); }

  // A resident region's block.
  BlockView view(const Region& region) const;
  const ChildDescriptor* descriptorAt(const Region& region, std::uint32_t slot) const;
  ChildDescriptor* descriptorAt(Region& region, std::uint32_t slot);

  // A resident region that no resident region hangs from, less wanted than `priority`; never the trunk.
  bool evictable(std::uint32_t region, double priority) const;
  // Restores the parent's descriptors at the region's entry voxels and frees its block; returns the slices
  // it held.
  std::uint32_t evict(std::uint32_t region);
  // Makes `built.block` the region's block (the old one freed), linked from its parent's block; when the
  // pool compacted to fit it, relinks every region. The caller has made room.
  void install(BuiltBlock& built);

  std::vector<std::uint32_t> residentSlices() const;
  // The slice that adds the voxels of `voxelLevel` around octree point `p` (ray feedback), if any.
  std::optional<std::uint32_t> sliceAt(int voxelLevel, glm::dvec3 p) const;
  // Pool invariants, every link leads to its region's root descriptor, every resident non-root region is
  // linked from its parent, page headers lead to each block's info section. Throws std::logic_error.
  void checkInvariants() const;

 private:
  std::uint32_t parentSlotOf(const Region& parent, std::uint32_t child, const glm::ivec3& coord) const;
  void link(std::uint32_t region);
  void relinkAll();

  BlockPool pool_;
  std::unique_ptr<LevelPool> levels_;
  std::vector<Region> regions_;
  std::vector<std::uint32_t> regionOf_, indexInRegion_;
  // Feedback lookup: (voxel level, cube level, cube) -> slice (a run's slices under each of its sub-cubes);
  // the cube levels each voxel level's keys use.
  std::unordered_map<std::uint64_t, std::uint32_t> sliceAt_;
  std::vector<std::vector<std::int32_t>> cubeLevelsOf_;
};

}  // namespace svo::paging
