// The paging client (paper sec. 7, DESIGN.md): streams a store's slices into a block pool of a fixed budget
// while frames are ray cast from what is resident.
//
// A *region* is what one slice covers (a cube, or a packed run of its sub-cubes: store_types.hpp) with its
// chain of slices (one per level until it splits). Each resident region is one block in the pool holding the
// cube's voxel and its subtree (only the run's sub-cubes for a run) down to the deepest resident slice;
// loading the region's next slice rebuilds only that block. The region of the root cube is the trunk, the
// block a frame starts from. A region's block is reached from its parent region's block through link
// descriptors (format.hpp) at its *entry voxels*, the cube's voxel or each sub-cube's voxel of a run, so the
// ray caster sees one octree; relocating a block is a memcpy plus patching the links at its ends. Where an
// entry voxel lies on the parent's deepest level, the parent's block holds a stub there, rendered as a leaf
// until linked.
//
// Threads: update() and every frame run on one render thread; background workers read and decode slices and
// lay out the new blocks, reading the pool under a shared lock. update() commits finished blocks (memcpy and
// patch, under the exclusive lock) within a time slice, so the render thread never waits for disk.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <shared_mutex>
#include <string>
#include <thread>
#include <unordered_map>
#include <utility>
#include <vector>

#include "svo/client/pool.hpp"
#include "svo/client/render.hpp"
#include "svo/store/schedule.hpp"
#include "svo/store/store_reader.hpp"

namespace svo {

// The largest pool: a link's slot offset is an int32, so the arena may span at most 2^31 slots.
inline constexpr std::size_t kMaxBudgetBytes = std::size_t(1) << 34;

struct PagerOptions {
  std::size_t budgetBytes = std::size_t(256) << 20;  // the pool: a hard limit
  int ioThreads = 2;                                 // read + decode + layout workers
  int maxInFlight = 8;  // requests queued or being worked on at once (raised to ioThreads if below)
  // Wall time update() may spend committing finished blocks (memcpy + pointer patches); the rest wait for
  // the next frame. Keeps streaming frames close to resident ones (goal: p99 within 1.5x of theirs).
  double commitMillis = 2.0;
  // Nice value of the workers (0-19). At 0 a still view converges at the speed of the cores the workers get
  // whatever else runs on the machine (at 19, two busy programs on 2 cores leave them almost none); frames
  // keep their cores through workersDuringFrames instead.
  int workerNice = 0;
  // Workers that go on while a frame renders (Pager::FrameScope); the others pause at their next stage until
  // the frame ends. A moving camera's frames keep most of the cores, and a still view, rendered a few times
  // a second, leaves the workers the time between frames.
  int workersDuringFrames = 1;
};

// What one update() did. Counts are slices.
struct PagerStats {
  std::uint32_t loaded = 0, evicted = 0, requested = 0, cancelled = 0, failed = 0;
  std::uint32_t denied = 0;          // read and laid out, then dropped: no room at their priority
  std::uint32_t wanted = 0;          // slices the view wants that are not resident
  std::uint64_t wantedRawBytes = 0;  // decoded bytes of every slice the view wants, resident or not
  std::uint32_t inFlight = 0;        // queued or being worked on after the update
  std::size_t residentBytes = 0;
};

// CPU time the workers spent per stage since the pager opened (thread CPU time, so time a worker waited for
// a core is not counted), and the voxels they decoded and laid out: where streaming's time goes.
struct WorkerCpu {
  double readSeconds = 0.0;      // pread, checksum, zstd
  double assembleSeconds = 0.0;  // the region's resident levels read back from its block
  double decodeSeconds = 0.0;    // slices decoded against their parent voxels
  double layoutSeconds = 0.0;    // voxel tree, block layout, pool pages prefaulted
  std::uint64_t voxelsDecoded = 0, voxelsLaidOut = 0;
  double seconds() const { return readSeconds + assembleSeconds + decodeSeconds + layoutSeconds; }
};

// The view query of a camera: eye, pixel angle, LOD target and the frustum, in octree space.
ViewQuery viewOf(const SceneTransform& scene, const Camera& camera, double lodPixels);

class Pager {
 public:
  // Opens the store and loads the root region's first slice synchronously (the first coarse image). Throws
  // std::runtime_error when the store cannot be read or its first slice does not fit the budget.
  Pager(const std::filesystem::path& store, const PagerOptions& options = {});
  ~Pager();
  Pager(const Pager&) = delete;
  Pager& operator=(const Pager&) = delete;

