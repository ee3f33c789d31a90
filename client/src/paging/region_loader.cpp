#include "paging/region_loader.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cstring>
#include <ctime>
#include <map>
#include <optional>
#include <stdexcept>

#include "svo/store/store_reader.hpp"

namespace svo::paging {
namespace {

int slotToward(const glm::ivec3& coord, int shift) {
  return childSlot(coord >> shift);
}

// The root voxel's values as a block records them (either attribute layout).
std::pair<std::uint32_t, std::uint32_t> rootValues(const BlockView& block) {
  const auto value = [&](AttachmentType raw, AttachmentType units) {
    const AttachmentEntry* e = block.attachment(raw) ? block.attachment(raw) : block.attachment(units);
    return e ? e->rootValue : 0u;
  };
  return {value(AttachmentType::Color, AttachmentType::ColorUnits),
          value(AttachmentType::Normal, AttachmentType::NormalUnits)};
}

// One descriptor's children's attribute values as its block holds them: uncompressed values (a child left
// out inherits its parent's), or the compressed units decoded, except at the block's deepest level, whose
// exact values the block keeps beside the units (they come in Morton order, one after another).
class ChildValues {
 public:
  ChildValues(const ChildDescriptor* d, const ReadBack& readBack, bool frontier) : frontier_(frontier) {
    if (!readBack.compressed) {
      colors_ = BlockView::attributes(d, AttachmentType::Color);
      normals_ = BlockView::attributes(d, AttachmentType::Normal);
    } else {
      colorUnit_ = BlockView::unit(d, AttachmentType::ColorUnits);
      normalUnit_ = BlockView::unit(d, AttachmentType::NormalUnits);
    }
  }
  void set(SliceVoxel& child, const SliceVoxel& parent, int slot, ReadBack& readBack) const {
    if (frontier_) {
      if (readBack.exactColors) child.color = readBack.exactColors[readBack.exactNext];
      if (readBack.exactNormals) {
        child.normalCode = readBack.exactNormals[readBack.exactNext];
        child.normal = latticeNormalBits(child.normalCode);
      }
      ++readBack.exactNext;
    } else if (readBack.compressed) {
      setShown(child, parent, slot);
    } else {
      child.color = colors_.at(slot).value_or(parent.color);
      child.normal = normals_.at(slot).value_or(parent.normal);
    }
  }
  // Compressed layout: the child's values as the block shows them (its unit decoded; a pair without a unit
  // shows its parent's values), at the deepest level too.
  void setShown(SliceVoxel& child, const SliceVoxel& parent, int slot) const {
    child.color = colorUnit_ ? colorUnit_->color(slot) : parent.color;
    child.normal = normalUnit_ ? encodeNormal(normalUnit_->normal(slot)) : parent.normal;
  }

