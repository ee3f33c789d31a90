#include "paging/level_pool.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <optional>
#include <stdexcept>
#include <utility>

#include "svo/store/codec.hpp"
#include "svo/store/format.hpp"
#include "svo/store/level_arrays.hpp"

namespace svo::paging {
namespace {

static_assert(std::endian::native == std::endian::little,
              "presence words are handed to PresenceBits::append as their bytes, LSB first");

const IndexedLevel& levelAt(const LevelRegion& region, int level) {
  return region.levels[std::size_t(level - region.baseLevel)];
}

// Where the child masks of `node`, a voxel of octree level `level`, are: its region's, or on its region's
// deepest level the base of the region linked there. False where it has none resident.
bool toMasks(LevelNode& node, int level) {
  if (level < node.region->deepestLevel()) return true;
  const LevelRegion::Link* link = node.region->linkAt(node.index);
  if (!link) return false;
  node = {link->region, node.index - link->first};
  return true;
}

// The 64 presence bits from bit `at` on (PresentValues keeps a zero word past its last voxel's).
inline std::uint64_t presenceAt(const std::vector<std::uint64_t>& words, std::uint32_t at) {
  const unsigned shift = at % 64;
  const std::uint64_t low = words[at / 64] >> shift;
  return shift && at / 64 + 1 < words.size() ? low | words[at / 64 + 1] << (64 - shift) : low;
}

// One past the index of the last child of voxel i.
std::uint32_t childEnd(const IndexedLevel& level, std::uint32_t i) {
  return level.firstChild(i) + std::uint32_t(std::popcount(unsigned(level.childMask(i))));
}

// A range of voxels of one level, in one region.
struct VoxelRange {
  const LevelRegion* region;
  std::uint32_t first, end;
};

// The resident voxels of each octree level, from the root to `target`, on the way into a cube's sub-cubes
// [firstSlot, lastSlot] (all eight: the whole cube): down to the cube the one voxel on the path, below it the
// voxels inside. Each level's are in the region that holds their child masks (on a region's deepest level
// where another region is linked, that region's base). Throws std::logic_error where the cube's voxels are
// not resident down to `target` in one region.
std::vector<VoxelRange> voxelsDownTo(const LevelRegion& root, int cubeLevel, glm::ivec3 cube, int firstSlot,
                                     int lastSlot, int target) {
  assert(cubeLevel < target);
  std::vector<VoxelRange> path;
  path.reserve(std::size_t(target) + 1);
  LevelNode node{&root, 0};
  for (int level = 0; level <= cubeLevel; ++level) {
    if (!toMasks(node, level)) throw std::logic_error("pager: a region's cube has no resident children");
    path.push_back({node.region, node.index, node.index + 1});
    if (level == cubeLevel) break;
    const int slot = childSlot(cube >> (cubeLevel - level - 1));
    const IndexedLevel& l = levelAt(*node.region, level);
    if (!(l.childMask(node.index) >> slot & 1))
      throw std::logic_error("pager: a region's cube is not resident in its parent");
    node.index = l.firstChild(node.index) + std::uint32_t(childRank(l.childMask(node.index), slot));
  }
  const IndexedLevel& cubeVoxel = levelAt(*node.region, cubeLevel);
  const std::uint8_t mask = cubeVoxel.childMask(node.index);
  const std::uint32_t firstChild = mask ? cubeVoxel.firstChild(node.index) : 0;  // none: the range is empty
  VoxelRange range{node.region, firstChild + std::uint32_t(childRank(mask, firstSlot)),
                   firstChild + std::uint32_t(childRank(mask, lastSlot + 1))};
  for (int level = cubeLevel + 1; level < target; ++level) {
    const bool empty = range.first == range.end;
    if (!empty && level == range.region->deepestLevel()) {
      const LevelRegion::Link* link = range.region->linkAt(range.first);
      if (!link || range.end > link->end)
        throw std::logic_error("pager: a region's cube spans regions that are not resident");
      range = {link->region, range.first - link->first, range.end - link->first};
    }
    path.push_back(range);
    if (empty) continue;
    const IndexedLevel& l = levelAt(*range.region, level);
    range = l.childMasks.empty()
                ? VoxelRange{range.region, 0, 0}  // no voxel of the level has children
                : VoxelRange{range.region, l.firstChild(range.first), childEnd(l, range.end - 1)};
  }
  path.push_back(range);
  return path;
}

// The normal codes the voxels of `region`'s deepest level show, its own or its nearest ancestor's, from
// those its base shows.
std::vector<std::uint16_t> shownNormals(const LevelRegion& region, std::vector<std::uint16_t> shown) {
  std::vector<std::uint16_t> below;
  for (std::size_t l = 0; l + 1 < region.levels.size(); ++l) {
    const IndexedLevel& parents = region.levels[l];
    const PresentValues<std::uint16_t>& own = region.levels[l + 1].normals;
    below.resize(region.levels[l + 1].voxels());
    std::uint32_t child = 0, present = 0;
    for (std::uint32_t i = 0; i < parents.voxels(); ++i)
      for (int n = std::popcount(unsigned(parents.childMask(i))); n > 0; --n, ++child)
        below[child] = !own.words.empty() && (own.words[child / 64] >> (child % 64) & 1)
                           ? own.values[present++]
                           : shown[i];
    std::swap(shown, below);
  }
  return shown;
}

// shownNormals for the voxels of `region`'s deepest level on a path (voxelsDownTo's, by level) alone: from
// those the path's voxels on its base show, down through the path's voxels of each level.
std::vector<std::uint16_t> shownNormalsAlong(const LevelRegion& region,
                                             const std::vector<std::uint16_t>& baseShown,
                                             const std::vector<VoxelRange>& path) {
  const auto along = [&](std::size_t l) {
    const VoxelRange& range = path[std::size_t(region.baseLevel) + l];
    if (range.first < range.end && range.region != &region)
      throw std::logic_error("pager: a region's base is not below its parent's");
    return range;
  };
  const VoxelRange base = along(0);
  if (base.first == base.end) return {};  // nothing resident below it either
  std::vector<std::uint16_t> shown(baseShown.begin() + base.first, baseShown.begin() + base.end), below;
  for (std::size_t l = 0; l + 1 < region.levels.size(); ++l) {
    const VoxelRange parents = along(l), children = along(l + 1);
    const IndexedLevel& level = region.levels[l];
    const PresentValues<std::uint16_t>& own = region.levels[l + 1].normals;
    below.assign(children.end - children.first, 0);
    if (parents.first < parents.end && !level.childMasks.empty()) {
      // The children in range follow one another: their own values too.
      const bool hasOwn = !own.words.empty();
      std::uint32_t child = level.firstChild(parents.first), present = hasOwn ? own.rank(children.first) : 0;
      for (std::uint32_t i = parents.first; i < parents.end; ++i)
        for (int n = std::popcount(unsigned(level.childMask(i))); n > 0; --n, ++child) {
          if (child < children.first || child >= children.end) continue;
          below[child - children.first] = hasOwn && (own.words[child / 64] >> (child % 64) & 1)
                                              ? own.values[present++]
                                              : shown[i - parents.first];
        }
    }
    std::swap(shown, below);
  }
  return shown;
}

// Voxels [first, end) of a level as the decoder's parents (level_arrays.hpp): their contours and the
// normals they show, `shown`; their child masks are left for the decoder to write.
OctreeLevel parentsOf(const PresentValues<std::uint32_t>& contours, std::uint32_t first, std::uint32_t end,
                      std::vector<std::uint16_t> shown) {
  OctreeLevel level;
  level.voxels = end - first;
  std::vector<std::uint64_t> bits((end - first + 63) / 64 + 1, 0);
  for (std::uint32_t k = 0; k * 64 < end - first; ++k) bits[k] = presenceAt(contours.words, first + 64 * k);
  if ((end - first) % 64) bits[(end - first) / 64] &= (std::uint64_t(1) << ((end - first) % 64)) - 1;
  level.contourBits.append(reinterpret_cast<const std::byte*>(bits.data()), level.voxels);
  level.shownContours.resize(level.voxels, 0);
  std::uint32_t present = first < end ? contours.rank(first) : 0;
  for (std::uint32_t i = first; i < end; ++i)
    if (contours.words[i / 64] >> (i % 64) & 1) level.shownContours[i - first] = contours.values[present++];
  level.shownNormalCodes = std::move(shown);
  return level;
}

}  // namespace

std::size_t LevelGrowth::bytes() const {
  // A resident region's deepest level takes its masks (it held none); a new region adds a link to its parent.
  std::size_t total =
      baseShownNormals.capacity() * sizeof(std::uint16_t) +
      (deepestMasks.empty() ? sizeof(LevelRegion::Link) : IndexedLevel::childMaskBytes(deepestMasks));
  for (const IndexedLevel& l : levels) total += l.bytes();
  return total;
}

LevelPool::LevelPool(const RegionTable& regions, const std::vector<SliceInfo>& slices,
                     const StoreHeader& header)
    : table_(regions),
      slices_(slices),
      header_(header),
      regions_(regions.size()),
      baseShownNormals_(regions.size()) {}

std::size_t LevelPool::bytes(std::uint32_t region) const {
  return regions_[region]
             ? regions_[region]->bytes() + baseShownNormals_[region].capacity() * sizeof(std::uint16_t)
             : 0;
}

OctreeLevel LevelPool::baseParents(std::uint32_t index, LevelGrowth& growth) const {
  const Region& r = table_[index];
  const std::uint32_t parentIndex = std::uint32_t(r.parent);
  const LevelRegion& parent = *regions_[parentIndex];
  const int target = slices_[r.slices.front()].voxelLevel - 1;
  if (parent.deepestLevel() != target)
    throw std::logic_error("pager: a region's parent does not end above its first slice");
  const std::vector<VoxelRange> path =
      voxelsDownTo(*regions_[0], r.cubeLevel, r.cubeCoord, r.firstSlot, r.lastSlot, target);
  const VoxelRange& range = path.back();
  if (range.first < range.end && range.region != &parent)
    throw std::logic_error("pager: a region's base is not on its parent's deepest level");
  growth.baseStart = range.first;
  // Along the path alone: a parent region's whole hierarchy would cost each new region the parent's size.
  growth.baseShownNormals = shownNormalsAlong(parent, baseShownNormals_[parentIndex], path);
  return parentsOf(parent.levels.back().contours, range.first, range.end, growth.baseShownNormals);
}

OctreeLevel LevelPool::startGrowth(std::uint32_t index, std::uint32_t first, LevelGrowth& growth) const {
  assert(first == (regions_[index] ? regions_[index]->levels.size() - 1 : 0));
  if (first > 0) {
    const LevelRegion& region = *regions_[index];
    return parentsOf(region.levels.back().contours, 0, region.levels.back().voxels(),
                     shownNormals(region, baseShownNormals_[index]));
  }
  if (index != 0) return baseParents(index, growth);
  OctreeLevel root = rootLevel(header_);  // the trunk's base is the root, with its own values
  growth.baseShownNormals = root.shownNormalCodes;
  return root;
}

std::optional<std::string> LevelPool::decode(std::uint32_t index, std::uint32_t first,
                                             std::span<const SliceBytes> raw, OctreeLevel&& parents,
                                             LevelGrowth& growth, const std::function<void()>& pause) const {
  const Region& r = table_[index];
  // The level the next slice decodes onto; its child masks, written by that slice, go to their place when
  // done. The first level finished is the one the first slice decoded onto: the resident deepest level,
  // whose masks go to the region's, or a new region's base, masks only (its values are its parent's).
  OctreeLevel above = std::move(parents);
  bool firstFinished = false;
  const auto finish = [&](OctreeLevel& level) {
    level.childMasks.resize(level.voxels, 0);
    if (!std::exchange(firstFinished, true) && (first > 0 || index != 0)) {
      if (first > 0)
        growth.deepestMasks = std::move(level.childMasks);
      else
        growth.levels.emplace_back().setChildMasks(std::move(level.childMasks));
      return;
    }
    level.shownContours = {}, level.shownNormalCodes = {};
    growth.levels.emplace_back(std::move(level));
  };
  std::optional<std::string> error;
  for (std::size_t k = 0; k < raw.size(); ++k) {
    const SliceInfo& info = slices_[r.slices[first + k]];
    OctreeLevel below;
    try {
      if (info.parentCount != above.voxels)
        throw SliceDecodeError("its parents are not the " + std::to_string(above.voxels) +
                               " resident voxels of its cube");
      decodeSliceLevel(raw[k], info, header_, above, 0, below);
    } catch (const std::exception& e) {
      above.childMasks.clear();  // the slice's partial masks go: the level above stays the deepest
      error = e.what();
      break;
    }
    finish(above);
    above = std::move(below);
    ++growth.added;
    pause();
  }
  if (growth.added > 0) finish(above);
  return error;
}

LevelGrowth LevelPool::grow(std::uint32_t index, std::uint32_t first, std::span<const SliceBytes> raw,
                            std::optional<std::string>* error) const {
  LevelGrowth growth;
  OctreeLevel parents = startGrowth(index, first, growth);
  std::optional<std::string> failed = decode(index, first, raw, std::move(parents), growth, [] {});
  if (error) *error = std::move(failed);
  return growth;
}

void LevelPool::install(std::uint32_t index, LevelGrowth&& growth) {
  const Region& r = table_[index];
  std::unique_ptr<LevelRegion>& region = regions_[index];
  // Its bytes and its parent's (whose links a new region joins) are counted again.
  const std::uint32_t parentIndex = r.parent >= 0 ? std::uint32_t(r.parent) : index;
  residentBytes_ -= bytes(index) + (parentIndex != index ? bytes(parentIndex) : 0);
  if (!region) {
    region = std::make_unique<LevelRegion>();
    region->baseLevel = slices_[r.slices.front()].voxelLevel - 1;
    baseShownNormals_[index] = std::move(growth.baseShownNormals);
    if (r.parent >= 0) {
      LevelRegion& parent = *regions_[std::size_t(r.parent)];
      region->parent = &parent;
      region->baseStart = growth.baseStart;
      const LevelRegion::Link link{growth.baseStart, growth.baseStart + growth.levels.front().voxels(),
                                   region.get()};
      parent.links.reserve(parent.links.size() + 1);  // exactly: the room asked for is one link
      parent.links.insert(std::upper_bound(parent.links.begin(), parent.links.end(), link,
                                           [](const auto& a, const auto& b) { return a.first < b.first; }),
                          link);
    }
  } else {
    region->levels.back().setChildMasks(std::move(growth.deepestMasks));
  }
  for (IndexedLevel& level : growth.levels) region->levels.push_back(std::move(level));
  residentBytes_ += bytes(index) + (parentIndex != index ? bytes(parentIndex) : 0);
}

void LevelPool::evict(std::uint32_t index) {
  LevelRegion* region = regions_[index].get();
  assert(index != 0 && region && region->links.empty());
  const std::uint32_t parentIndex = std::uint32_t(table_[index].parent);
  residentBytes_ -= bytes(index) + bytes(parentIndex);
  std::vector<LevelRegion::Link>& links = regions_[parentIndex]->links;
  const auto link =
      std::find_if(links.begin(), links.end(), [&](const auto& l) { return l.region == region; });
  assert(link != links.end());
  links.erase(link);
  regions_[index].reset();
  baseShownNormals_[index] = {};
  residentBytes_ += bytes(parentIndex);
}

void LevelPool::checkInvariants() const {
  const auto fail = [](std::uint32_t r, const std::string& what) {
    throw std::logic_error("pager invariant: region " + std::to_string(r) + " " + what);
  };
  std::size_t held = 0;
  // The normals each parent region's deepest voxels show, found once for all its children.
  std::vector<std::optional<std::vector<std::uint16_t>>> shownByParent(regions_.size());
  for (std::uint32_t r = 0; r < regions_.size(); ++r) {
    const LevelRegion* region = regions_[r].get();
    const Region& info = table_[r];
    if (!region != !info.resident) fail(r, "is resident in the table and not in the pool, or the reverse");
    if (!region) continue;
    held += bytes(r);
    if (region->levels.size() != info.resident + 1) fail(r, "holds a level per slice and its base");
    if (region->baseLevel != slices_[info.slices.front()].voxelLevel - 1)
      fail(r, "is based on a wrong level");
    for (std::size_t l = 1; l < region->levels.size(); ++l) {
      const IndexedLevel& above = region->levels[l - 1];
      if (above.voxels() == 0 || above.children() != region->levels[l].voxels())
        fail(r, "has a level whose voxels are not the children the level above counts");
    }
    for (std::size_t k = 1; k < region->links.size(); ++k)
      if (region->links[k].first < region->links[k - 1].end) fail(r, "has links that overlap");
    if (r == 0) continue;
    const LevelRegion* parent = regions_[std::size_t(info.parent)].get();
    if (region->parent != parent || !parent) fail(r, "is not below its parent region");
    const LevelRegion::Link* link = parent->linkAt(region->baseStart);
    if (region->levels[0].voxels() && (!link || link->region != region || link->first != region->baseStart ||
                                       link->end != region->baseStart + region->levels[0].voxels()))
      fail(r, "is not linked from its parent at its base");
    // The normals its base shows, kept when it was loaded, are those its parent's hierarchy shows there.
    std::optional<std::vector<std::uint16_t>>& shownBelow = shownByParent[std::size_t(info.parent)];
    if (!shownBelow) shownBelow = shownNormals(*parent, baseShownNormals_[std::size_t(info.parent)]);
    const std::vector<std::uint16_t>& shown = *shownBelow;
    const std::vector<std::uint16_t>& kept = baseShownNormals_[r];
    if (kept.size() != region->levels[0].voxels() || region->baseStart + kept.size() > shown.size() ||
        !std::equal(kept.begin(), kept.end(), shown.begin() + region->baseStart))
      fail(r, "keeps normals its base does not show");
  }
  if (held != residentBytes_)
    fail(0, "and the others hold " + std::to_string(held) + " bytes; the pool counts " +
                std::to_string(residentBytes_));
}

}  // namespace svo::paging
