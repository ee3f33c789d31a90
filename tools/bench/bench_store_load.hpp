// `svo bench store`'s load costs (bench_store_load.cpp): what bringing a store's voxels into the block pool
// costs per voxel on one thread, stage by stage; what storing the pool's own block bytes instead would cost
// on disk and to decompress; and what arrays per level instead of blocks would cost to decode, hold and cast.
#pragma once

#include <cstdint>
#include <vector>

#include "report.hpp"
#include "svo/store/block.hpp"
#include "svo/store/level_arrays.hpp"
#include "svo/store/store_reader.hpp"

namespace svo::tools::bench {

struct LoadCosts {
  int deepestLevel = 0;  // levels 1 to this, decoded into one tree
  std::uint64_t slices = 0, voxels = 0, leaves = 0;
  std::uint64_t storeDiskBytes = 0;  // those slices' compressed bytes
  // The stages of a pager load, each over all of the tree's voxels: read + XXH3 + zstd from the page cache,
  // decodeSlice onto the levels above, layoutBlock in either attribute layout (on the calling thread, as a
  // pager worker lays out).
  Summary read, decode, layoutRaw, layoutCompressed;
  // The alternative: the laid-out block stored as it is, zstd-compressed in slice-sized chunks.
  struct StoredBlock {
    AttributeLayout attributes = AttributeLayout::Raw;
    std::uint64_t memoryBytes = 0;
    int zstdLevel = 0;
    std::uint64_t diskBytes = 0;
    Summary decompress;
  };
  std::vector<StoredBlock> stored;
  // The other alternative: the slices decoded straight into arrays per level (level_arrays.hpp), which need
  // no layout; and the bytes either pool would hold (laid-out blocks: raw, compressed attributes).
  struct LevelArrays {
    Summary decode;
    LevelArrayBytes bytes;
  } levelArrays;
  LayoutStats blockStats[2];
  // castRay through the raw block and through the level arrays, over the same rays.
  struct Casting {
    Summary block, levels;
    std::uint64_t rays = 0, hits = 0;
  } casting;
};

// Levels 1 down to the deepest whose voxels, with those above, stay within kLoadSampleVoxels (at least level
// 1), timed `runs` times after a warm-up, the stages interleaved.
LoadCosts measureLoadCosts(const StoreReader& reader, int runs);
void printLoadCosts(const LoadCosts& costs);

}  // namespace svo::tools::bench
