#include "svo/client/level_raycast.hpp"

#include <bit>
#include <cstring>
#include <stdexcept>
#include <string>

#include "ray_setup.hpp"

namespace svo {

using namespace ray_setup;

namespace {

// continueRay's reading of level arrays: a parent is its index in its level (kScaleMax - 1 - scale), and
// its children are the level below's from firstChild on, in slot order.
struct LevelDescent {
  const LevelOctree* octree;
  using Node = std::uint32_t;
  struct Parent {
    std::uint8_t validMask;
    std::uint32_t firstChild;
  };
  Parent read(Node parent, int scale) const {
    const LevelOctree::Level& level = octree->level(kScaleMax - 1 - scale);
    return {level.childMasks[parent], level.firstChild(parent)};
  }
  static std::uint32_t childOf(const Parent& p, int slot) {
    return p.firstChild + std::uint32_t(childRank(p.validMask, slot));
  }
  bool contour(Node, const Parent& p, int slot, int scale, Contour& c) const {
    std::uint32_t bits;
    if (!octree->level(kScaleMax - scale).contours.find(childOf(p, slot), bits)) return false;
    c = decodeContour(bits);
    return true;
  }
  // A child without children of its own is the hit.
  bool child(Node, const Parent& p, int slot, int scale, Node& child) const {
    child = childOf(p, slot);
    return octree->level(kScaleMax - scale).childMasks[child] != 0;
  }
  static void recordPath(LevelCastHit& hit, int scale, Node parent, int) { hit.pathParent[scale] = parent; }
};

}  // namespace

std::uint32_t LevelOctree::Level::firstChild(std::uint32_t i) const {
  const std::uint32_t group = i / kChildCountGroup * kChildCountGroup;
  std::uint64_t masks;
  std::memcpy(&masks, childMasks.data() + group, sizeof masks);
  const unsigned before = 8 * (i - group);  // bits of the masks before voxel i in its group
  masks = before ? masks & ((std::uint64_t(1) << before) - 1) : 0;
  return childCounts[i / kChildCountGroup] + std::uint32_t(std::popcount(masks));
}

template <class Value>
PresentValues<Value>::PresentValues(const PresenceBits& bits, const std::vector<Value>& present)
    : words(bits.words().begin(), bits.words().end()), values(present) {
  words.push_back(0);  // a word past the last voxel's, so that find() may look at any voxel's
  std::uint32_t count = 0;
  for (const std::uint64_t w : words) {
    counts.push_back(count);
    count += std::uint32_t(std::popcount(w));
  }
  if (count != values.size()) throw std::invalid_argument("values are not as many as their presence bits");
}
template struct PresentValues<std::uint32_t>;
template struct PresentValues<std::uint16_t>;

static_assert(kChildCountGroup == 8, "firstChild loads a group's masks as one 64-bit word");
static_assert(kPresenceCountGroup == 64, "PresentValues::find counts within one 64-bit presence word");

LevelOctree::LevelOctree(const std::vector<OctreeLevel>& levels, const StoreHeader& header)
    : hasColors_(header.hasColors), hasNormals_(header.hasNormals) {
  const auto fail = [](std::size_t l, const std::string& what) {
    throw std::invalid_argument("LevelOctree: level " + std::to_string(l) + ": " + what);
  };
  if (levels.empty() || levels[0].voxels != 1) fail(0, "not the root alone");
  if (levels.size() > std::size_t(kMaxLevels) + 1) fail(levels.size() - 1, "deeper than the octree's levels");
  std::uint64_t expected = 1;  // voxels the level above's masks count
  for (std::size_t l = 0; l < levels.size(); ++l) {
    const OctreeLevel& in = levels[l];
    if (in.voxels != expected) fail(l, "its voxels are not the children the level above counts");
    const auto perVoxel = [&](const PresenceBits& bits, bool kept) {
      return !kept || bits.size() == in.voxels;
    };
    if (in.childMasks.size() != in.voxels || !perVoxel(in.contourBits, true) ||
        !perVoxel(in.colorBits, hasColors_) || !perVoxel(in.normalBits, hasNormals_))
      fail(l, "its arrays do not hold a value per voxel");
    Level& out = levels_.emplace_back();
    out.childMasks = in.childMasks;
    out.childMasks.resize(in.voxels + kChildCountGroup, 0);
    std::uint32_t children = 0;
    for (std::size_t i = 0; i < in.voxels; ++i) {
      if (i % kChildCountGroup == 0) out.childCounts.push_back(children);
      children += std::uint32_t(std::popcount(unsigned(in.childMasks[i])));
    }
    if (l + 1 == levels.size() && children != 0) fail(l, "the deepest level has children");
    expected = children;
    try {
      out.contours = PresentValues<std::uint32_t>(in.contourBits, in.contours);
      if (hasColors_) out.colors = PresentValues<std::uint32_t>(in.colorBits, in.colors);
      if (hasNormals_) out.normals = PresentValues<std::uint16_t>(in.normalBits, in.normalCodes);
    } catch (const std::invalid_argument& e) {
      fail(l, e.what());
    }
  }
  if ((hasColors_ && levels_[0].colors.values.size() != 1) ||
      (hasNormals_ && levels_[0].normals.values.size() != 1))
    fail(0, "the root has no value of its own");
}

LevelCastHit castRay(const LevelOctree& octree, const OctreeRay& ray, const CastOptions& options) {
  LevelCastHit hit;
  if (octree.levels() >= 2) castFromRoot(0u, ray, options, hit, LevelDescent{&octree});
  return hit;
}

std::uint32_t hitAttribute(const LevelOctree& octree, const LevelCastHit& hit, AttachmentType type) {
  const bool color = type == AttachmentType::Color;
  if (!hit.hit || (color ? !octree.hasColors() : type != AttachmentType::Normal || !octree.hasNormals()))
    return 0;
  // The hit voxel, then its ancestors up to the root, each by its level and its index there.
  const auto valueOf = [&](int level, std::uint32_t i, std::uint32_t& value) {
    const LevelOctree::Level& l = octree.level(level);
    std::uint16_t code;
    if (color) return l.colors.find(i, value);
    if (!l.normals.find(i, code)) return false;
    value = latticeNormalBits(code);
    return true;
  };
  const int parentLevel = kScaleMax - 1 - hit.scale;
  const LevelOctree::Level& parent = octree.level(parentLevel);
  const std::uint8_t mask = parent.childMasks[hit.parent];
  std::uint32_t value = 0;
  if (valueOf(parentLevel + 1, parent.firstChild(hit.parent) + std::uint32_t(childRank(mask, hit.childSlot)),
              value) ||
      valueOf(parentLevel, hit.parent, value))
    return value;
  for (int scale = hit.scale + 1; scale < kScaleMax; ++scale)
    if (valueOf(kScaleMax - 1 - scale, hit.pathParent[scale], value)) return value;
  return value;  // the root keeps its own value: the walk ends there
}

}  // namespace svo
