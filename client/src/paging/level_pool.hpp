// The pager's resident regions (regions.hpp) held as level arrays (level_raycast.hpp's LevelRegion) instead
// of blocks. A load decodes its slices straight onto the region's deepest resident level and appends the new
// levels; a new region's first slice decodes onto its base, a range of its parent region's deepest level.
// Nothing resident is laid out again: a load costs in proportion to its slices, plus one pass over the
// region's resident hierarchy for the normals its deepest voxels show (no level stores them).
//
// Threads: workers decode (decode()) reading the regions under the pager's shared lock; install() and
// evict() change them under its exclusive lock.
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "paging/regions.hpp"
#include "svo/client/level_raycast.hpp"
#include "svo/store/level_arrays.hpp"
#include "svo/store/store_index.hpp"

namespace svo::paging {

// What a worker decoded for a region, for install() to add.
struct LevelGrowth {
  std::uint32_t region = 0;
  std::uint32_t added = 0;  // slices decoded, a prefix of those asked for
  // A resident region: its deepest level's child masks, now that the level below is decoded. A new region:
  // empty, and levels[0] is its base.
  std::vector<std::uint8_t> deepestMasks;
  std::vector<IndexedLevel> levels;  // in order down from the region's deepest (or base) level
  std::uint32_t baseStart = 0;       // a new region's base: its first voxel on the parent's deepest level
  std::vector<std::uint16_t> baseShownNormals;  // a new region's base: the normal codes its voxels show
  std::uint32_t failedSlice = SliceInfo::kNoSlice;
  std::string error;  // why failedSlice could not be decoded
  std::size_t bytes() const;
};

class LevelPool {
 public:
  LevelPool(const RegionTable& regions, const StoreIndex& index);

  // The region's slices from `first` on (their decompressed bytes, as many as given) decoded onto what is
  // resident; `first` must be the region's resident slices, and a new region's parent must be complete. A
  // slice that fails to decode ends the growth, which holds the ones before it. `pause` is called between
  // slices.
  LevelGrowth decode(
      std::uint32_t region, std::uint32_t first, std::span<const SliceBytes> raw,
      const std::function<void()>& pause = [] {}) const;
  // Adds the growth to its region (creating and linking a new region to its parent).
  void install(LevelGrowth&& growth);
  // Drops a resident region that no resident region hangs from, and its link in its parent.
  void evict(std::uint32_t region);

  const LevelRegion* region(std::uint32_t region) const { return regions_[region].get(); }
  // The root's region: what a descent starts from (nullptr before the trunk is installed).
  const LevelRegion* trunk() const { return regions_[0].get(); }
  std::size_t bytes(std::uint32_t region) const;
  std::size_t residentBytes() const { return residentBytes_; }

 private:
  // The level the region's next slice decodes onto: its deepest level, or a new region's base.
  OctreeLevel residentParents(std::uint32_t region) const;
  OctreeLevel baseParents(std::uint32_t region, LevelGrowth& growth) const;

  const RegionTable& table_;
  const StoreIndex& index_;
  std::vector<std::unique_ptr<LevelRegion>> regions_;
  std::vector<std::vector<std::uint16_t>> baseShownNormals_;  // per region: the normal codes its base shows
  std::size_t residentBytes_ = 0;
};

}  // namespace svo::paging
