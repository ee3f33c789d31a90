// The paging client (paper sec. 7; docs/architecture.md): streams a store's slices into a block pool of a
// fixed budget while frames are ray cast from what is resident.
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

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <shared_mutex>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "svo/client/level_raycast.hpp"
#include "svo/client/pool.hpp"
#include "svo/client/render.hpp"
#include "svo/client/slice_source.hpp"
#include "svo/store/schedule.hpp"
#include "svo/store/store_reader.hpp"

namespace svo {

// How the pool holds the resident regions: as laid-out blocks (block.hpp) that every load lays out again, or
// as arrays per level (level_raycast.hpp's LevelRegion) that a load appends its levels to. Level arrays take
// raw attributes and are cast one ray at a time after each tile's beam pass (render(const Pager&, ...)): no
// packets, GPU mirror or compressed attributes yet.
enum class PoolLayout { Blocks, Levels };
const char* nameOf(PoolLayout layout);  // "blocks", "levels"

// The largest pool: a link's slot offset is an int32, so the arena may span at most 2^31 slots.
inline constexpr std::size_t kMaxBudgetBytes = std::size_t(1) << 34;

struct PagerOptions {
  std::size_t budgetBytes = std::size_t(256) << 20;  // the pool: a hard limit
  // Threads that fetch slices from the store: a local disk needs few, a network link many waiting at once.
  int fetchThreads = 2;
  int decodeThreads = 2;  // threads that decode slices and lay out blocks (CPU)
  // Requests queued, fetching, fetched or being decoded at once (raised to the fetch plus decode threads, so
  // that none idles for want of a request).
  int maxInFlight = 8;
  // Wall time update() may spend committing finished blocks (memcpy + pointer patches); the rest wait for
  // the next frame. Keeps streaming frames close to resident ones (goal: p99 within 1.5x of theirs).
  double commitMillis = 2.0;
  // Nice value of the worker threads (0-19). At 0 a still view converges at the speed of the cores the
  // workers get whatever else runs on the machine (at 19, two busy programs on 2 cores leave them almost
  // none); frames keep their cores through decodersDuringFrames instead.
  int workerNice = 0;
  // Decode threads that go on while a frame renders (Pager::FrameScope); the others pause at their next
  // stage until the frame ends. A still view (the one the update before had too), rendered a few times a
  // second, leaves the workers the time between frames, and one decoder beside its frames brings its detail
  // sooner. A moving camera's frames keep the cores, its decoders stopping within a stage too, and its loads
  // run between frames and once it stops (chosen by the path's p99 against resident frames, svo bench stream
  // on 2 cores).
  int decodersDuringFrames = 1;
  int decodersDuringMovingFrames = 0;
  // A slice whose fetch failed for a reason that may pass (a server restarting or overloaded, a timeout: the
  // source's own retries ran out) is asked for again after this many seconds, twice as long after each
  // further failure, at most sourceRetryMaxSeconds; a corrupt slice is never asked for again. 1 s to 10 s:
  // a restarted server is used again within seconds, and a dead one costs a few requests a second.
  double sourceRetrySeconds = 1.0;
  double sourceRetryMaxSeconds = 10.0;
  // How the pool's blocks hold colors and normals (block.hpp): compressed units take about a third of the
  // bytes of uncompressed values on colored scenes, and cost encoding time as slices load.
  AttributeOptions attributes;
  PoolLayout layout = PoolLayout::Blocks;
};

// What one update() did. Counts are slices.
struct PagerStats {
  std::uint32_t loaded = 0, evicted = 0, requested = 0, cancelled = 0, failed = 0;
  std::uint32_t deferred = 0;        // fetches that failed for a reason that may pass: asked again later
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
  double layoutSeconds = 0.0;    // voxel tree, block layout
  // The pool's pages the block will be copied into, mapped on their first use: a cost of the pool's first
  // fill, bounded by the budget, which a pager that has run a while no longer pays.
  double poolPagesSeconds = 0.0;
  std::uint64_t voxelsDecoded = 0, voxelsLaidOut = 0;
  double seconds() const {
    return readSeconds + assembleSeconds + decodeSeconds + layoutSeconds + poolPagesSeconds;
  }
};

// What a pixel shows against what the store holds, for the viewer's false colors.
enum class PixelDetail : std::uint8_t {
  Miss,          // the ray hit nothing
  AtTarget,      // the ray stopped at its level-of-detail target, or at a voxel no wider
  FinestStored,  // wider, but the store has no finer level there
  Loading,       // wider; the slice that refines it is being fetched or decoded
  Waiting,       // wider; that slice is not asked for yet (or the view does not want it)
  NoRoom,        // wider; that slice does not fit the budget at its priority, or failed
};

// The view query of a camera: eye, pixel angle, LOD target and the frustum, in octree space.
ViewQuery viewOf(const SceneTransform& scene, const Camera& camera, double lodPixels);

namespace paging {
class RegionTable;
class Scheduler;
class RegionLoader;
class LoadWorkers;
struct BuiltBlock;
}  // namespace paging

class Pager {
 public:
  // Loads the root region's slices synchronously (the first coarse image). Throws std::runtime_error when
  // the store cannot be read or its first slices do not fit the budget.
  Pager(std::shared_ptr<const SliceSource> source, const PagerOptions& options = {});
  // A local store file.
  Pager(const std::filesystem::path& store, const PagerOptions& options = {});
  ~Pager();
  Pager(const Pager&) = delete;
  Pager& operator=(const Pager&) = delete;

