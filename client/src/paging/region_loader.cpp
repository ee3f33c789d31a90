#include "paging/region_loader.hpp"

#include <cassert>
#include <ctime>
#include <map>
#include <optional>
#include <stdexcept>

#include "svo/store/store_reader.hpp"

namespace svo::paging {
namespace {

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

int slotToward(const glm::ivec3& coord, int shift) {
  return childSlot(coord >> shift);
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
        // Written in place: a voxel assembled aside and pushed back stalls on store forwarding.
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

WorkerCpu StageCounters::seconds() const {
  const auto seconds = [](const std::atomic<std::uint64_t>& nanos) {
    return double(nanos.load(std::memory_order_relaxed)) * 1e-9;
  };
  return {seconds(read),
          seconds(assemble),
          seconds(decode),
          seconds(layout),
          voxelsDecoded.load(std::memory_order_relaxed),
          voxelsLaidOut.load(std::memory_order_relaxed)};
}

RegionLoader::RegionLoader(const SliceSource& source, RegionTable& regions, std::shared_mutex& poolMutex)
    : source_(source), index_(source.index()), regions_(regions), poolMutex_(poolMutex) {}

FetchedChain RegionLoader::fetch(const LoadRequest& request) {
  const StageClock clock(cpu_.read);
  const Region& region = regions_[regions_.regionOf(request.slice)];  // its slice list never changes
  const std::span<const std::uint32_t> chain =
      std::span(region.slices).subspan(regions_.indexInRegion(request.slice), request.count);
  FetchedChain out;
  try {
    source_.fetchAll(chain, out.slices);
  } catch (const std::exception& e) {
    out.error = e.what();
    assert(out.slices.size() < chain.size());
    out.failedSlice = chain[out.slices.size()];
    const auto* sliceError = dynamic_cast<const SliceError*>(&e);
    out.transient = sliceError && sliceError->transient;
  }
  for (std::size_t k = 0; k < out.slices.size(); ++k)
    bytesRead_.fetch_add(index_.slices()[chain[k]].compressedBytes, std::memory_order_relaxed);
  return out;
}

VoxelLevels RegionLoader::residentLevels(const Region& region) const {
  if (region.resident > 0) {
    // Deepen: the region's own block, more levels.
    const BlockView view = regions_.view(region);
    return readSubtree(regions_.descriptorAt(region, region.rootSlot),
                       {region.cubeCoord, 0, false, 0, rootValue(view, AttachmentType::Color),
                        rootValue(view, AttachmentType::Normal)});
  }
  if (region.parent < 0) {
    const StoreHeader& header = index_.header();
    return {{{glm::ivec3(0), 0, false, 0, header.rootColor, header.rootNormal}}};
  }
  // A new region: its cube's voxel and subtree from the parent region's block.
  const Region& parent = regions_[std::uint32_t(region.parent)];
  const BlockView view = regions_.view(parent);
  SliceVoxel voxel{parent.cubeCoord,
                   0,
                   false,
                   0,
                   rootValue(view, AttachmentType::Color),
                   rootValue(view, AttachmentType::Normal)};
  const ChildDescriptor* d = regions_.descriptorAt(parent, parent.rootSlot);
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
  return readSubtree(d, voxel, region.firstSlot, region.lastSlot);
}

void RegionLoader::layOut(const Region& region, const VoxelLevels& levels, std::uint32_t resident,
                          BuiltBlock& out) {
  const StoreHeader& header = index_.header();
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
}

BuiltBlock RegionLoader::build(const LoadRequest& request, FetchedChain&& fetched,
                               const std::function<void()>& pause) {
  BuiltBlock out;
  out.slice = request.slice;
  out.region = regions_.regionOf(request.slice);
  out.requested = request.count;
  out.error = std::move(fetched.error);
  out.failedSlice = fetched.failedSlice;
  out.transient = fetched.transient;
  const Region& region = regions_[out.region];  // its slice list never changes: no lock needed
  const std::uint32_t first = regions_.indexInRegion(request.slice);
  // A slice that fails here has wrong bytes (an earlier one than any the fetch could not get): never retried.
  const auto fail = [&](std::uint32_t slice, const std::string& what) {
    out.failedSlice = slice;
    out.error = index_.name() + ": slice " + std::to_string(slice) + ": " + what;
    out.transient = false;
  };
  if (fetched.slices.empty()) return out;

  // Checksums and zstd: a failure ends the chain, the slices before it still load.
  pause();
  StageClock clock(cpu_.read);
  std::vector<SliceBytes> raw;
  for (std::uint32_t k = 0; k < fetched.slices.size(); ++k) {
    const std::uint32_t slice = region.slices[first + k];
    try {
      raw.push_back(unpackSlice(index_, slice, fetched.slices[k]));
    } catch (const std::exception& e) {
      out.error = e.what();
      out.failedSlice = slice;
      out.transient = false;
      break;
    }
  }
  fetched.slices.clear();
  if (raw.empty()) return out;

  clock.enter(cpu_.assemble);
  std::shared_lock lock(poolMutex_);
  out.version = region.version;
  const std::uint32_t resident = region.resident;
  if (resident != first) return out;  // stale: the commit drops it
  if (region.resident == 0 && region.parent >= 0 && !regions_[std::uint32_t(region.parent)].complete())
    return out;  // stale
  VoxelLevels levels;
  try {
    levels = residentLevels(region);
  } catch (const std::exception& e) {
    fail(request.slice, e.what());
    return out;
  }
  // The pool is read; decoding and layout need only this copy, so commits need not wait for them.
  lock.unlock();
  clock.enter(cpu_.decode);
  for (std::uint32_t k = 0; k < raw.size(); ++k) {
    const std::uint32_t slice = region.slices[first + k];
    pause();
    try {
      if (region.cubeLevel + int(levels.size()) != index_.slices()[slice].voxelLevel)
        throw std::runtime_error("the resident levels do not end above it");
      std::vector<SliceVoxel> added;
      decodeSlice(index_, slice, raw[k], levels.back(), added);
      cpu_.voxelsDecoded.fetch_add(added.size(), std::memory_order_relaxed);
      levels.push_back(std::move(added));
      ++out.added;
    } catch (const std::exception& e) {
      fail(slice, e.what());
      break;
    }
  }
  if (out.added == 0) return out;

  pause();
  clock.enter(cpu_.layout);
  try {
    layOut(region, levels, resident, out);
  } catch (const std::exception& e) {
    fail(region.slices[first + out.added - 1], e.what());
    out.added = 0;
    out.block = Block();
    return out;
  }
  // The pages the commit will most likely copy the block into, mapped here rather than on the render thread.
  std::shared_lock poolShared(poolMutex_);  // no commit beside it
  std::lock_guard prefaulting(prefaultMutex_);
  regions_.pool().prefault(out.block.bytes().size());
  return out;
}

}  // namespace svo::paging
