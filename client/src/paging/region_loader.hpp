// What a pager worker does with one request: fetch its slices from the store, then build the region's new
// block: the region's resident levels read back from the pool (or, for a new region, its cube's voxel from
// the parent's block), the slices decoded onto them, and the whole laid out as one block.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <mutex>
#include <shared_mutex>
#include <string>
#include <vector>

#include "paging/regions.hpp"
#include "paging/scheduler.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/slice_source.hpp"

namespace svo::paging {

// A request's slices as fetched (compressed, as stored), in order, up to the first that failed.
struct FetchedChain {
  std::vector<SliceBytes> slices;
  std::uint32_t failedSlice = SliceInfo::kNoSlice;
  std::string error;
  bool transient = false;  // the source failed for a reason that may pass (SliceError::transient)
};

// Worker CPU time per stage in nanoseconds (thread CPU time), and the voxels decoded and laid out.
struct StageCounters {
  std::atomic<std::uint64_t> read{0}, assemble{0}, decode{0}, layout{0};
  std::atomic<std::uint64_t> voxelsDecoded{0}, voxelsLaidOut{0};
  WorkerCpu seconds() const;
};

class RegionLoader {
 public:
  // Workers read the pool under `poolMutex` shared; commits write it exclusively.
  RegionLoader(const SliceSource& source, RegionTable& regions, std::shared_mutex& poolMutex);

  // The request's slices from the source (I/O).
  FetchedChain fetch(const LoadRequest& request);
  // The region's new block with the fetched slices checked, decompressed and decoded onto it (CPU); `pause`
  // lets a frame have the cores between stages. A slice that fails ends the chain: the block holds the ones
  // before it.
  BuiltBlock build(const LoadRequest& request, FetchedChain&& fetched, const std::function<void()>& pause);

  std::uint64_t bytesRead() const { return bytesRead_.load(std::memory_order_relaxed); }
  WorkerCpu cpu() const { return cpu_.seconds(); }

 private:
  // The region's voxels as far as the pool holds them, level by level: the levels to deepen.
  VoxelLevels residentLevels(const Region& region) const;
  // Lays the decoded levels out as the region's block, with the slots of its entry voxels and, when the
  // region is complete, of its child regions' entry voxels.
  void layOut(const Region& region, const VoxelLevels& levels, std::uint32_t resident, BuiltBlock& out);

  const SliceSource& source_;
  const StoreIndex& index_;
  RegionTable& regions_;  // read only, but for prefaulting the pool's free pages
  std::shared_mutex& poolMutex_;
  std::mutex prefaultMutex_;  // one worker at a time prefaults the pool (BlockPool::prefault)
  std::atomic<std::uint64_t> bytesRead_{0};
  StageCounters cpu_;
};

}  // namespace svo::paging