 private:
  bool frontier_;
  BlockView::Attributes colors_, normals_;
  std::optional<BlockView::UnitHalf> colorUnit_, normalUnit_;
};

// The calling worker's voxel array, kept from one load to the next (RegionVoxels::tree): its pages stay
// mapped, where a fresh array of a few MiB is mapped and zeroed a page at a time as it is written.
std::vector<SliceVoxel>& workerVoxels() {
  thread_local std::vector<SliceVoxel> voxels;
  return voxels;
}

// The region's voxel array with room for `expected` voxels: the worker's, emptied.
RegionVoxels regionVoxels(std::size_t expected) {
  RegionVoxels out;
  out.tree.voxels = std::move(workerVoxels());
  out.tree.voxels.clear();
  out.tree.voxels.reserve(expected);
  return out;
}

// The subtree below `start` as far as the blocks hold it, level by level in Morton order, through the
// start's children in slots [firstSlot, lastSlot] only (a run's region; its siblings may be linked to other
// blocks). `descriptor` is the start voxel's (nullptr when it has no children here). Stubs read as voxels
// without children. In the compressed layout each descriptor's units are carried to the new block as they
// are: the values read back from them are lossy. `expected`: the voxels the array is to hold in the end (the
// levels read, then the slices decoded onto them), so that it moves as seldom as possible.
RegionVoxels readSubtree(const ChildDescriptor* descriptor, const SliceVoxel& start, ReadBack& readBack,
                         std::size_t expected, std::uint8_t firstSlot = 0, std::uint8_t lastSlot = 7) {
  RegionVoxels out = regionVoxels(expected);
  std::vector<SliceVoxel>& voxels = out.tree.voxels;
  voxels.push_back(start);
  out.endLevel();
  std::vector<const ChildDescriptor*> descriptors{descriptor};
  while (true) {
    const std::size_t levels = out.levels(), begin = out.levelStart[levels - 1], end = voxels.size();
    // The next level's size: room for it behind this level, which its voxels are read from as it is written.
    std::size_t children = 0;
    for (const ChildDescriptor* d : descriptors)
      if (d && !d->isStub()) children += std::size_t(std::popcount(unsigned(d->validMask())));
    out.tree.reserveMore(children);
    std::vector<const ChildDescriptor*> nextDescriptors;
    nextDescriptors.reserve(children);
    if (readBack.carried) readBack.carried->unitOf.emplace_back(end - begin, kNoCarriedUnit);
    const bool frontier = readBack.startLevel + int(levels) == readBack.frontierLevel;
    for (std::size_t i = begin; i < end; ++i) {
      const ChildDescriptor* d = descriptors[i - begin];
      if (!d || d->isStub()) continue;
      SliceVoxel& parent = voxels[i];
      std::uint8_t mask = d->validMask();
      if (levels == 1)
        for (int slot = 0; slot < 8; ++slot)
          if (slot < firstSlot || slot > lastSlot) mask &= std::uint8_t(~(1u << slot));
      parent.childMask = mask;
      if (readBack.carried) readBack.carried->carry(d, levels - 1, i - begin);
      const ChildValues values(d, readBack, frontier);
      for (int slot = 0; slot < 8; ++slot) {
        if (!(mask >> slot & 1u)) continue;
        // Written in place: a voxel assembled aside and pushed back stalls on store forwarding.
        SliceVoxel& c = voxels.emplace_back();
        c.coord = childCoord(parent.coord, slot);
        const std::optional<std::uint32_t> contour = BlockView::contour(d, slot);
        c.hasContour = contour.has_value(), c.contour = contour.value_or(0);
        values.set(c, parent, slot, readBack);
        nextDescriptors.push_back((d->nonLeafMask() >> slot & 1u) ? BlockView::child(d, slot) : nullptr);
      }
    }
    if (voxels.size() == end) return out;
    out.endLevel();
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
          seconds(poolPages),
          voxelsDecoded.load(std::memory_order_relaxed),
          voxelsLaidOut.load(std::memory_order_relaxed)};
}

RegionLoader::RegionLoader(const SliceSource& source, RegionTable& regions, std::shared_mutex& poolMutex,
                           AttributeOptions attributes)
    : source_(source),
      index_(source.index()),
      regions_(regions),
      poolMutex_(poolMutex),
      attributes_(attributes) {}

void CarriedLevels::carry(const ChildDescriptor* d, std::size_t level, std::size_t index) {
  CarriedUnit unit;
  // The descriptor's half of its pair, whether the pair holds units or not.
  unit.half = std::uint8_t(BlockView::slotIndexOf(d, BlockView::infoOf(d)) % 2);
  if (const auto colors = BlockView::unit(d, AttachmentType::ColorUnits)) {
    std::memcpy(unit.color.words.data(), colors->words, sizeof(unit.color.words));
    unit.hasColor = true;
  }
  if (const auto normals = BlockView::unit(d, AttachmentType::NormalUnits)) {
    std::memcpy(unit.normal.words.data(), normals->words, sizeof(unit.normal.words));
    unit.hasNormal = true;
    if (isExact(unit.normal))
      for (std::uint32_t mask = unit.normal.words[2]; mask; mask &= mask - 1) {
        const int slot = std::countr_zero(mask);
        unit.exactNormals[std::size_t(slot)] = exactNormalBits(normals->words, slot);
      }
  }
  unitOf[level][index] = std::uint32_t(units.size());
  units.push_back(unit);
}

void RegionLoader::keepForDeepening(const Region& region, RegionVoxels& voxels, CarriedLevels&& carried,
                                    std::uint32_t residentAfter, BuiltBlock& out) const {
  LevelOrderTree& tree = voxels.tree;
  const std::vector<std::size_t>& levelStart = voxels.levelStart;
  tree.carriedUnits = std::move(carried.units);
  tree.shownRoot = carried.shownRoot;
  tree.carriedUnitOf.assign(tree.voxels.size(), kNoCarriedUnit);
  for (std::size_t l = 0; l < carried.unitOf.size(); ++l)
    std::copy(carried.unitOf[l].begin(), carried.unitOf[l].end(),
              tree.carriedUnitOf.begin() + std::ptrdiff_t(levelStart[l]));
  // The deepest level's exact values, while a slice of this region or of a child region may be decoded on
  // them; a region at the store's last level keeps none.
  if (residentAfter == region.slices.size() && region.children.empty()) return;
  const std::span<const SliceVoxel> deepest = voxels.level(voxels.levels() - 1);
  const StoreHeader& header = index_.header();
  for (const SliceVoxel& v : deepest) {
    if (header.hasColors) tree.exactColors.push_back(v.color);
    if (header.hasNormals) tree.exactNormals.push_back(octNormalCodeOf(v.normal));
  }
  if (residentAfter != region.slices.size()) return;
  // Where each child region's voxels begin among them: its first sub-cube's corner, in Morton order.
  const int deepestLevel = region.cubeLevel + int(voxels.levels()) - 1;
  for (const std::uint32_t child : region.children) {
    const Region& c = regions_[child];
    const auto [coords, level] = entryVoxels(c.cubeLevel, c.cubeCoord, c.firstSlot, c.lastSlot);
    const glm::ivec3 corner = coords.front() << (deepestLevel - level);
    const auto it =
        std::lower_bound(deepest.begin(), deepest.end(), corner,
                         [](const SliceVoxel& v, const glm::ivec3& k) { return mortonLess(v.coord, k); });
    out.childFrontier[child] = std::uint32_t(it - deepest.begin());
  }
}

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

ReadBack RegionLoader::readBack(const Region& region, int startLevel, std::uint32_t exactFirst,
                                CarriedLevels* carried) const {
  ReadBack r;
  r.compressed = attributes_.compressed();
  r.startLevel = startLevel;
  if (!r.compressed) return r;
  r.carried = carried;
  r.frontierLevel = index_.slices()[region.slices[region.resident - 1]].voxelLevel;
  const BlockView view = regions_.view(region);
  const StoreHeader& header = index_.header();
  const AttachmentEntry* colors = view.attachment(AttachmentType::ExactColors);
  const AttachmentEntry* normals = view.attachment(AttachmentType::ExactNormals);
  if ((header.hasColors && !colors) || (header.hasNormals && !normals))
    throw std::runtime_error("its block kept no exact values to decode the next level on");
  if (colors) r.exactColors = view.words(*colors) + exactFirst;
  if (normals) r.exactNormals = reinterpret_cast<const std::uint16_t*>(view.words(*normals)) + exactFirst;
  return r;
}

std::size_t RegionLoader::voxelsOfSlices(const Region& region, std::uint32_t begin, std::uint32_t end) const {
  std::size_t voxels = 0;
  for (std::uint32_t k = begin; k < end; ++k) voxels += index_.slices()[region.slices[k]].voxelCount;
  return voxels;
}

RegionVoxels RegionLoader::residentLevels(const Region& region, std::size_t expected,
                                          CarriedLevels& carried) const {
  if (region.resident > 0) {
    // Deepen: the region's own block, more levels.
    const auto [color, normal] = rootValues(regions_.view(region));
    ReadBack back = readBack(region, region.cubeLevel, 0, &carried);
    return readSubtree(regions_.descriptorAt(region, region.rootSlot),
                       {.coord = region.cubeCoord, .color = color, .normal = normal}, back, expected);
  }
  if (region.parent < 0) {
    const StoreHeader& header = index_.header();
    RegionVoxels root = regionVoxels(expected);
    root.tree.voxels.push_back({.color = header.rootColor, .normal = header.rootNormal});
    root.endLevel();
    return root;
  }
  // A new region: its cube's voxel and subtree from the parent region's block.
  const Region& parent = regions_[std::uint32_t(region.parent)];
  const auto first = parent.childFrontier.find(regions_.indexOf(region));
  ReadBack back =
      readBack(parent, region.cubeLevel, first == parent.childFrontier.end() ? 0 : first->second, &carried);
  const auto [color, normal] = rootValues(regions_.view(parent));
  SliceVoxel voxel{.coord = parent.cubeCoord, .color = color, .normal = normal};
  SliceVoxel shown = voxel;  // compressed: its values as the parent's block shows them (shownRoot)
  const ChildDescriptor* d = regions_.descriptorAt(parent, parent.rootSlot);
  for (int level = parent.cubeLevel + 1; level <= region.cubeLevel; ++level) {
    const int slot = slotToward(region.cubeCoord, region.cubeLevel - level);
    if (!d || d->isStub() || !(d->validMask() >> slot & 1u))
      throw std::runtime_error("its cube's voxel is not in the parent region");
    voxel.coord = childCoord(voxel.coord, slot);
    // Its contour too: the store predicts its children's contours from it.
    const std::optional<std::uint32_t> contour = BlockView::contour(d, slot);
    voxel.hasContour = contour.has_value(), voxel.contour = contour.value_or(0);
    const SliceVoxel above = voxel;
    // The cube's voxel at the parent's deepest level is the first of the exact values its subtree starts at.
    ReadBack one = back;
    const ChildValues values(d, one, level == back.frontierLevel);
    values.set(voxel, above, slot, one);
    if (back.compressed) values.setShown(shown, SliceVoxel(shown), slot);
    d = (d->nonLeafMask() >> slot & 1u) ? BlockView::child(d, slot) : nullptr;
  }
  if (back.compressed) carried.shownRoot = {shown.color, shown.normal};
  return readSubtree(d, voxel, back, expected, region.firstSlot, region.lastSlot);
}

void RegionLoader::layOut(const Region& region, RegionVoxels& voxels, CarriedLevels&& carried,
                          std::uint32_t resident, const std::function<void()>& pause, BuiltBlock& out) {
  const StoreHeader& header = index_.header();
  LevelOrderTree& tree = voxels.tree;
  tree.hasColors = header.hasColors, tree.hasNormals = header.hasNormals;
  cpu_.voxelsLaidOut.fetch_add(tree.voxels.size(), std::memory_order_relaxed);
  // The record of voxel `coord` at `depth` below the cube, or nullopt.
  const auto recordAt = [&](std::size_t depth, const glm::ivec3& coord) -> std::optional<std::size_t> {
    if (depth >= voxels.levels()) return std::nullopt;
    const std::span<const SliceVoxel> level = voxels.level(depth);
    const auto it =
        std::lower_bound(level.begin(), level.end(), coord,
                         [](const SliceVoxel& v, const glm::ivec3& k) { return mortonLess(v.coord, k); });
    if (it == level.end() || it->coord != coord) return std::nullopt;
    return voxels.levelStart[depth] + std::size_t(it - level.begin());
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
        if (tree.voxels[*record].childMask == 0) tree.stubs.push_back(std::uint32_t(*record));
        records.push_back({coord, *record});
      }
      if (records.empty()) throw std::runtime_error("a child region's voxels are missing");
    }
  }
  std::sort(tree.stubs.begin(), tree.stubs.end());
  // Its own entry voxels that have children, which the parent's links lead to.
  std::vector<std::pair<glm::ivec3, std::size_t>> entryRecords;
  const auto [coords, level] =
      entryVoxels(region.cubeLevel, region.cubeCoord, region.firstSlot, region.lastSlot);
  for (const glm::ivec3& coord : coords)
    if (const auto record = recordAt(std::size_t(level - region.cubeLevel), coord);
        record && tree.voxels[*record].childMask != 0)
      entryRecords.push_back({coord, *record});
  if (attributes_.compressed())
    keepForDeepening(region, voxels, std::move(carried), resident + out.added, out);
  std::vector<std::uint32_t> slotOf;
  LayoutOptions layout;
  layout.inheritEqualOnly = true;  // decoded slices: the store already decided what inherits
  attributes_.applyTo(layout);
  layout.betweenPasses = pause;
  out.block = layoutBlock(tree, layout, nullptr, &slotOf);
  out.rootSlot = out.block.view().info().rootSlot;
  for (const auto& [coord, record] : entryRecords) out.entries.push_back({coord, slotOf[record]});
  for (const auto& [child, records] : childRecords)
    for (const auto& [coord, record] : records) out.childSlots[child].push_back({coord, slotOf[record]});
}