  const StoreReader& store() const { return store_; }
  const SceneTransform& transform() const { return store_.header().transform; }
  // The resident octree for the next frame (valid until the next update()).
  BlockView trunk() const;

  // Between frames, on the render thread: commits finished loads (evicting the least wanted leaf regions to
  // make room), then re-prioritizes and cancels requests for `view`.
  PagerStats update(const ViewQuery& view);
  // Ray feedback from a rendered frame: pixels that stopped at a voxel wider than the view's target, on a
  // grid of every kFeedbackStride-th pixel, raise the priority of the slice that refines that voxel (in every
  // update until the next frame's feedback).
  void feedback(const Frame& frame, const Camera& camera, double lodPixels);
  // Marks a frame rendering from the pool, from construction to destruction: workers beyond
  // PagerOptions::workersDuringFrames pause at their next stage meanwhile.
  class FrameScope {
   public:
    explicit FrameScope(Pager& pager);
    ~FrameScope();
    FrameScope(const FrameScope&) = delete;
    FrameScope& operator=(const FrameScope&) = delete;

   private:
    Pager& pager_;
  };
  // Blocks until a worker finishes something or `seconds` pass (loops that converge a view; never a frame).
  void waitForWork(double seconds);
  // Nothing the last view wanted is missing (or everything missing failed or does not fit) and no request
  // is in flight.
  bool converged() const;
  // The same for the view frustum alone: nothing missing inside it can load, so the frame shows all the
  // detail it will get; slices around it (wanted for turns, ranked lower) may still be loading.
  bool viewConverged() const;

  std::size_t residentBytes() const { return pool_.usedBytes(); }
  // Compressed bytes the workers have read from the store so far.
  std::uint64_t bytesRead() const { return bytesRead_.load(std::memory_order_relaxed); }
  WorkerCpu workerCpu() const;
  std::size_t budgetBytes() const { return pool_.capacityBytes(); }
  std::vector<std::uint32_t> residentSlices() const;
  // The slices the last update's view wanted, resident or not, in directory order.
  std::vector<std::uint32_t> wantedSlices() const;
  std::vector<std::uint32_t> failedSlices() const;
  // Messages of slices that failed (checksum, decode) since the last call; each slice fails once and is never
  // requested again.
  std::vector<std::string> takeErrors() { return std::exchange(errors_, {}); }
  // Pool invariants, every link leads to its region's root descriptor, every resident non-root region is
  // linked from its parent, page headers lead to each block's info section. Throws std::logic_error.
  void checkInvariants() const;

 private:
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
    std::size_t blockBytes = 0;                         // its block's size (the pool holds it in whole pages)
    std::uint32_t rootSlot = 0;                         // the cube's voxel in its block
    EntrySlots entries;                                 // its entry voxels that have children, in its block
    std::map<std::uint32_t, EntrySlots> childSlots;     // child region -> its entry voxels in this block
    std::map<std::uint32_t, ChildDescriptor> unlinked;  // slot -> descriptor before a link replaced it
    std::uint64_t version = 0;                          // bumped by every commit or eviction
    double priority = 0.0;                              // highest view priority of its resident slices
  };
  // Consecutive slices of one region, `count` from `slice` on: a worker decodes them in turn and lays the
  // region out once, so a cold view deepens a region by several levels in one commit.
  struct Request {
    std::uint32_t slice = 0, count = 1;
    double priority = 0.0;
  };
  struct Prepared {  // a worker's new block for a region, or the error that stopped it
    std::uint32_t slice = 0, region = 0;
    std::uint32_t requested = 0;  // slices of the request
    std::uint32_t added = 0;      // slices the block adds (fewer than requested when one failed)
    std::uint64_t version = 0;    // of the region when read
    Block block;
    std::uint32_t rootSlot = 0;
    EntrySlots entries;
    std::map<std::uint32_t, EntrySlots> childSlots;
    std::uint32_t failedSlice = SliceInfo::kNoSlice;
    std::string error;
  };

