#include "svo/client/level_raycast.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cstring>
#include <stdexcept>
#include <string>

#include "level_descent.hpp"

namespace svo {

using namespace ray_setup;

namespace {

// The level arrays holding the values of voxel `node` of octree level `level`, `node` made its index there: a
// region's base voxel's values are its parent region's.
const IndexedLevel& valuesOf(int level, LevelNode& node) {
  if (level == node.region->baseLevel && node.region->parent)
    node = {node.region->parent, node.region->baseStart + node.index};
  return node.region->levels[std::size_t(level - node.region->baseLevel)];
}

// The children of the voxels before each group of kChildCountGroup, and all of them.
std::uint64_t countChildren(const std::vector<std::uint8_t>& masks, std::size_t voxels,
                            std::vector<std::uint32_t>& counts) {
  counts.clear();
  counts.reserve(voxels / kChildCountGroup + 1);
  std::uint64_t children = 0;
  for (std::size_t i = 0; i < voxels; ++i) {
    if (i % kChildCountGroup == 0) counts.push_back(std::uint32_t(children));
    children += std::uint32_t(std::popcount(unsigned(masks[i])));
  }
  return children;
}

}  // namespace

template <class Value>
PresentValues<Value>::PresentValues(const PresenceBits& bits, std::vector<Value>&& present)
    : values(std::move(present)) {
  // Sized exactly: a pool counts what its arrays hold.
  words.reserve(bits.words().size() + 1);
  words.assign(bits.words().begin(), bits.words().end());
  words.push_back(0);  // a word past the last voxel's, so that find() may look at any voxel's
  counts.reserve(words.size());
  std::uint32_t count = 0;
  for (const std::uint64_t w : words) {
    counts.push_back(count);
    count += std::uint32_t(std::popcount(w));
  }
  if (count != values.size()) throw std::invalid_argument("values are not as many as their presence bits");
}
template struct PresentValues<std::uint32_t>;
template struct PresentValues<std::uint16_t>;

static_assert(kPresenceCountGroup == 64, "PresentValues::find counts within one 64-bit presence word");

IndexedLevel::IndexedLevel(OctreeLevel&& level) {
  const auto perVoxel = [&](const PresenceBits& bits) { return bits.size() == level.voxels; };
  if (level.childMasks.size() != level.voxels || !perVoxel(level.contourBits))
    throw std::invalid_argument("its arrays do not hold a value per voxel");
  contours = PresentValues<std::uint32_t>(level.contourBits, std::move(level.contours));
  if (perVoxel(level.colorBits))
    colors = PresentValues<std::uint32_t>(level.colorBits, std::move(level.colors));
  if (perVoxel(level.normalBits))
    normals = PresentValues<std::uint16_t>(level.normalBits, std::move(level.normalCodes));
  setChildMasks(std::move(level.childMasks));
}

std::uint32_t IndexedLevel::children() const {
  const std::uint32_t n = voxels();
  return n && !childMasks.empty()
             ? firstChild(n - 1) + std::uint32_t(std::popcount(unsigned(childMasks[n - 1])))
             : 0;
}

std::uint64_t IndexedLevel::setChildMasks(std::vector<std::uint8_t>&& masks) {
  const std::size_t voxels = masks.size();
  voxels_ = std::uint32_t(voxels);
  if (std::all_of(masks.begin(), masks.end(), [](std::uint8_t m) { return m == 0; })) {
    childMasks = {}, childCounts = {};  // no voxel has children: nothing to keep
    return 0;
  }
  childMasks = std::move(masks);
  childMasks.reserve(voxels + kChildCountGroup);  // exactly: a pool counts what its arrays hold
  childMasks.resize(voxels + kChildCountGroup, 0);
  return countChildren(childMasks, voxels, childCounts);
}

std::size_t IndexedLevel::childMaskBytes(const std::vector<std::uint8_t>& masks) {
  return std::max(masks.capacity(), masks.size() + kChildCountGroup) +
         (masks.size() / kChildCountGroup + 1) * sizeof(std::uint32_t);
}

std::size_t IndexedLevel::bytes() const {
  const auto part = [](const auto& p) {
    return p.words.capacity() * sizeof p.words[0] + p.counts.capacity() * sizeof p.counts[0] +
           p.values.capacity() * sizeof p.values[0];
  };
  return childMasks.capacity() + childCounts.capacity() * sizeof childCounts[0] + part(contours) +
         part(colors) + part(normals);
}

const LevelRegion::Link* LevelRegion::linkAt(std::uint32_t i) const {
  const auto after = std::upper_bound(links.begin(), links.end(), i,
                                      [](std::uint32_t v, const Link& link) { return v < link.first; });
  if (after == links.begin() || i >= std::prev(after)->end) return nullptr;
  return &*std::prev(after);
}

std::size_t LevelRegion::bytes() const {
  std::size_t total = links.capacity() * sizeof(Link);
  for (const IndexedLevel& level : levels) total += level.bytes();
  return total;
}

LevelOctree::LevelOctree(const std::vector<OctreeLevel>& levels, const StoreHeader& header)
    : hasColors_(header.hasColors), hasNormals_(header.hasNormals) {
  const auto fail = [](std::size_t l, const std::string& what) {
    throw std::invalid_argument("LevelOctree: level " + std::to_string(l) + ": " + what);
  };
  if (levels.empty() || levels[0].voxels != 1) fail(0, "not the root alone");
  if (levels.size() > std::size_t(kMaxLevels) + 1) fail(levels.size() - 1, "deeper than the octree's levels");
  std::uint64_t expected = 1;  // voxels the level above's masks count
  for (std::size_t l = 0; l < levels.size(); ++l) {
    OctreeLevel in = levels[l];
    if (in.voxels != expected) fail(l, "its voxels are not the children the level above counts");
    const auto kept = [&](const PresenceBits& bits, bool has) { return !has || bits.size() == in.voxels; };
    if (!kept(in.colorBits, hasColors_) || !kept(in.normalBits, hasNormals_))
      fail(l, "its arrays do not hold a value per voxel");
    try {
      region_.levels.emplace_back(std::move(in));
    } catch (const std::invalid_argument& e) {
      fail(l, e.what());
    }
    expected = region_.levels.back().children();
    if (l + 1 == levels.size() && expected != 0) fail(l, "the deepest level has children");
  }
  const Level& root = region_.levels[0];
  if ((hasColors_ && root.colors.values.size() != 1) || (hasNormals_ && root.normals.values.size() != 1))
    fail(0, "the root has no value of its own");
}

LevelCastHit castRay(const LevelRegion& root, const OctreeRay& ray, const CastOptions& options) {
  LevelCastHit hit;
  if (root.hasChildren()) castFromRoot(LevelNode{&root, 0}, ray, options, hit, LevelDescent{});
  return hit;
}

LevelNode hitVoxel(const LevelCastHit& hit) {
  const IndexedLevel& parent = LevelDescent::levelOf(*hit.parent.region, hit.scale);
  const std::uint8_t mask = parent.childMasks[hit.parent.index];
  return {hit.parent.region,
          parent.firstChild(hit.parent.index) + std::uint32_t(childRank(mask, hit.childSlot))};
}

LevelHitValues hitValues(const LevelCastHit& hit, bool colors, bool normals) {
  LevelHitValues out;
  if (!hit.hit) return out;
  // The hit voxel, then its ancestors up to the root, each by its level and its index there, until each
  // attribute asked for has a value.
  const auto visit = [&](int level, LevelNode node) {
    const IndexedLevel& l = valuesOf(level, node);
    if (colors && !l.colors.words.empty() && l.colors.find(node.index, out.color)) colors = false;
    std::uint16_t code;
    if (normals && !l.normals.words.empty() && l.normals.find(node.index, code))
      out.normal = latticeNormalBits(code), normals = false;
    return !colors && !normals;
  };
  const int parentLevel = kScaleMax - 1 - hit.scale;
  if (visit(parentLevel + 1, hitVoxel(hit)) || visit(parentLevel, hit.parent)) return out;
  for (int scale = hit.scale + 1; scale < kScaleMax; ++scale)
    if (visit(kScaleMax - 1 - scale, hit.pathParent[scale])) break;
  return out;  // the root keeps its own values: the walk ends there
}

std::uint32_t hitAttribute(const LevelCastHit& hit, AttachmentType type) {
  const bool color = type == AttachmentType::Color;
  if (!color && type != AttachmentType::Normal) return 0;
  const LevelHitValues values = hitValues(hit, color, !color);
  return color ? values.color : values.normal;
}

}  // namespace svo