void RegionLoader::buildLevels(const LevelPool& levels, BuiltBlock& out, std::uint32_t first,
                               std::span<const SliceBytes> raw, std::shared_lock<std::shared_mutex>& lock,
                               StageClock& clock, const Pauses& pauses) {
  OctreeLevel parents;
  try {
    parents = levels.startGrowth(out.region, first, out.growth);
  } catch (const std::exception& e) {
    out.failedSlice = regions_[out.region].slices[first];
    out.error = index_.name() + ": slice " + std::to_string(out.failedSlice) + ": " + e.what();
    out.transient = false;
    return;
  }
  // The pool is read; the decoding needs only the parents' copy, so commits need not wait for it.
  lock.unlock();
  clock.enter(cpu_.decode);
  const std::optional<std::string> error =
      levels.decode(out.region, first, raw, std::move(parents), out.growth, pauses.betweenStages);
  out.added = out.growth.added;
  std::uint64_t voxels = 0;
  for (std::uint32_t k = 0; k < out.added; ++k)
    voxels += index_.slices()[regions_[out.region].slices[first + k]].voxelCount;
  cpu_.voxelsDecoded.fetch_add(voxels, std::memory_order_relaxed);
  if (error) {
    out.failedSlice = regions_[out.region].slices[first + out.added];
    out.error = index_.name() + ": slice " + std::to_string(out.failedSlice) + ": " + *error;
    out.transient = false;
  }
}

