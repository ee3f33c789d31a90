// Per-slice byte accounting of a slice store, shared by `svo inspect` and `svo bench store`: a slice's
// decoded bytes split by part (presence bits belong to their part; split bits, valid masks and the slice head
// are hierarchy), summed per level or over the whole store.
#pragma once

#include <cstdint>

#include "svo/store/codec.hpp"

namespace svo::tools {

struct LevelSummary {
  std::uint64_t slices = 0, voxels = 0, parents = 0, contours = 0, colors = 0, normals = 0;
  std::uint64_t rawBytes = 0, diskBytes = 0;
  std::uint64_t hierarchyBytes = 0, contourBytes = 0, colorBytes = 0, normalBytes = 0;
  std::uint32_t smallestSlice = 0xFFFFFFFFu, largestSlice = 0;
};

// One slice's counts and bytes by part.
LevelSummary summarizeSlice(const SliceInfo& slice, const StoreHeader& header);
// Adds `l` into `to` (sums; smallest and largest slice kept).
void add(LevelSummary& to, const LevelSummary& l);

}  // namespace svo::tools
