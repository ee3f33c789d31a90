#include "svo/client/pager.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include <glm/geometric.hpp>

#include "paging/level_pool.hpp"
#include "paging/load_workers.hpp"
#include "paging/region_loader.hpp"
#include "paging/regions.hpp"
#include "paging/scheduler.hpp"

namespace svo {
namespace {

// Feedback samples every kFeedbackStride-th pixel in x and y (1/64 of the rays: plenty to find the visible
// slices, cheap next to the frame).
constexpr int kFeedbackStride = 8;
// The pager's next requests a source that sends ahead is told of with each view: a few times the requests in
// flight (PagerOptions::maxInFlight, 8 by default), what the next round trip can use.
constexpr std::size_t kFirstSlicesToSource = 32;

// The options, checked; the pool's budget first (RegionTable's pool takes it).
PagerOptions checked(PagerOptions options) {
  if (options.budgetBytes > kMaxBudgetBytes)
    throw std::runtime_error("budget: at most 16 GiB (got " + std::to_string(options.budgetBytes >> 20) +
                             " MiB)");
  if (options.budgetBytes < kPageBytes)
    throw std::runtime_error("budget: " + std::to_string(options.budgetBytes) + " bytes hold no 8 KB page");
  if (options.fetchThreads < 1 || options.decodeThreads < 1 || options.maxInFlight < 1 ||
      !(options.commitMillis > 0.0))
    throw std::runtime_error(
        "pager: fetchThreads, decodeThreads, maxInFlight and commitMillis must be positive");
  if (options.workerNice < 0 || options.workerNice > 19)
    throw std::runtime_error("pager: worker nice must be in [0, 19], got " +
                             std::to_string(options.workerNice));
  if (!(options.sourceRetrySeconds >= 0.0) || !(options.sourceRetryMaxSeconds >= options.sourceRetrySeconds))
    throw std::runtime_error("pager: source retry seconds must be >= 0 and at most the maximum");
  if (options.decodersDuringFrames < 0 || options.decodersDuringMovingFrames < 0)
    throw std::runtime_error("pager: decoders during frames must be >= 0, got " +
                             std::to_string(options.decodersDuringFrames) + " (still), " +
                             std::to_string(options.decodersDuringMovingFrames) + " (moving)");
  if (options.layout == PoolLayout::Levels && options.attributes.compressed())
    throw std::runtime_error("pager: a pool of level arrays holds raw attributes only");
  options.maxInFlight = std::max(options.maxInFlight, options.fetchThreads + options.decodeThreads);
  return options;
}

}  // namespace

const char* nameOf(PoolLayout layout) {
  return layout == PoolLayout::Levels ? "levels" : "blocks";
}

ViewQuery viewOf(const SceneTransform& scene, const Camera& camera, double lodPixels) {
  ViewQuery view;
  view.eye = scene.toOctree(camera.eye);
  view.pixelAngle = camera.pixelAngle();
  view.lodPixels = lodPixels;
  // Four side planes through the eye (inward normals); octree space is world space shifted and scaled
  // uniformly, so normals carry over and only the offsets change.
  const Camera::Basis b = camera.basis();
  const double tanY = b.tanHalf, tanX = b.tanHalf * b.aspect;
  const glm::dvec3 normals[4] = {
      glm::normalize(b.forward * tanX + b.right), glm::normalize(b.forward * tanX - b.right),
      glm::normalize(b.forward * tanY + b.up), glm::normalize(b.forward * tanY - b.up)};
  for (const glm::dvec3& n : normals) view.frustum.push_back({n.x, n.y, n.z, glm::dot(n, view.eye)});
  return view;
}

Pager::Pager(const std::filesystem::path& store, const PagerOptions& options)
    : Pager(openLocalStore(store), options) {}

Pager::Pager(std::shared_ptr<const SliceSource> source, const PagerOptions& options)
    : source_(std::move(source)), options_(checked(options)) {
  const std::vector<SliceInfo>& slices = index().slices();
  const std::string& name = index().name();
  regions_ = std::make_unique<paging::RegionTable>(
      slices, options_.budgetBytes, name,
      options_.layout == PoolLayout::Levels ? &index().header() : nullptr);
  scheduler_ = std::make_unique<paging::Scheduler>(
      slices, *regions_, paging::RetryBackoff{options_.sourceRetrySeconds, options_.sourceRetryMaxSeconds});
  loader_ = std::make_unique<paging::RegionLoader>(*source_, *regions_, poolMutex_, options_.attributes);

  // The trunk: the root cube's levels, synchronously. It is the first coarse image and never leaves the pool.
  const std::vector<std::uint32_t>& trunk = (*regions_)[0].slices;
  const paging::LoadRequest request{trunk.front(), std::uint32_t(trunk.size()), 1.0};
  paging::BuiltBlock built = loader_->build(request, loader_->fetch(request), {[] {}, {}});
  if (!built.error.empty()) throw std::runtime_error(built.error);
  const std::size_t needed = roomOf(built).first;
  if (needed > regions_->capacityBytes())
    throw std::runtime_error("budget: " + std::to_string(regions_->capacityBytes()) +
                             " bytes cannot hold the trunk (levels 1-" +
                             std::to_string(slices[trunk.back()].voxelLevel) + ") of " + name +
                             ", which needs " + std::to_string(needed) + " bytes");
  PagerStats ignored;
  scheduler_->want(trunk, 1.0);
  if (!commit(built, ignored)) throw std::logic_error("pager: the trunk did not commit");

  paging::LoadWorkers::Options workers;
  workers.fetchThreads = options_.fetchThreads;
  workers.decodeThreads = options_.decodeThreads;
  workers.nice = options_.workerNice;
  workers_ = std::make_unique<paging::LoadWorkers>(
      workers, [this](const paging::LoadRequest& r) { return loader_->fetch(r); },
      [this](const paging::LoadRequest& r, paging::FetchedChain&& chain, const paging::Pauses& pauses) {
        return loader_->build(r, std::move(chain), pauses);
      });
}

Pager::~Pager() = default;

Pager::FrameScope::FrameScope(Pager& pager) : pager_(pager) {
  const PagerOptions& o = pager_.options_;
  const bool moving = pager_.viewMoving_;
  pager_.workers_->frameBegins(moving ? o.decodersDuringMovingFrames : o.decodersDuringFrames, moving);
}

Pager::FrameScope::~FrameScope() {
  pager_.workers_->frameEnds();
}

BlockView Pager::trunk() const {
  if (regions_->levels()) throw std::logic_error("pager: the pool holds level arrays, not blocks");
  return regions_->view((*regions_)[0]);
}

const LevelRegion* Pager::levelTrunk() const {
  return regions_->levels() ? regions_->levels()->trunk() : nullptr;
}

Frame render(const Pager& pager, const Camera& camera, const RenderOptions& options) {
  if (const LevelRegion* trunk = pager.levelTrunk())
    return render(*trunk, pager.index().header(), pager.transform(), camera, options);
  return render(pager.trunk(), pager.transform(), camera, options);
}

// ---------------------------------------------------------------------------------------------------------
// Commits (render thread, exclusive lock).

std::pair<std::size_t, std::size_t> Pager::roomOf(const paging::BuiltBlock& built) const {
  // Level arrays grow in place by what the load adds; a block replaces its region's old one, in whole pages.
  if (regions_->levels()) return {built.growth.bytes(), 0};
  return {std::size_t(BlockPool::pagesFor(built.block.bytes().size())) * kPageBytes,
          regions_->heldBytes(built.region)};
}

bool Pager::commit(paging::BuiltBlock& built, PagerStats& stats) {
  paging::RegionTable& regions = *regions_;
  paging::Region& region = regions[built.region];
  const std::uint32_t first = regions.indexInRegion(built.slice);
  scheduler_->setInFlight({built.slice, built.requested, 0.0}, false);
  if (!built.error.empty() && built.transient) {
    scheduler_->markDeferred(built.failedSlice);
    ++stats.deferred;
    if (!std::exchange(sourceFailing_, true)) errors_.push_back(built.error + " (asking again later)");
  } else if (!built.error.empty()) {
    scheduler_->markFailed(built.failedSlice);
    ++stats.failed;
    errors_.push_back(built.error);
  }
  if (built.added == 0 || region.version != built.version || region.resident != first)
    return false;  // nothing to add, or stale: the region changed while the worker read it
  const auto [needed, freed] = roomOf(built);
  {
    double raw = 0.0;
    for (std::uint32_t k = 0; k < built.added; ++k)
      raw += index().slices()[region.slices[first + k]].rawBytes;
    scheduler_->learnBlockGrowth(raw, regions.levels() ? double(needed)
                                                       : double(built.block.bytes().size()) -
                                                             double(region.resident ? region.blockBytes : 0));
  }
  if (region.parent >= 0 && !regions[std::uint32_t(region.parent)].complete()) return false;
  // Room is made by the view's own ranking, without ray feedback: a slice's feedback stops once it is
  // resident (rays then stop at its finer voxels), so boosted slices would evict each other in turn.
  const double priority = scheduler_->viewPriority(built.slice);
  if (priority <= 0.0) {
    ++stats.cancelled;  // the view moved on while it was read
    return false;
  }
  if (needed > regions.freeBytes() + freed) {
    // Make room: leaf regions less wanted than this slice, least wanted first. Never the region itself or
    // its ancestors (the new block is built on them), never the trunk.
    std::vector<std::uint8_t> keep(regions.size(), 0);
    for (std::int32_t r = std::int32_t(built.region); r >= 0; r = regions[std::uint32_t(r)].parent)
      keep[std::size_t(r)] = 1;
    std::vector<std::uint32_t> candidates;
    for (std::uint32_t r = 1; r < regions.size(); ++r)
      if (!keep[r] && regions.evictable(r, priority)) candidates.push_back(r);
    std::sort(candidates.begin(), candidates.end(),
              [&](std::uint32_t a, std::uint32_t b) { return regions[a].priority < regions[b].priority; });
    std::size_t reclaimable = 0;
    std::size_t take = 0;
    while (take < candidates.size() && needed > regions.freeBytes() + freed + reclaimable)
      reclaimable += regions.heldBytes(candidates[take++]);
    if (needed > regions.freeBytes() + freed + reclaimable) {
      // Detail is dropped, never memory added. The chain's last slice is marked, so a shorter chain can
      // still load.
      scheduler_->markDenied(region.slices[first + built.added - 1], needed - freed);
      stats.denied += built.added;
      return false;
    }
    // Evicting a leaf can turn its parent into a leaf; this pass only evicts the ones found above, which
    // together suffice.
    for (std::size_t i = 0; i < take; ++i) stats.evicted += regions.evict(candidates[i]);
  }
  for (std::uint32_t k = 0; k < built.added; ++k) {
    scheduler_->clearDenied(region.slices[first + k]);
    scheduler_->clearDeferred(region.slices[first + k]);
  }
  sourceFailing_ = false;
  regions.install(built);
  region.priority = std::max(region.priority, priority);
  stats.loaded += built.added;
  return true;
}

// ---------------------------------------------------------------------------------------------------------
// The render thread's side.

PagerStats Pager::update(const ViewQuery& view) {
  PagerStats stats;
  viewMoving_ = lastView_ && *lastView_ != view;
  lastView_ = view;
  // 1. What the view wants, with ray feedback.
  stats.wantedRawBytes = scheduler_->rank(scheduleSlices(index(), view), *regions_);

  // 2. Commit what the workers finished, most wanted first, within the time slice.
  std::vector<paging::BuiltBlock> finished = workers_->takeDone();
  std::sort(finished.begin(), finished.end(), [&](const paging::BuiltBlock& a, const paging::BuiltBlock& b) {
    return scheduler_->wantedPriority(a.slice) > scheduler_->wantedPriority(b.slice);
  });
  const auto start = std::chrono::steady_clock::now();
  std::size_t committed = 0;
  {
    std::unique_lock lock(poolMutex_);
    for (; committed < finished.size(); ++committed) {
      const double ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
      if (committed > 0 && ms > options_.commitMillis) break;
      commit(finished[committed], stats);
    }
  }
  if (committed < finished.size())
    workers_->putBack({std::make_move_iterator(finished.begin() + std::ptrdiff_t(committed)),
                       std::make_move_iterator(finished.end())});

  // 3. Requests: the most wanted slices that can load now and fit; queued or fetched ones the view no longer
  // ranks are dropped.
  const paging::Scheduler::Candidates candidates = scheduler_->candidates();
  // Before any request goes out: a source that sends ahead (the view stream) knows the view and sends the
  // pager's most wanted slices first, ray feedback included.
  std::vector<std::uint32_t> first;
  for (std::size_t k = 0; k < std::min(candidates.requests.size(), kFirstSlicesToSource); ++k)
    first.push_back(candidates.requests[k].slice);
  source_->follow(view, options_.budgetBytes, first);
  stats.inFlight =
      std::uint32_t(workers_->edit([&](std::vector<paging::LoadRequest>& queued,
                                       std::vector<paging::LoadRequest>& fetched, std::size_t busy) {
        scheduler_->plan(queued, fetched, busy, std::size_t(options_.maxInFlight), candidates,
                         stats.requested, stats.cancelled);
      }));
  lastRequestable_ = std::uint32_t(candidates.requests.size());
  lastInFlight_ = stats.inFlight;
  lastViewPending_ = candidates.viewPending;
  lastDeferred_ = candidates.deferred;
  stats.wanted = candidates.missing;
  stats.residentBytes = regions_->usedBytes();
  return stats;
}

std::optional<std::uint32_t> Pager::refiningSlice(const Frame& frame, const Camera& camera,
                                                  const Camera::Basis& basis, int x, int y,
                                                  double lodPixels) const {
  const std::size_t i = std::size_t(y) * std::size_t(frame.width) + std::size_t(x);
  if (!(frame.voxelPixels[i] > lodPixels)) return std::nullopt;
  const SceneTransform& scene = transform();
  const std::optional<int> level = hitLevel(frame, i, camera.pixelAngle(), scene.size);
  if (!level) return std::nullopt;
  glm::dvec3 direction;
  Camera::pixelRay(camera, basis, x, y, direction);
  return regions_->sliceAt(*level + 1, scene.toOctree(camera.eye + direction * double(frame.depth[i])));
}

void Pager::feedback(const Frame& frame, const Camera& camera, double lodPixels) {
  std::unordered_map<std::uint32_t, std::uint32_t> hits;
  const Camera::Basis basis = camera.basis();
  for (int y = kFeedbackStride / 2; y < frame.height; y += kFeedbackStride)
    for (int x = kFeedbackStride / 2; x < frame.width; x += kFeedbackStride)
      if (const std::optional<std::uint32_t> slice = refiningSlice(frame, camera, basis, x, y, lodPixels))
        ++hits[*slice];
  scheduler_->setFeedback(std::move(hits));  // the latest frame's feedback replaces the last one's
}

std::vector<PixelDetail> Pager::detailMap(const Frame& frame, const Camera& camera, double lodPixels) const {
  std::vector<PixelDetail> out(std::size_t(frame.width) * std::size_t(frame.height), PixelDetail::Miss);
  const Camera::Basis basis = camera.basis();
  for (int y = 0; y < frame.height; ++y) {
    for (int x = 0; x < frame.width; ++x) {
      const std::size_t i = std::size_t(y) * std::size_t(frame.width) + std::size_t(x);
      if (!std::isfinite(frame.depth[i])) continue;
      if (!(frame.voxelPixels[i] > lodPixels) || (!frame.lodStopped.empty() && frame.lodStopped[i])) {
        out[i] = PixelDetail::AtTarget;
      } else if (const std::optional<std::uint32_t> s =
                     refiningSlice(frame, camera, basis, x, y, lodPixels)) {
        out[i] = scheduler_->inFlight(*s)                           ? PixelDetail::Loading
                 : scheduler_->denied(*s) || scheduler_->failed(*s) ? PixelDetail::NoRoom
                                                                    : PixelDetail::Waiting;
      } else {
        out[i] = PixelDetail::FinestStored;
      }
    }
  }
  return out;
}

Pager::PoolChanges Pager::takePoolChanges() {
  if (regions_->levels()) throw std::logic_error("pager: a pool of level arrays has no GPU mirror yet");
  BlockPool& pool = regions_->pool();
  if (!mirrored_) pool.trackWrittenPages(), mirrored_ = true;
  PoolChanges changes;
  changes.arena = pool.arena();
  changes.rootSlot =
      std::uint32_t(trunk().root() - reinterpret_cast<const ChildDescriptor*>(changes.arena.data()));
  changes.written = pool.takeWrittenPages();
  return changes;
}

void Pager::waitForWork(double seconds) {
  workers_->waitForWork(seconds);
}

bool Pager::converged() const {
  return lastRequestable_ == 0 && lastInFlight_ == 0 && lastDeferred_ == 0;
}

bool Pager::viewConverged() const {
  return lastViewPending_ == 0;
}

std::size_t Pager::residentBytes() const {
  return regions_->usedBytes();
}

std::size_t Pager::budgetBytes() const {
  return regions_->capacityBytes();
}

std::uint64_t Pager::bytesRead() const {
  return loader_->bytesRead();
}

WorkerCpu Pager::workerCpu() const {
  return loader_->cpu();
}

std::vector<std::uint32_t> Pager::residentSlices() const {
  return regions_->residentSlices();
}

std::vector<std::uint32_t> Pager::wantedSlices() const {
  return scheduler_->wantedSlices();
}

std::vector<std::uint32_t> Pager::failedSlices() const {
  return scheduler_->failedSlices();
}

std::vector<std::uint32_t> Pager::deferredSlices() const {
  return scheduler_->deferredSlices();
}

void Pager::checkInvariants() const {
  regions_->checkInvariants();
}

}  // namespace svo
