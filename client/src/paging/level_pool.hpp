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
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "paging/regions.hpp"
#include "svo/client/level_raycast.hpp"
#include "svo/store/level_arrays.hpp"

namespace svo::paging {

class LevelPool {
 public:
  LevelPool(const RegionTable& regions, const std::vector<SliceInfo>& slices, const StoreHeader& header);

  // The level the region's next slice decodes onto (its deepest resident level, or a new region's base),
  // with what the decoder reads of it; a new region's base's place goes to `growth`. `first` must be the
  // region's resident slices, and a new region's parent must be complete. Reads the pool.
  OctreeLevel startGrowth(std::uint32_t region, std::uint32_t first, LevelGrowth& growth) const;
  // The region's slices from `first` on (their decompressed bytes, as many as given) decoded onto
  // `parents`, startGrowth's, into `growth`. A slice that fails to decode ends the growth, which holds the
  // ones before it; its error is returned. `pause` is called between slices. Does not read the pool.
  std::optional<std::string> decode(std::uint32_t region, std::uint32_t first,
                                    std::span<const SliceBytes> raw, OctreeLevel&& parents,
                                    LevelGrowth& growth, const std::function<void()>& pause) const;
  // Both, for a caller that keeps the pool still meanwhile.
  LevelGrowth grow(std::uint32_t region, std::uint32_t first, std::span<const SliceBytes> raw,
                   std::optional<std::string>* error = nullptr) const;
  // Adds the growth to its region (creating and linking a new region to its parent).
  void install(std::uint32_t region, LevelGrowth&& growth);
  // Drops a resident region that no resident region hangs from, and its link in its parent.
  void evict(std::uint32_t region);

  const LevelRegion* region(std::uint32_t region) const { return regions_[region].get(); }
  // The root's region: what a descent starts from (nullptr before the trunk is installed).
  const LevelRegion* trunk() const { return regions_[0].get(); }
  std::size_t bytes(std::uint32_t region) const;
  std::size_t residentBytes() const { return residentBytes_; }
  bool hasColors() const { return header_.hasColors; }
  bool hasNormals() const { return header_.hasNormals; }
  // Every resident region's levels as its slices make them, linked from its parent at its base, and the
  // bytes counted. Throws std::logic_error.
  void checkInvariants() const;

 private:
  OctreeLevel baseParents(std::uint32_t region, LevelGrowth& growth) const;

  const RegionTable& table_;
  const std::vector<SliceInfo>& slices_;
  const StoreHeader& header_;
  std::vector<std::unique_ptr<LevelRegion>> regions_;
  std::vector<std::vector<std::uint16_t>> baseShownNormals_;  // per region: the normal codes its base shows
  std::size_t residentBytes_ = 0;
};

}  // namespace svo::paging