  // The store's header and directory, and where its slices come from.
  const StoreIndex& index() const { return source_->index(); }
  const std::shared_ptr<const SliceSource>& source() const { return source_; }
  const SceneTransform& transform() const { return index().header().transform; }
  // The resident octree for the next frame (valid until the next update()), where the pool holds blocks;
  // throws std::logic_error where it holds level arrays.
  BlockView trunk() const;
  // The same where the pool holds level arrays (nullptr where it holds blocks).
  const LevelRegion* levelTrunk() const;
  PoolLayout layout() const { return options_.layout; }

  // Between frames, on the render thread: commits finished loads (evicting the least wanted leaf regions to
  // make room), then re-prioritizes and cancels requests for `view`.
  PagerStats update(const ViewQuery& view);
  // Ray feedback from a rendered frame: pixels that stopped at a voxel wider than the view's target, on a
  // grid of every kFeedbackStride-th pixel, raise the priority of the slice that refines that voxel (in every
  // update until the next frame's feedback).
  void feedback(const Frame& frame, const Camera& camera, double lodPixels);
  // Every pixel of a frame rendered from the pool classified as PixelDetail, row by row (the frame rendered
  // with RenderOptions::diagnostics tells which rays stopped at their target).
  std::vector<PixelDetail> detailMap(const Frame& frame, const Camera& camera, double lodPixels) const;
  // Marks a frame rendering from the pool, from construction to destruction: decode threads beyond
  // PagerOptions::decodersDuringFrames (decodersDuringMovingFrames where the last update's view differs from
  // the one before it) pause at their next stage meanwhile.
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
  // Nothing the last view wanted is missing (or everything missing failed or does not fit), no request is in
  // flight and no slice waits to be asked for again after a failure that may pass.
  bool converged() const;
  // The same for the view frustum alone: nothing missing inside it can load, so the frame shows all the
  // detail it will get; slices around it (wanted for turns, ranked lower) may still be loading.
  bool viewConverged() const;

  std::size_t residentBytes() const;
  std::size_t budgetBytes() const;
  // Compressed bytes the workers have read from the store so far.
  std::uint64_t bytesRead() const;
  WorkerCpu workerCpu() const;
  std::vector<std::uint32_t> residentSlices() const;
  // The slices the last update's view wanted, resident or not, in directory order.
  std::vector<std::uint32_t> wantedSlices() const;
  std::vector<std::uint32_t> failedSlices() const;
  // Slices whose last fetch failed for a reason that may pass (PagerOptions::sourceRetrySeconds) and that
  // have not loaded since.
  std::vector<std::uint32_t> deferredSlices() const;
  // Messages of slices that failed (checksum, decode) since the last call; each slice fails once and is never
  // requested again. A source that stops answering (failures that may pass) gives one message until a slice
  // loads again.
  std::vector<std::string> takeErrors() { return std::exchange(errors_, {}); }
  // For a mirror of the pool (the GPU caster's buffer), on the render thread between updates: the arena, the
  // trunk's root descriptor in it (64-bit slots from its start), and the pages written since the last call
  // (on the first, every page that holds a block).
  struct PoolChanges {
    std::span<const std::byte> arena;
    std::uint32_t rootSlot = 0;
    std::vector<BlockPool::PageRun> written;
  };
  PoolChanges takePoolChanges();
  // Pool invariants, every link leads to its region's root descriptor, every resident non-root region is
  // linked from its parent, page headers lead to each block's info section. Throws std::logic_error.
  void checkInvariants() const;

 private:
  // The pool bytes a built block needs, and those its region's old block frees when it commits.
  std::pair<std::size_t, std::size_t> roomOf(const paging::BuiltBlock& built) const;
  bool commit(paging::BuiltBlock& built, PagerStats& stats);
  // The slice that refines the voxel pixel (x, y) of `frame` stopped at, when wider than `lodPixels` and the
  // store has one.
  std::optional<std::uint32_t> refiningSlice(const Frame& frame, const Camera& camera,
                                             const Camera::Basis& basis, int x, int y,
                                             double lodPixels) const;

  std::shared_ptr<const SliceSource> source_;
  PagerOptions options_;
  // Workers read blocks shared (assembling a region's levels); commits and evictions write
  // exclusively.
  mutable std::shared_mutex poolMutex_;
  std::unique_ptr<paging::RegionTable> regions_;
  std::unique_ptr<paging::Scheduler> scheduler_;
  std::unique_ptr<paging::RegionLoader> loader_;
  std::unique_ptr<paging::LoadWorkers> workers_;  // last: its threads stop first
  std::vector<std::string> errors_;
  bool sourceFailing_ = false;  // a fetch failed for a reason that may pass, and nothing has loaded since
  bool mirrored_ = false;       // takePoolChanges was called: the pool tracks written pages
  std::optional<ViewQuery> lastView_;  // the last update's
  bool viewMoving_ = false;            // the last update's view differs from the one before it
  std::uint32_t lastRequestable_ = 0, lastInFlight_ = 0, lastViewPending_ = 0, lastDeferred_ = 0;
};

// A frame from what the pager holds resident, whichever its pool layout (render.hpp's render for blocks).
Frame render(const Pager& pager, const Camera& camera, const RenderOptions& options);

}  // namespace svo