BuiltBlock RegionLoader::build(const LoadRequest& request, FetchedChain&& fetched, const Pauses& pauses) {
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
  pauses.betweenStages();
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
  if (const LevelPool* levels = regions_.levels()) {
    buildLevels(*levels, out, first, raw, lock, clock, pauses);
    return out;
  }
  // The voxels the request's slices add (fewer where one fails), and with the resident ones and the cube's
  // voxel (in no slice), what the region's array is to hold.
  const std::size_t decodedAtMost = voxelsOfSlices(region, first, first + std::uint32_t(raw.size()));
  RegionVoxels voxels;
  CarriedLevels carried;
  try {
    voxels = residentLevels(region, 1 + voxelsOfSlices(region, 0, first) + decodedAtMost, carried);
  } catch (const std::exception& e) {
    fail(request.slice, e.what());
    return out;
  }
  // The pool is read; decoding and layout need only this copy, so commits need not wait for them.
  lock.unlock();
  clock.enter(cpu_.decode);
  // Room for every slice's voxels behind the levels read, exactly: the array moves once at most (where a new
  // region read more levels from its parent's block than its own slices count), not once per slice.
  voxels.tree.voxels.reserve(voxels.tree.voxels.size() + decodedAtMost);
  for (std::uint32_t k = 0; k < raw.size(); ++k) {
    const std::uint32_t slice = region.slices[first + k];
    pauses.betweenStages();
    try {
      const std::size_t levels = voxels.levels();
      if (region.cubeLevel + int(levels) != index_.slices()[slice].voxelLevel)
        throw std::runtime_error("the resident levels do not end above it");
      decodeSlice(index_, slice, raw[k], voxels.tree, voxels.levelStart[levels - 1],
                  voxels.levelStart[levels], pauses.withinStage);
      cpu_.voxelsDecoded.fetch_add(voxels.tree.voxels.size() - voxels.levelStart[levels],
                                   std::memory_order_relaxed);
      voxels.endLevel();
      ++out.added;
    } catch (const std::exception& e) {
      // The block ends at the level above: the slice's partial level goes, and the voxels it split (leaves
      // until then) are leaves again, so that the array is a whole tree.
      voxels.tree.voxels.resize(voxels.levelStart.back());
      for (SliceVoxel& v : voxels.level(voxels.levels() - 1)) v.childMask = 0;
      fail(slice, e.what());
      break;
    }
  }
  if (out.added == 0) return out;

  pauses.betweenStages();
  clock.enter(cpu_.layout);
  try {
    layOut(region, voxels, std::move(carried), resident, pauses.withinStage, out);
    workerVoxels() = std::move(voxels.tree.voxels);
  } catch (const std::exception& e) {
    fail(region.slices[first + out.added - 1], e.what());
    out.added = 0;
    out.block = Block();
    return out;
  }
  // The pages the commit will most likely copy the block into, mapped here rather than on the render thread,
  // and without the pool lock, which a commit would wait for.
  clock.enter(cpu_.poolPages);
  regions_.pool().prefault(out.block.bytes().size());
  return out;
}

}  // namespace svo::paging
