// What a pager worker does with one request: fetch its slices from the store, then build the region's new
// block: the region's resident levels read back from the pool (or, for a new region, its cube's voxel from
// the parent's block), the slices decoded onto them, and the whole laid out as one block.
#pragma once

#include <atomic>
#include <cstdint>
#include <ctime>
#include <functional>
#include <optional>
#include <shared_mutex>
#include <span>
#include <string>
#include <vector>

#include "paging/level_pool.hpp"
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
  std::atomic<std::uint64_t> read{0}, assemble{0}, decode{0}, layout{0}, poolPages{0};
  std::atomic<std::uint64_t> voxelsDecoded{0}, voxelsLaidOut{0};
  WorkerCpu seconds() const;
};

// Charges the calling thread's CPU time to one stage counter at a time: enter() closes the current stage and
// opens the next, the destructor closes the last (early returns included).
class StageClock {
 public:
  explicit StageClock(std::atomic<std::uint64_t>& first) : stage_(&first), start_(now()) {}
  ~StageClock() { close(); }
  StageClock(const StageClock&) = delete;
  StageClock& operator=(const StageClock&) = delete;
  void enter(std::atomic<std::uint64_t>& next) {
    close();
    stage_ = &next;
  }

 private:
  static std::uint64_t now() {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return std::uint64_t(t.tv_sec) * 1'000'000'000u + std::uint64_t(t.tv_nsec);
  }
  void close() {
    const std::uint64_t t = now();
    stage_->fetch_add(t - start_, std::memory_order_relaxed);
    start_ = t;
  }
  std::atomic<std::uint64_t>* stage_;
  std::uint64_t start_;
};

// The compressed layout's units of the descriptors read back from a block, to lay them out again unchanged:
// decoding and encoding again would drift, and would differ from the whole octree's units.
struct CarriedLevels {
  std::vector<CarriedUnit> units;
  std::vector<std::vector<std::uint32_t>> unitOf;  // per level read, per voxel: into units, or kNoCarriedUnit
  std::optional<std::pair<std::uint32_t, std::uint32_t>> shownRoot;  // TreeAttachments::shownRoot
  void carry(const ChildDescriptor* d, std::size_t level, std::size_t index);
};

// A region's voxels level by level in one array (the tree its block is laid out from), and where each level
// begins: level k below the region's cube is voxels [levelStart[k], levelStart[k + 1]).
struct RegionVoxels {
  LevelOrderTree tree;
  std::vector<std::size_t> levelStart{0};

  std::size_t levels() const { return levelStart.size() - 1; }
  std::span<SliceVoxel> level(std::size_t k) {
    return std::span(tree.voxels).subspan(levelStart[k], levelStart[k + 1] - levelStart[k]);
  }
  // The voxels appended since the last level ended become a level.
  void endLevel() { levelStart.push_back(tree.voxels.size()); }
};

// How to read a block back beyond its descriptors. In the compressed layout the units are lossy, so the
// values of the block's deepest level, which the next slice is decoded on, come from its exact attachments.
struct ReadBack {
  bool compressed = false;
  int startLevel = 0;                          // the level of the voxel the read starts at
  int frontierLevel = -1;                      // the block's deepest level
  const std::uint32_t* exactColors = nullptr;  // the first exact value the read takes
  const std::uint16_t* exactNormals = nullptr;
  std::size_t exactNext = 0;  // exact values taken so far
  CarriedLevels* carried = nullptr;
};

// Where a decode thread waits while a frame renders, when it must let the frame have the cores: between the
// stages of a load for every frame, and within a stage's long loops (decoding, layout passes, unit encoding)
// only for a moving camera's frames, which must not share the cores with a stage begun before them; a still
// view's loads matter more than its frame time.
struct Pauses {
  std::function<void()> betweenStages, withinStage;
};

class RegionLoader {
 public:
  // Workers read the pool under `poolMutex` shared; commits write it exclusively.
  RegionLoader(const SliceSource& source, RegionTable& regions, std::shared_mutex& poolMutex,
               AttributeOptions attributes);

  // The request's slices from the source (I/O).
  FetchedChain fetch(const LoadRequest& request);
  // The region's new block with the fetched slices checked, decompressed and decoded onto it (CPU); `pauses`
  // let a frame have the cores between stages and within them. A slice that fails ends the chain: the block
  // holds the ones before it.
  BuiltBlock build(const LoadRequest& request, FetchedChain&& fetched, const Pauses& pauses);

  std::uint64_t bytesRead() const { return bytesRead_.load(std::memory_order_relaxed); }
  WorkerCpu cpu() const { return cpu_.seconds(); }

 private:
  // The region's voxels as far as the pool holds them, level by level: the levels to deepen.
  // `expected`: the voxels the region's array is to hold when the request's slices are decoded onto them.
  RegionVoxels residentLevels(const Region& region, std::size_t expected, CarriedLevels& carried) const;
  // The voxels the region's slices [begin, end) add: with the cube's voxel, exactly a region's own levels (a
  // new region reads a few levels more from its parent's block).
  std::size_t voxelsOfSlices(const Region& region, std::uint32_t begin, std::uint32_t end) const;
  ReadBack readBack(const Region& region, int startLevel, std::uint32_t exactFirst,
                    CarriedLevels* carried) const;
  // Lays the decoded levels out as the region's block, with the slots of its entry voxels and, when the
  // region is complete, of its child regions' entry voxels. `pause` as LayoutOptions::betweenPasses: between
  // the layout's passes and within its unit encoding, which it then keeps on this thread.
  void layOut(const Region& region, RegionVoxels& voxels, CarriedLevels&& carried, std::uint32_t resident,
              const std::function<void()>& pause, BuiltBlock& out);
  // The compressed layout: the units carried from the pool, and the exact values of the deepest level (and
  // where each child region's begin) while another slice may be decoded on them.
  // build() where the pool holds level arrays: the slices decoded onto the region's resident levels, read
  // under `lock`, which it releases once it has them.
  void buildLevels(const LevelPool& levels, BuiltBlock& out, std::uint32_t first,
                   std::span<const SliceBytes> raw, std::shared_lock<std::shared_mutex>& lock,
                   StageClock& clock, const Pauses& pauses);
  void keepForDeepening(const Region& region, RegionVoxels& voxels, CarriedLevels&& carried,
                        std::uint32_t residentAfter, BuiltBlock& out) const;

  const SliceSource& source_;
  const StoreIndex& index_;
  RegionTable& regions_;  // read only, but for prefaulting the pool's free pages
  std::shared_mutex& poolMutex_;
  const AttributeOptions attributes_;
  std::atomic<std::uint64_t> bytesRead_{0};
  StageCounters cpu_;
};

}  // namespace svo::paging
