#include "svo/client/pager.hpp"

#include <pthread.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <stdexcept>
#include <string>
#include <tuple>

#include <glm/common.hpp>
#include <glm/geometric.hpp>

namespace svo {
namespace {

// Ray feedback: a slice that rays saw stopping at too coarse a voxel ranks this many times higher
// than its distance-only priority; the distance rule cannot tell a visible cube from an occluded one.
constexpr double kFeedbackBoost = 4.0;
// Feedback samples every kFeedbackStride-th pixel in x and y (1/64 of the rays: plenty to find the visible
// slices, cheap next to the frame).
constexpr int kFeedbackStride = 8;
// Cube levels the feedback lookup key packs (16 bits per coordinate); stores never split that deep in
// practice (8^16 slices).
constexpr int kMaxKeyedCubeLevel = 16;
// A block's bytes per decoded slice byte it holds, for judging whether a chained request's block will fit
// before it is built (measured: 2.4-3.0 on the bunny's single-slice regions, 1.5 on its 8-slice trunk).
constexpr double kBlockBytesPerRawByte = 3.0;
// The least a block can grow per decoded slice byte before any block was measured: every contour and
// attribute value of the slice is in the block, and a descriptor outweighs the split bit and valid mask it
// replaces. Used to skip requests whose blocks cannot fit; measured blocks then raise it (terrain: 1.8).
constexpr double kLeastBlockBytesPerRawByte = 1.0;

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

std::uint64_t sliceKey(int voxelLevel, int cubeLevel, glm::ivec3 c) {
  return std::uint64_t(voxelLevel) << 58 | std::uint64_t(cubeLevel) << 53 | std::uint64_t(c.x) << 32 |
         std::uint64_t(c.y) << 16 | std::uint64_t(c.z);
}

int slotToward(const glm::ivec3& coord, int shift) {
  return childSlot(coord >> shift);
}

// Where a region is entered from its parent's block: the cube's voxel, or each sub-cube's voxel of a run
// (present or not), in Morton order, and their level.
std::pair<std::vector<glm::ivec3>, int> entryVoxels(int cubeLevel, glm::ivec3 cube, std::uint8_t firstSlot,
                                                    std::uint8_t lastSlot) {
  if (isWholeCube(firstSlot, lastSlot)) return {{cube}, cubeLevel};
  std::vector<glm::ivec3> out;
  for (int slot = firstSlot; slot <= lastSlot; ++slot) out.push_back(childCoord(cube, slot));
  return {out, cubeLevel + 1};
}

std::uint32_t rootValue(const BlockView& block, AttachmentType type) {
  const AttachmentEntry* e = block.attachment(type);
  return e ? e->rootValue : 0;
}

// The subtree below `start` as far as the blocks hold it, level by level in Morton order, through the
// start's children in slots [firstSlot, lastSlot] only (a run's region; its siblings may be linked to other
// blocks). `descriptor` is the start voxel's (nullptr when it has no children here). Stubs read as voxels
// without children.
VoxelLevels readSubtree(const ChildDescriptor* descriptor, const SliceVoxel& start,
                        std::uint8_t firstSlot = 0, std::uint8_t lastSlot = 7) {
  VoxelLevels levels{{start}};
  std::vector<const ChildDescriptor*> descriptors{descriptor};
  while (true) {
    std::vector<SliceVoxel> next;
    std::vector<const ChildDescriptor*> nextDescriptors;
    std::vector<SliceVoxel>& level = levels.back();
    for (std::size_t i = 0; i < level.size(); ++i) {
      const ChildDescriptor* d = descriptors[i];
      if (!d || d->isStub()) continue;
      SliceVoxel& parent = level[i];
      std::uint8_t mask = d->validMask();
      if (levels.size() == 1)
        for (int slot = 0; slot < 8; ++slot)
          if (slot < firstSlot || slot > lastSlot) mask &= std::uint8_t(~(1u << slot));
      parent.childMask = mask;
      const BlockView::Attributes colors = BlockView::attributes(d, AttachmentType::Color);
      const BlockView::Attributes normals = BlockView::attributes(d, AttachmentType::Normal);
      for (int slot = 0; slot < 8; ++slot) {
        if (!(mask >> slot & 1u)) continue;
        // Written in place: a voxel assembled aside and pushed back stalled on store forwarding.
        SliceVoxel& c = next.emplace_back();
        c.coord = childCoord(parent.coord, slot);
        const std::optional<std::uint32_t> contour = BlockView::contour(d, slot);
        c.hasContour = contour.has_value(), c.contour = contour.value_or(0);
        c.color = colors.at(slot).value_or(parent.color);
        c.normal = normals.at(slot).value_or(parent.normal);
        nextDescriptors.push_back((d->nonLeafMask() >> slot & 1u) ? BlockView::child(d, slot) : nullptr);
      }
    }
    if (next.empty()) return levels;
    levels.push_back(std::move(next));
    descriptors = std::move(nextDescriptors);
  }
}

}  // namespace

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

Pager::Pager(const std::filesystem::path& path, const PagerOptions& options)
    : store_(path), options_(options), pool_([&] {
        if (options.budgetBytes > kMaxBudgetBytes)
          throw std::runtime_error("budget: at most 16 GiB (got " +
                                   std::to_string(options.budgetBytes >> 20) + " MiB)");
        if (options.budgetBytes < kPageBytes)
          throw std::runtime_error("budget: " + std::to_string(options.budgetBytes) +
                                   " bytes hold no 8 KB page");
        return options.budgetBytes;
      }()) {
  if (options.ioThreads < 1 || options.maxInFlight < 1 || !(options.commitMillis > 0.0))
    throw std::runtime_error("pager: ioThreads, maxInFlight and commitMillis must be positive");
  if (options.workerNice < 0 || options.workerNice > 19)
    throw std::runtime_error("pager: worker nice must be in [0, 19], got " +
                             std::to_string(options.workerNice));
  if (options.workersDuringFrames < 0)
    throw std::runtime_error("pager: workers during frames must be >= 0, got " +
                             std::to_string(options.workersDuringFrames));
  // A worker never idles for want of a request slot (svo render --io-threads 16 with the default 8).
  options_.maxInFlight = std::max(options_.maxInFlight, options_.ioThreads);
  const std::vector<SliceInfo>& slices = store_.slices();
  const std::size_t n = slices.size();
  regionOf_.assign(n, 0), indexInRegion_.assign(n, 0), failed_.assign(n, 0), inFlight_.assign(n, 0);
  wantedPriority_.assign(n, 0.0), viewPriority_.assign(n, 0.0), denied_.assign(n, 0);
  inView_.assign(n, 0);
  cubeLevelsOf_.resize(std::size_t(kMaxLevels) + 2);
  std::map<std::tuple<int, int, int, int, int, int>, std::uint32_t> regionAt;  // (level, cube, run) -> region
  const auto fail = [&](std::uint32_t s, const std::string& what) {
    throw std::runtime_error(path.string() + ": slice " + std::to_string(s) + " " + what);
  };
  for (std::uint32_t s = 0; s < n; ++s) {
    const SliceInfo& info = slices[s];
    auto [it, fresh] = regionAt.try_emplace(
        {info.cubeLevel, info.cubeCoord.x, info.cubeCoord.y, info.cubeCoord.z, info.firstSlot, info.lastSlot},
        std::uint32_t(regions_.size()));
    if (fresh) {
      Region r;
      r.cubeLevel = info.cubeLevel;
      r.cubeCoord = info.cubeCoord;
      r.firstSlot = info.firstSlot, r.lastSlot = info.lastSlot;
      if (info.parentSlice == SliceInfo::kNoSlice) {
        if (!regions_.empty()) fail(s, "starts a second root region");
      } else {
        if (info.parentSlice >= s) fail(s, "comes before its parent slice");
        r.parent = std::int32_t(regionOf_[info.parentSlice]);
        const Region& p = regions_[std::size_t(r.parent)];
        if (p.slices.back() != info.parentSlice || !sliceWithin(info, slices[info.parentSlice]))
          fail(s, "does not continue its parent region's last slice");
        regions_[std::size_t(r.parent)].children.push_back(std::uint32_t(regions_.size()));
      }
      if (regions_.empty() && info.parentSlice != SliceInfo::kNoSlice) fail(s, "has no root region");
      regions_.push_back(std::move(r));
    }
    Region& r = regions_[it->second];
    if (!r.slices.empty() &&
        (info.parentSlice != r.slices.back() || info.voxelLevel != slices[r.slices.back()].voxelLevel + 1))
      fail(s, "does not follow the previous slice of its cube");
    regionOf_[s] = it->second;
    indexInRegion_[s] = std::uint32_t(r.slices.size());
    r.slices.push_back(s);
    const auto [keys, keyLevel] = entryVoxels(info.cubeLevel, info.cubeCoord, info.firstSlot, info.lastSlot);
    if (keyLevel <= kMaxKeyedCubeLevel && info.voxelLevel <= kMaxLevels) {
      for (const glm::ivec3& key : keys) sliceAt_[sliceKey(info.voxelLevel, keyLevel, key)] = s;
      auto& levels = cubeLevelsOf_[std::size_t(info.voxelLevel)];
      if (std::find(levels.begin(), levels.end(), keyLevel) == levels.end()) levels.push_back(keyLevel);
    }
  }
  if (regions_.empty()) throw std::runtime_error(path.string() + ": the store has no slices");

  // The trunk: the root cube's levels, synchronously. It is the first coarse image and never leaves the pool.
  const std::vector<std::uint32_t>& trunk = regions_[0].slices;
  Prepared prepared = prepare({trunk.front(), std::uint32_t(trunk.size()), 1.0});
  if (!prepared.error.empty()) throw std::runtime_error(prepared.error);
  const std::size_t needed = prepared.block.bytes().size();
  if (needed > pool_.capacityBytes())
    throw std::runtime_error("budget: " + std::to_string(pool_.capacityBytes()) +
                             " bytes cannot hold the trunk (levels 1-" +
                             std::to_string(store_.slices()[trunk.back()].voxelLevel) + ") of " +
                             path.string() + ", which needs " + std::to_string(needed) + " bytes");
  PagerStats ignored;
  for (const std::uint32_t slice : trunk) wantedPriority_[slice] = viewPriority_[slice] = 1.0;
  if (!commit(prepared, ignored)) throw std::logic_error("pager: the trunk did not commit");
  for (int i = 0; i < options.ioThreads; ++i)
    workers_.emplace_back([this, i](std::stop_token t) { work(i, t); });
}

Pager::~Pager() {
  for (auto& w : workers_) w.request_stop();
  {
    std::lock_guard lock(frameMutex_);
    stopping_ = true;
  }
  frameEnded_.notify_all();
  queueReady_.notify_all();
  workers_.clear();  // joins
}

Pager::FrameScope::FrameScope(Pager& pager) : pager_(pager) {
  std::lock_guard lock(pager_.frameMutex_);
  pager_.frameRendering_ = true;
}

Pager::FrameScope::~FrameScope() {
  {
    std::lock_guard lock(pager_.frameMutex_);
    pager_.frameRendering_ = false;
  }
  pager_.frameEnded_.notify_all();
}

void Pager::waitForFrameEnd(int worker) {
  if (worker < options_.workersDuringFrames) return;
  std::unique_lock lock(frameMutex_);
  frameEnded_.wait(lock, [&] { return !frameRendering_ || stopping_; });
}

BlockView Pager::trunk() const {
  return BlockView::unchecked(pool_.data(regions_[0].block), pool_.size(regions_[0].block));
}

const ChildDescriptor* Pager::descriptorAt(const Region& region, std::uint32_t slot) const {
  return reinterpret_cast<const ChildDescriptor*>(pool_.data(region.block)) + slot;
}
ChildDescriptor* Pager::descriptorAt(Region& region, std::uint32_t slot) {
  return reinterpret_cast<ChildDescriptor*>(pool_.data(region.block)) + slot;
}

// ---------------------------------------------------------------------------------------------------------
// Workers.

void Pager::work(int worker, std::stop_token stop) {
  pthread_setname_np(pthread_self(), "svo-pager");  // tells the workers apart in top, perf and gdb
  // Linux nice values are per thread: a positive one yields the cores to the render threads (best effort; an
  // unprivileged process may always lower its own priority).
  if (options_.workerNice != 0) setpriority(PRIO_PROCESS, id_t(::syscall(SYS_gettid)), options_.workerNice);
  while (true) {
    Request request;
    {
      std::unique_lock lock(queueMutex_);
      if (!queueReady_.wait(lock, stop, [&] { return !queue_.empty(); })) return;
      request = queue_.front();
      queue_.pop_front();
      ++working_;
    }
    Prepared prepared = prepare(request, worker);
    {
      std::lock_guard lock(queueMutex_);
      --working_;
      done_.push_back(std::move(prepared));
    }
    doneReady_.notify_all();
  }
}

Pager::Prepared Pager::prepare(const Request& request, int worker) {
  Prepared out;
  out.slice = request.slice;
  out.region = regionOf_[request.slice];
  out.requested = request.count;
  const Region& region = regions_[out.region];  // its slice list never changes: no lock needed
  const std::uint32_t first = indexInRegion_[request.slice];
  const auto fail = [&](std::uint32_t slice, const std::string& what) {
    out.failedSlice = slice;
    out.error = store_.path().string() + ": slice " + std::to_string(slice) + ": " + what;
  };
  // Disk, checksum and zstd, no lock held; a failed slice ends the chain, the ones before it still load.
  StageClock clock(cpu_.read);
  std::vector<SliceBytes> raw;
  for (std::uint32_t k = 0; k < request.count; ++k) {
    const std::uint32_t slice = region.slices[first + k];
    waitForFrameEnd(worker);
    try {
      raw.push_back(store_.readSlice(slice));
      bytesRead_.fetch_add(store_.slices()[slice].compressedBytes, std::memory_order_relaxed);
    } catch (const std::exception& e) {
      out.error = e.what();
      out.failedSlice = slice;
      break;
    }
  }
  if (raw.empty()) return out;

  waitForFrameEnd(worker);
  clock.enter(cpu_.assemble);
  std::shared_lock lock(poolMutex_);
  out.version = region.version;
  const std::uint32_t resident = region.resident;
  if (resident != first) return out;  // stale: commit drops it
  const StoreHeader& header = store_.header();
  VoxelLevels levels;
  try {
    if (region.resident > 0) {
      // Deepen: the region's own block, more levels.
      const BlockView view = BlockView::unchecked(pool_.data(region.block), pool_.size(region.block));
      levels = readSubtree(descriptorAt(region, region.rootSlot),
                           {region.cubeCoord, 0, false, 0, rootValue(view, AttachmentType::Color),
                            rootValue(view, AttachmentType::Normal)});
    } else if (region.parent < 0) {
      levels = {{{glm::ivec3(0), 0, false, 0, header.rootColor, header.rootNormal}}};
    } else {
      // A new region: its cube's voxel and subtree from the parent region's block.
      const Region& parent = regions_[std::size_t(region.parent)];
      if (parent.resident != parent.slices.size()) return out;  // stale
      const BlockView view = BlockView::unchecked(pool_.data(parent.block), pool_.size(parent.block));
      SliceVoxel voxel{parent.cubeCoord,
                       0,
                       false,
                       0,
                       rootValue(view, AttachmentType::Color),
                       rootValue(view, AttachmentType::Normal)};
      const ChildDescriptor* d = descriptorAt(parent, parent.rootSlot);
      for (int level = parent.cubeLevel + 1; level <= region.cubeLevel; ++level) {
        const int slot = slotToward(region.cubeCoord, region.cubeLevel - level);
        if (!d || d->isStub() || !(d->validMask() >> slot & 1u))
          throw std::runtime_error("its cube's voxel is not in the parent region");
        voxel.coord = childCoord(voxel.coord, slot);
        // Its contour too: the store predicts its children's contours from it.
        const std::optional<std::uint32_t> contour = BlockView::contour(d, slot);
        voxel.hasContour = contour.has_value(), voxel.contour = contour.value_or(0);
        if (auto v = BlockView::attribute(d, slot, AttachmentType::Color)) voxel.color = *v;
        if (auto v = BlockView::attribute(d, slot, AttachmentType::Normal)) voxel.normal = *v;
        d = (d->nonLeafMask() >> slot & 1u) ? BlockView::child(d, slot) : nullptr;
      }
      levels = readSubtree(d, voxel, region.firstSlot, region.lastSlot);
    }
  } catch (const std::exception& e) {
    fail(request.slice, e.what());
    return out;
  }
  // The pool is read; decoding and layout need only this copy, so commits need not wait for them.
  lock.unlock();
  clock.enter(cpu_.decode);
  for (std::uint32_t k = 0; k < raw.size(); ++k) {
    const std::uint32_t slice = region.slices[first + k];
    waitForFrameEnd(worker);
    try {
      if (region.cubeLevel + int(levels.size()) != store_.slices()[slice].voxelLevel)
        throw std::runtime_error("the resident levels do not end above it");
      std::vector<SliceVoxel> added;
      store_.decodeSlice(slice, raw[k], levels.back(), added);
      cpu_.voxelsDecoded.fetch_add(added.size(), std::memory_order_relaxed);
      levels.push_back(std::move(added));
      ++out.added;
    } catch (const std::exception& e) {
      fail(slice, e.what());
      break;
    }
  }
  if (out.added == 0) return out;

  waitForFrameEnd(worker);
  clock.enter(cpu_.layout);
  try {
    VoxelTree tree = treeOfLevels(levels, header.hasColors, header.hasNormals);
    cpu_.voxelsLaidOut.fetch_add(tree.voxels.size(), std::memory_order_relaxed);
    std::vector<std::size_t> levelStart{0};
    for (const auto& l : levels) levelStart.push_back(levelStart.back() + l.size());
    // The record of voxel `coord` at `depth` below the cube, or nullopt.
    const auto recordAt = [&](std::size_t depth, const glm::ivec3& coord) -> std::optional<std::size_t> {
      if (depth >= levels.size()) return std::nullopt;
      const auto& level = levels[depth];
      const auto it =
          std::lower_bound(level.begin(), level.end(), coord,
                           [](const SliceVoxel& v, const glm::ivec3& k) { return mortonLess(v.coord, k); });
      if (it == level.end() || it->coord != coord) return std::nullopt;
      return levelStart[depth] + std::size_t(it - level.begin());
    };
    // Completing the region: its child regions' entry voxels get descriptors to link them by (stubs where
    // the voxel has no children here).
    std::map<std::uint32_t, std::vector<std::pair<glm::ivec3, std::size_t>>> childRecords;
    if (resident + out.added == region.slices.size()) {
      for (const std::uint32_t child : region.children) {
        const Region& c = regions_[child];
        const auto [coords, level] = entryVoxels(c.cubeLevel, c.cubeCoord, c.firstSlot, c.lastSlot);
        auto& records = childRecords[child];
        for (const glm::ivec3& coord : coords) {
          const auto record = recordAt(std::size_t(level - region.cubeLevel), coord);
          if (!record) continue;  // a sub-cube of the run without voxels
          if (tree.voxels[*record].childMask == 0) tree.voxels[*record].stub = true;
          records.push_back({coord, *record});
        }
        if (records.empty()) throw std::runtime_error("a child region's voxels are missing");
      }
    }
    // Its own entry voxels that have children, which the parent's links lead to.
    std::vector<std::pair<glm::ivec3, std::size_t>> entryRecords;
    const auto [coords, level] =
        entryVoxels(region.cubeLevel, region.cubeCoord, region.firstSlot, region.lastSlot);
    for (const glm::ivec3& coord : coords)
      if (const auto record = recordAt(std::size_t(level - region.cubeLevel), coord);
          record && tree.voxels[*record].childMask != 0)
        entryRecords.push_back({coord, *record});
    std::vector<std::uint32_t> slotOf;
    LayoutOptions layout;
    layout.inheritEqualOnly = true;  // decoded slices: the store already decided what inherits
    out.block = layoutBlock(tree, layout, nullptr, &slotOf);
    out.rootSlot = out.block.view().info().rootSlot;
    for (const auto& [coord, record] : entryRecords) out.entries.push_back({coord, slotOf[record]});
    for (const auto& [child, records] : childRecords)
      for (const auto& [coord, record] : records) out.childSlots[child].push_back({coord, slotOf[record]});
  } catch (const std::exception& e) {
    fail(region.slices[first + out.added - 1], e.what());
    out.added = 0;
    out.block = Block();
    return out;
  }
  // The pages the commit will most likely copy the block into, mapped here rather than on the render thread.
  std::shared_lock poolShared(poolMutex_);  // no commit beside it
  std::lock_guard prefaulting(prefaultMutex_);
  pool_.prefault(out.block.bytes().size());
  return out;
}

// ---------------------------------------------------------------------------------------------------------
// Commits, links and eviction (render thread, exclusive lock).

// The parent's slot of `coord`, one of a child region's entry voxels.
std::uint32_t Pager::parentSlotOf(const Region& parent, std::uint32_t child, const glm::ivec3& coord) const {
  const auto slots = parent.childSlots.find(child);
  if (slots != parent.childSlots.end())
    for (const auto& [c, slot] : slots->second)
      if (c == coord) return slot;
  throw std::logic_error("pager: a region's entry voxel has no slot in its parent");
}

void Pager::link(std::uint32_t index) {
  const Region& region = regions_[index];
  Region& parent = regions_[std::size_t(region.parent)];
  for (const auto& [coord, slot] : region.entries) {
    const std::uint32_t parentSlot = parentSlotOf(parent, index, coord);
    ChildDescriptor* at = descriptorAt(parent, parentSlot);
    parent.unlinked.try_emplace(parentSlot, *at);
    const ChildDescriptor* target = descriptorAt(region, slot);
    *at = ChildDescriptor::link(std::int32_t(target - at));
  }
}

void Pager::relinkAll() {
  for (std::uint32_t r = 1; r < regions_.size(); ++r)
    if (regions_[r].resident) link(r);
}

void Pager::evict(std::uint32_t index, PagerStats& stats) {
  Region& region = regions_[index];
  Region& parent = regions_[std::size_t(region.parent)];
  for (const auto& [coord, slot] : region.entries) {
    const std::uint32_t parentSlot = parentSlotOf(parent, index, coord);
    *descriptorAt(parent, parentSlot) = parent.unlinked.at(parentSlot);
    parent.unlinked.erase(parentSlot);
  }
  pool_.erase(region.block);
  stats.evicted += region.resident;
  region.resident = 0;
  ++region.version;
}

bool Pager::commit(Prepared& prepared, PagerStats& stats) {
  Region& region = regions_[prepared.region];
  const std::uint32_t first = indexInRegion_[prepared.slice];
  for (std::uint32_t k = 0; k < prepared.requested; ++k) inFlight_[region.slices[first + k]] = 0;
  if (!prepared.error.empty()) {
    failed_[prepared.failedSlice] = 1;
    ++stats.failed;
    errors_.push_back(prepared.error);
  }
  if (prepared.added == 0 || region.version != prepared.version || region.resident != first)
    return false;  // nothing to add, or stale: the region changed while the worker read it
  const std::size_t needed = std::size_t(BlockPool::pagesFor(prepared.block.bytes().size())) * kPageBytes;
  const std::size_t freed = region.resident ? pool_.size(region.block) : 0;
  {
    double raw = 0.0;
    for (std::uint32_t k = 0; k < prepared.added; ++k)
      raw += store_.slices()[region.slices[first + k]].rawBytes;
    const double grown =
        double(prepared.block.bytes().size()) - double(region.resident ? region.blockBytes : 0);
    if (raw > 0.0 && grown > 0.0)
      leastBlockBytesPerRawByte_ = std::min(leastBlockBytesPerRawByte_.value_or(INFINITY), grown / raw);
  }
  if (region.parent >= 0 &&
      regions_[std::size_t(region.parent)].resident != regions_[std::size_t(region.parent)].slices.size())
    return false;
  // Room is made by the view's own ranking, without ray feedback: a slice's feedback stops once it is
  // resident (rays then stop at its finer voxels), so boosted slices would evict each other in turn.
  const double priority = viewPriority_[prepared.slice];
  if (priority <= 0.0) {
    ++stats.cancelled;  // the view moved on while it was read
    return false;
  }
  if (needed > pool_.freeBytes() + freed) {
    // Make room: leaf regions less wanted than this slice, least wanted first. Never the region itself or
    // its ancestors (the new block is built on them), never the trunk.
    std::vector<std::uint8_t> keep(regions_.size(), 0);
    for (std::int32_t r = std::int32_t(prepared.region); r >= 0; r = regions_[std::size_t(r)].parent)
      keep[std::size_t(r)] = 1;
    std::vector<std::uint32_t> candidates;
    for (std::uint32_t r = 1; r < regions_.size(); ++r)
      if (!keep[r] && evictable(r, priority)) candidates.push_back(r);
    std::sort(candidates.begin(), candidates.end(),
              [&](std::uint32_t a, std::uint32_t b) { return regions_[a].priority < regions_[b].priority; });
    std::size_t reclaimable = 0;
    std::size_t take = 0;
    while (take < candidates.size() && needed > pool_.freeBytes() + freed + reclaimable)
      reclaimable += pool_.size(regions_[candidates[take++]].block);
    if (needed > pool_.freeBytes() + freed + reclaimable) {
      // Detail is dropped, never memory added. The chain's last slice is marked, so a shorter chain can
      // still load.
      denied_[region.slices[first + prepared.added - 1]] = needed - freed;
      stats.denied += prepared.added;
      return false;
    }
    // Evicting a leaf can turn its parent into a leaf; this pass only evicts the ones found above, which
    // together suffice.
    for (std::size_t i = 0; i < take; ++i) evict(candidates[i], stats);
  }
  if (region.resident) pool_.erase(region.block);
  bool moved = false;
  const auto id =
      pool_.insert(std::span<const std::byte>(prepared.block.bytes().data(), prepared.block.bytes().size()),
                   [&](BlockPool::BlockId) { moved = true; });
  if (!id) throw std::logic_error("pager: the pool refused a block that fits");
  region.block = *id;
  region.blockBytes = prepared.block.bytes().size();
  region.rootSlot = prepared.rootSlot;
  region.entries = std::move(prepared.entries);
  region.childSlots = std::move(prepared.childSlots);
  region.unlinked.clear();
  for (std::uint32_t k = 0; k < prepared.added; ++k) denied_[region.slices[first + k]] = 0;
  region.resident += prepared.added;
  ++region.version;
  region.priority = std::max(region.priority, priority);
  if (moved) {
    relinkAll();
  } else if (region.parent >= 0) {
    link(prepared.region);
  }
  stats.loaded += prepared.added;
  return true;
}

// ---------------------------------------------------------------------------------------------------------
// The render thread's side.

// A resident region that no resident region hangs from, less wanted than `priority`; never the trunk.
bool Pager::evictable(std::uint32_t index, double priority) const {
  const Region& r = regions_[index];
  return index != 0 && r.resident && r.priority < priority &&
         std::none_of(r.children.begin(), r.children.end(),
                      [&](std::uint32_t k) { return regions_[k].resident != 0; });
}

// The evictable leaf regions by priority with their running byte sums, for roomFor (evictable() with the
// priority test left to the lookup).
void Pager::indexRoom() {
  evictableRoom_.clear();
  for (std::uint32_t r = 1; r < regions_.size(); ++r)
    if (evictable(r, INFINITY))
      evictableRoom_.push_back({regions_[r].priority, pool_.size(regions_[r].block)});
  std::sort(evictableRoom_.begin(), evictableRoom_.end());
  for (std::size_t i = 1; i < evictableRoom_.size(); ++i)
    evictableRoom_[i].second += evictableRoom_[i - 1].second;
}

// Whether `bytes` more could be made room for at `priority` for a block of `region`: free pages plus the leaf
// regions less wanted (as indexed by indexRoom), less the region and its parent, which commit() keeps.
bool Pager::roomFor(std::size_t bytes, double priority, std::uint32_t region) const {
  const auto less = std::lower_bound(evictableRoom_.begin(), evictableRoom_.end(),
                                     std::pair<double, std::size_t>(priority, 0));
  std::size_t room = pool_.freeBytes() + (less == evictableRoom_.begin() ? 0 : std::prev(less)->second);
  const auto kept = [&](std::uint32_t r) {
    if (evictable(r, priority)) room -= std::min(room, pool_.size(regions_[r].block));
  };
  kept(region);
  if (regions_[region].parent >= 0) kept(std::uint32_t(regions_[region].parent));
  return room >= bytes;
}

// Decoded slice bytes to block bytes, at least: the smallest ratio measured, or the prior before any.
double Pager::leastBlockBytesPerRawByte() const {
  return leastBlockBytesPerRawByte_.value_or(kLeastBlockBytesPerRawByte);
}

// The least a slice's request adds to the pool: what it needed when last dropped for lack of room, or its
// decoded bytes at the smallest block growth per decoded byte measured so far. A request that cannot get
// that much room is not made: reading, decoding and laying out a block that is then dropped takes the
// cores from the frames and delays convergence (20M terrain close-up at 64 MiB: 61 MiB read to converge
// before this check, 36 MiB after).
std::size_t Pager::leastBlockGrowth(std::uint32_t slice) const {
  const Region& region = regions_[regionOf_[slice]];
  const std::size_t bytes =
      (region.resident ? region.blockBytes : 0) +
      std::size_t(leastBlockBytesPerRawByte() * double(store_.slices()[slice].rawBytes));
  const std::size_t pages = std::size_t(BlockPool::pagesFor(bytes)) * kPageBytes;
  const std::size_t held = region.resident ? pool_.size(region.block) : 0;
  return std::max(denied_[slice], pages > held ? pages - held : 0);
}

// How many of the region's slices from `slice` on one request takes: the following ones too while the view
// wants them and the grown block would still fit the free pages (a chain never evicts to make room for its
// tail).
std::uint32_t Pager::chainLength(std::uint32_t slice) const {
  const Region& region = regions_[regionOf_[slice]];
  double estimate = (region.resident ? double(pool_.size(region.block)) : 0.0) +
                    kBlockBytesPerRawByte * store_.slices()[slice].rawBytes;
  std::uint32_t count = 1;
  for (std::uint32_t i = indexInRegion_[slice] + 1; i < region.slices.size(); ++i, ++count) {
    const std::uint32_t s = region.slices[i];
    estimate += kBlockBytesPerRawByte * store_.slices()[s].rawBytes;
    if (viewPriority_[s] <= 0.0 || failed_[s] || denied_[s] > pool_.freeBytes() ||
        estimate > double(pool_.freeBytes()))
      break;
  }
  return count;
}

bool Pager::requestable(std::uint32_t slice) const {
  if (failed_[slice] || inFlight_[slice]) return false;
  const Region& region = regions_[regionOf_[slice]];
  if (region.resident != indexInRegion_[slice]) return false;
  if (region.resident == 0 && region.parent >= 0) {
    const Region& parent = regions_[std::size_t(region.parent)];
    if (parent.resident != parent.slices.size()) return false;
  }
  return true;
}

PagerStats Pager::update(const ViewQuery& view) {
  PagerStats stats;
  const std::size_t n = store_.slices().size();
  // 1. What the view wants, with ray feedback.
  std::fill(wantedPriority_.begin(), wantedPriority_.end(), 0.0);
  std::fill(viewPriority_.begin(), viewPriority_.end(), 0.0);
  std::fill(inView_.begin(), inView_.end(), 0);
  for (const SliceRequest& r : scheduleSlices(store_.slices(), view)) {
    stats.wantedRawBytes += store_.slices()[r.slice].rawBytes;
    viewPriority_[r.slice] = r.priority;
    inView_[r.slice] = r.inFrustum;
    wantedPriority_[r.slice] = r.priority * (feedbackHits_.count(r.slice) ? kFeedbackBoost : 1.0);
  }
  for (Region& r : regions_) {
    r.priority = 0.0;
    for (std::uint32_t k = 0; k < r.resident; ++k)
      r.priority = std::max(r.priority, viewPriority_[r.slices[k]]);
  }

  // 2. Commit what the workers finished, most wanted first, within the time slice.
  std::vector<Prepared> finished;
  {
    std::lock_guard lock(queueMutex_);
    finished.swap(done_);
  }
  std::sort(finished.begin(), finished.end(), [&](const Prepared& a, const Prepared& b) {
    return wantedPriority_[a.slice] > wantedPriority_[b.slice];
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
  if (committed < finished.size()) {
    std::lock_guard lock(queueMutex_);
    for (std::size_t i = committed; i < finished.size(); ++i) done_.push_back(std::move(finished[i]));
  }

  // 3. Requests: the most wanted slices that can load now and fit; queued ones the view no longer ranks are
  // dropped.
  indexRoom();
  std::vector<SliceRequest> candidates;
  std::uint32_t missing = 0, viewPending = 0;
  for (std::uint32_t s = 0; s < n; ++s) {
    if (wantedPriority_[s] <= 0.0 || failed_[s]) continue;
    const Region& region = regions_[regionOf_[s]];
    if (region.resident > indexInRegion_[s]) continue;
    ++missing;
    const bool candidate = requestable(s) && roomFor(leastBlockGrowth(s), viewPriority_[s], regionOf_[s]);
    if (candidate) candidates.push_back({s, wantedPriority_[s], 0.0, true});
    viewPending += inView_[s] && (candidate || inFlight_[s]);
  }
  std::sort(candidates.begin(), candidates.end(),
            [](const SliceRequest& a, const SliceRequest& b) { return a.priority > b.priority; });
  {
    std::lock_guard lock(queueMutex_);
    // Re-rank what is queued with this view's priorities; what it no longer wants is cancelled.
    const auto setInFlight = [&](const Request& q, std::uint8_t value) {
      const Region& region = regions_[regionOf_[q.slice]];
      for (std::uint32_t k = 0; k < q.count; ++k)
        inFlight_[region.slices[indexInRegion_[q.slice] + k]] = value;
    };
    std::vector<Request> keep;
    for (const Request& q : queue_) {
      if (wantedPriority_[q.slice] > 0.0) {
        keep.push_back({q.slice, q.count, wantedPriority_[q.slice]});
      } else {
        setInFlight(q, 0);
        stats.cancelled += q.count;
      }
    }
    // What the requests in flight will take, at least: a new request must fit beside them, or several
    // requests that each fit alone are read and laid out only for the later ones to be dropped.
    const double perRawByte = leastBlockBytesPerRawByte();
    std::size_t reserved = 0;
    for (std::uint32_t s = 0; s < n; ++s)
      if (inFlight_[s]) reserved += std::size_t(perRawByte * double(store_.slices()[s].rawBytes));
    for (const SliceRequest& c : candidates) {
      if (keep.size() + working_ + done_.size() >= std::size_t(options_.maxInFlight)) break;
      const std::size_t growth = leastBlockGrowth(c.slice);
      if (!roomFor(reserved + growth, viewPriority_[c.slice], regionOf_[c.slice])) continue;
      reserved += growth;
      keep.push_back({c.slice, chainLength(c.slice), c.priority});
      setInFlight(keep.back(), 1);
      stats.requested += keep.back().count;
    }
    std::sort(keep.begin(), keep.end(),
              [](const Request& a, const Request& b) { return a.priority > b.priority; });
    // Over the limit after re-ranking: the least wanted wait for a later update.
    while (keep.size() + working_ + done_.size() > std::size_t(options_.maxInFlight) && !keep.empty()) {
      setInFlight(keep.back(), 0);
      stats.cancelled += keep.back().count;
      keep.pop_back();
    }
    queue_.assign(keep.begin(), keep.end());
    stats.inFlight = std::uint32_t(queue_.size() + working_ + done_.size());
  }
  queueReady_.notify_all();
  lastRequestable_ = std::uint32_t(candidates.size());
  lastInFlight_ = stats.inFlight;
  lastViewPending_ = viewPending;
  stats.wanted = missing;
  stats.residentBytes = pool_.usedBytes();
  return stats;
}

void Pager::feedback(const Frame& frame, const Camera& camera, double lodPixels) {
  feedbackHits_.clear();  // the latest frame's feedback replaces the last one's
  const SceneTransform& scene = transform();
  const Camera::Basis basis = camera.basis();
  for (int y = kFeedbackStride / 2; y < frame.height; y += kFeedbackStride) {
    for (int x = kFeedbackStride / 2; x < frame.width; x += kFeedbackStride) {
      const std::size_t i = std::size_t(y) * std::size_t(frame.width) + std::size_t(x);
      const double depth = frame.depth[i];
      if (!std::isfinite(depth) || !(frame.voxelPixels[i] > lodPixels)) continue;
      glm::dvec3 direction;
      Camera::pixelRay(camera, basis, x, y, direction);
      const glm::dvec3 p = scene.toOctree(camera.eye + direction * depth);
      const double voxelSize = frame.voxelPixels[i] * depth * camera.pixelAngle() / scene.size;
      const int level = int(std::lround(-std::log2(voxelSize)));
      if (level < 0 || level + 1 > kMaxLevels) continue;
      for (const std::int32_t cubeLevel : cubeLevelsOf_[std::size_t(level + 1)]) {
        const double cells = std::ldexp(1.0, cubeLevel);
        const glm::ivec3 cube =
            glm::clamp(glm::ivec3(glm::floor((p - 1.0) * cells)), glm::ivec3(0), glm::ivec3(int(cells) - 1));
        const auto it = sliceAt_.find(sliceKey(level + 1, cubeLevel, cube));
        if (it != sliceAt_.end()) {
          ++feedbackHits_[it->second];
          break;
        }
      }
    }
  }
}

void Pager::waitForWork(double seconds) {
  std::unique_lock lock(queueMutex_);
  doneReady_.wait_for(lock, std::chrono::duration<double>(seconds), [&] { return !done_.empty(); });
}

bool Pager::converged() const {
  return lastRequestable_ == 0 && lastInFlight_ == 0;
}

bool Pager::viewConverged() const {
  return lastViewPending_ == 0;
}

WorkerCpu Pager::workerCpu() const {
  const auto seconds = [](const std::atomic<std::uint64_t>& nanos) {
    return double(nanos.load(std::memory_order_relaxed)) * 1e-9;
  };
  return {seconds(cpu_.read),
          seconds(cpu_.assemble),
          seconds(cpu_.decode),
          seconds(cpu_.layout),
          cpu_.voxelsDecoded.load(std::memory_order_relaxed),
          cpu_.voxelsLaidOut.load(std::memory_order_relaxed)};
}

std::vector<std::uint32_t> Pager::residentSlices() const {
  std::vector<std::uint32_t> out;
  for (const Region& r : regions_) out.insert(out.end(), r.slices.begin(), r.slices.begin() + r.resident);
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<std::uint32_t> Pager::wantedSlices() const {
  std::vector<std::uint32_t> out;
  for (std::uint32_t s = 0; s < viewPriority_.size(); ++s)
    if (viewPriority_[s] > 0.0) out.push_back(s);
  return out;
}

std::vector<std::uint32_t> Pager::failedSlices() const {
  std::vector<std::uint32_t> out;
  for (std::uint32_t s = 0; s < failed_.size(); ++s)
    if (failed_[s]) out.push_back(s);
  return out;
}

void Pager::checkInvariants() const {
  const auto fail = [](const std::string& what) { throw std::logic_error("pager invariant: " + what); };
  pool_.check();
  if (pool_.usedBytes() > pool_.capacityBytes()) fail("resident bytes exceed the budget");
  if (!regions_[0].resident) fail("the trunk is not resident");
  std::size_t held = 0;
  for (std::uint32_t r = 0; r < regions_.size(); ++r) {
    const Region& region = regions_[r];
    if (!region.resident) continue;
    const std::string name = "region " + std::to_string(r);
    if (!pool_.contains(region.block)) fail(name + " has no block");
    held += pool_.size(region.block);
    // Every page header leads to the block's info section.
    const std::byte* base = pool_.data(region.block);
    const std::int64_t infoOffset = std::int64_t(*reinterpret_cast<const std::int32_t*>(base)) * 4;
    if (infoOffset <= 0 || std::size_t(infoOffset) + sizeof(BlockInfo) > pool_.size(region.block))
      fail(name + ": page header leads outside its block");
    const auto* info = reinterpret_cast<const BlockInfo*>(base + infoOffset);
    if (info->magic != kBlockInfoMagic) fail(name + ": no info section where the page header leads");
    for (std::uint64_t page = 0; page * kSlotsPerPage < info->slotCount; ++page)
      if (std::int64_t(page * kPageBytes) +
              std::int64_t(*reinterpret_cast<const std::int32_t*>(base + page * kPageBytes)) * 4 !=
          infoOffset)
        fail(name + ": page header " + std::to_string(page) + " does not lead to the info section");
    const ChildDescriptor* root = descriptorAt(region, region.rootSlot);
    if (root->validMask() == 0) fail(name + ": its root descriptor is a stub or link");
    if (region.entries.empty()) fail(name + " has no entry voxel");
    if (region.parent >= 0) {
      const Region& parent = regions_[std::size_t(region.parent)];
      if (parent.resident != parent.slices.size()) fail(name + " is resident below an incomplete parent");
      for (const auto& [coord, slot] : region.entries) {
        const ChildDescriptor* at = descriptorAt(parent, parentSlotOf(parent, r, coord));
        if (!at->isLink() || at + at->linkOffset() != descriptorAt(region, slot))
          fail(name + " is not linked from its parent");
      }
    }
    for (const std::uint32_t c : region.children) {
      const auto slots = region.childSlots.find(c);
      if (region.resident == region.slices.size() && slots == region.childSlots.end())
        fail(name + " has no slot for child region " + std::to_string(c));
      if (slots != region.childSlots.end() && !regions_[c].resident)
        for (const auto& [coord, slot] : slots->second)
          if (descriptorAt(region, slot)->isLink()) fail(name + " links evicted region " + std::to_string(c));
    }
  }
  if (held != pool_.usedBytes())
    fail("regions hold " + std::to_string(held) + " bytes, the pool says " +
         std::to_string(pool_.usedBytes()));
}

}  // namespace svo
