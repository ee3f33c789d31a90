#include "paging/regions.hpp"

#include "paging/level_pool.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <tuple>
#include <utility>

#include <glm/common.hpp>

namespace svo::paging {
namespace {

// Cube levels the feedback lookup key packs (16 bits per coordinate); stores never split that deep in
// practice (8^16 slices).
constexpr int kMaxKeyedCubeLevel = 16;

std::uint64_t sliceKey(int voxelLevel, int cubeLevel, glm::ivec3 c) {
  return std::uint64_t(voxelLevel) << 58 | std::uint64_t(cubeLevel) << 53 | std::uint64_t(c.x) << 32 |
         std::uint64_t(c.y) << 16 | std::uint64_t(c.z);
}

}  // namespace

std::pair<std::vector<glm::ivec3>, int> entryVoxels(int cubeLevel, glm::ivec3 cube, std::uint8_t firstSlot,
                                                    std::uint8_t lastSlot) {
  if (isWholeCube(firstSlot, lastSlot)) return {{cube}, cubeLevel};
  std::vector<glm::ivec3> out;
  for (int slot = firstSlot; slot <= lastSlot; ++slot) out.push_back(childCoord(cube, slot));
  return {out, cubeLevel + 1};
}

RegionTable::RegionTable(const std::vector<SliceInfo>& slices, std::size_t budgetBytes,
                         const std::string& store, const StoreHeader* levelArraysOf)
    : pool_(budgetBytes) {
  const std::size_t n = slices.size();
  regionOf_.assign(n, 0), indexInRegion_.assign(n, 0);
  cubeLevelsOf_.resize(std::size_t(kMaxLevels) + 2);
  std::map<std::tuple<int, int, int, int, int, int>, std::uint32_t> regionAt;  // (level, cube, run) -> region
  const auto fail = [&](std::uint32_t s, const std::string& what) {
    throw std::runtime_error(store + ": slice " + std::to_string(s) + " " + what);
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
  if (regions_.empty()) throw std::runtime_error(store + ": the store has no slices");
  if (levelArraysOf) levels_ = std::make_unique<LevelPool>(*this, slices, *levelArraysOf);
}

RegionTable::~RegionTable() = default;

std::size_t RegionTable::heldBytes(std::uint32_t region) const {
  if (levels_) return levels_->bytes(region);
  return regions_[region].resident ? pool_.size(regions_[region].block) : 0;
}

std::size_t RegionTable::usedBytes() const {
  return levels_ ? levels_->residentBytes() : pool_.usedBytes();
}

BlockView RegionTable::view(const Region& region) const {
  return BlockView::unchecked(pool_.data(region.block), pool_.size(region.block));
}

const ChildDescriptor* RegionTable::descriptorAt(const Region& region, std::uint32_t slot) const {
  return reinterpret_cast<const ChildDescriptor*>(pool_.data(region.block)) + slot;
}
ChildDescriptor* RegionTable::descriptorAt(Region& region, std::uint32_t slot) {
  return reinterpret_cast<ChildDescriptor*>(pool_.data(region.block)) + slot;
}

bool RegionTable::evictable(std::uint32_t index, double priority) const {
  const Region& r = regions_[index];
  return index != 0 && r.resident && r.priority < priority &&
         std::none_of(r.children.begin(), r.children.end(),
                      [&](std::uint32_t k) { return regions_[k].resident != 0; });
}

// The parent's slot of `coord`, one of a child region's entry voxels.
std::uint32_t RegionTable::parentSlotOf(const Region& parent, std::uint32_t child,
                                        const glm::ivec3& coord) const {
  const auto slots = parent.childSlots.find(child);
  if (slots != parent.childSlots.end())
    for (const auto& [c, slot] : slots->second)
      if (c == coord) return slot;
  throw std::logic_error("pager: a region's entry voxel has no slot in its parent");
}

void RegionTable::link(std::uint32_t index) {
  const Region& region = regions_[index];
  Region& parent = regions_[std::size_t(region.parent)];
  for (const auto& [coord, slot] : region.entries) {
    const std::uint32_t parentSlot = parentSlotOf(parent, index, coord);
    ChildDescriptor* at = descriptorAt(parent, parentSlot);
    parent.unlinked.try_emplace(parentSlot, *at);
    const ChildDescriptor* target = descriptorAt(region, slot);
    *at = ChildDescriptor::link(std::int32_t(target - at));
    pool_.markWritten(at, sizeof *at);
  }
}

void RegionTable::relinkAll() {
  for (std::uint32_t r = 1; r < regions_.size(); ++r)
    if (regions_[r].resident) link(r);
}

std::uint32_t RegionTable::evict(std::uint32_t index) {
  Region& region = regions_[index];
  if (levels_) {
    levels_->evict(index);
    ++region.version;
    return std::exchange(region.resident, 0);
  }
  Region& parent = regions_[std::size_t(region.parent)];
  for (const auto& [coord, slot] : region.entries) {
    const std::uint32_t parentSlot = parentSlotOf(parent, index, coord);
    ChildDescriptor* at = descriptorAt(parent, parentSlot);
    *at = parent.unlinked.at(parentSlot);
    pool_.markWritten(at, sizeof *at);
    parent.unlinked.erase(parentSlot);
  }
  pool_.erase(region.block);
  const std::uint32_t slices = region.resident;
  region.resident = 0;
  ++region.version;
  return slices;
}

void RegionTable::install(BuiltBlock& built) {
  Region& region = regions_[built.region];
  if (levels_) {
    levels_->install(built.region, std::move(built.growth));
    region.resident += built.added;
    ++region.version;
    return;
  }
  if (region.resident) pool_.erase(region.block);
  bool moved = false;
  const auto id =
      pool_.insert(std::span<const std::byte>(built.block.bytes().data(), built.block.bytes().size()),
                   [&](BlockPool::BlockId) { moved = true; });
  if (!id) throw std::logic_error("pager: the pool refused a block that fits");
  region.block = *id;
  region.blockBytes = built.block.bytes().size();
  region.rootSlot = built.rootSlot;
  region.entries = std::move(built.entries);
  region.childSlots = std::move(built.childSlots);
  region.childFrontier = std::move(built.childFrontier);
  region.unlinked.clear();
  region.resident += built.added;
  ++region.version;
  if (moved) {
    relinkAll();
  } else if (region.parent >= 0) {
    link(built.region);
  }
}

std::vector<std::uint32_t> RegionTable::residentSlices() const {
  std::vector<std::uint32_t> out;
  for (const Region& r : regions_) out.insert(out.end(), r.slices.begin(), r.slices.begin() + r.resident);
  std::sort(out.begin(), out.end());
  return out;
}

std::optional<std::uint32_t> RegionTable::sliceAt(int voxelLevel, glm::dvec3 p) const {
  if (voxelLevel < 1 || voxelLevel > kMaxLevels) return std::nullopt;
  for (const std::int32_t cubeLevel : cubeLevelsOf_[std::size_t(voxelLevel)]) {
    const double cells = std::ldexp(1.0, cubeLevel);
    const glm::ivec3 cube =
        glm::clamp(glm::ivec3(glm::floor((p - 1.0) * cells)), glm::ivec3(0), glm::ivec3(int(cells) - 1));
    const auto it = sliceAt_.find(sliceKey(voxelLevel, cubeLevel, cube));
    if (it != sliceAt_.end()) return it->second;
  }
  return std::nullopt;
}

void RegionTable::checkInvariants() const {
  const auto fail = [](const std::string& what) { throw std::logic_error("pager invariant: " + what); };
  if (levels_) {
    if (usedBytes() > capacityBytes()) fail("resident bytes exceed the budget");
    if (!regions_[0].resident) fail("the trunk is not resident");
    return levels_->checkInvariants();
  }
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
      if (!parent.complete()) fail(name + " is resident below an incomplete parent");
      for (const auto& [coord, slot] : region.entries) {
        const ChildDescriptor* at = descriptorAt(parent, parentSlotOf(parent, r, coord));
        if (!at->isLink() || at + at->linkOffset() != descriptorAt(region, slot))
          fail(name + " is not linked from its parent");
      }
    }
    for (const std::uint32_t c : region.children) {
      const auto slots = region.childSlots.find(c);
      if (region.complete() && slots == region.childSlots.end())
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

}  // namespace svo::paging