  void work(int worker, std::stop_token stop);
  // `worker` < 0: the caller's own thread, never paused.
  Prepared prepare(const Request& request, int worker = -1);
  // Pauses worker `worker` while a frame renders, unless it is one of those allowed to go on.
  void waitForFrameEnd(int worker);
  bool commit(Prepared& prepared, PagerStats& stats);
  void evict(std::uint32_t region, PagerStats& stats);
  void link(std::uint32_t region);
  void relinkAll();
  bool requestable(std::uint32_t slice) const;
  std::uint32_t chainLength(std::uint32_t slice) const;
  std::uint32_t parentSlotOf(const Region& parent, std::uint32_t child, const glm::ivec3& coord) const;
  bool evictable(std::uint32_t region, double priority) const;
  void indexRoom();
  bool roomFor(std::size_t bytes, double priority, std::uint32_t region) const;
  std::size_t leastBlockGrowth(std::uint32_t slice) const;
  double leastBlockBytesPerRawByte() const;
  const ChildDescriptor* descriptorAt(const Region& region, std::uint32_t slot) const;
  ChildDescriptor* descriptorAt(Region& region, std::uint32_t slot);

  StoreReader store_;
  PagerOptions options_;
  BlockPool pool_;
  std::vector<Region> regions_;
  std::vector<std::uint32_t> regionOf_, indexInRegion_;
  std::vector<std::uint8_t> failed_;
  // Feedback lookup: (voxel level, cube level, cube) -> slice (a run's slices under each of its sub-cubes);
  // the cube levels each voxel level's keys use.
  std::unordered_map<std::uint64_t, std::uint32_t> sliceAt_;
  std::vector<std::vector<std::int32_t>> cubeLevelsOf_;
  std::unordered_map<std::uint32_t, std::uint32_t> feedbackHits_;
  std::vector<double> viewPriority_;    // per slice, the view query's rank (0 = not wanted): decides eviction
  std::vector<double> wantedPriority_;  // the same with ray feedback: decides load order
  std::vector<std::size_t> denied_;     // bytes a slice dropped for lack of room needed (0 = not dropped)
  std::vector<std::pair<double, std::size_t>> evictableRoom_;  // see indexRoom
  std::optional<double> leastBlockBytesPerRawByte_;            // smallest measured (commit)
  std::vector<std::string> errors_;
  std::vector<std::uint8_t> inView_;  // per slice: wanted and inside the view frustum
  std::uint32_t lastRequestable_ = 0, lastInFlight_ = 0, lastViewPending_ = 0;
  std::atomic<std::uint64_t> bytesRead_{0};
  // WorkerCpu's stages in nanoseconds, and its voxel counts.
  struct StageNanos {
    std::atomic<std::uint64_t> read{0}, assemble{0}, decode{0}, layout{0};
    std::atomic<std::uint64_t> voxelsDecoded{0}, voxelsLaidOut{0};
  } cpu_;

  mutable std::shared_mutex
      poolMutex_;             // workers read blocks shared; commits and evictions write exclusively
  std::mutex prefaultMutex_;  // one worker at a time prefaults the pool (BlockPool::prefault)
  mutable std::mutex queueMutex_;
  std::condition_variable_any queueReady_;
  std::condition_variable doneReady_;
  std::deque<Request> queue_;  // highest priority first
  std::vector<std::uint8_t> inFlight_;
  std::vector<Prepared> done_;
  std::uint32_t working_ = 0;
  std::mutex frameMutex_;
  std::condition_variable frameEnded_;
  bool frameRendering_ = false;
  bool stopping_ = false;  // under frameMutex_: paused workers leave
  std::vector<std::jthread> workers_;
};

}  // namespace svo
