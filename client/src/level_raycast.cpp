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
    if (!octree->level(kScaleMax - scale).contour(childOf(p, slot), bits)) return false;
    c = decodeContour(bits);
    return true;
  }
  // A child without children of its own is the hit.
  bool child(Node, const Parent& p, int slot, int scale, Node& child) const {
    child = childOf(p, slot);
    return octree->level(kScaleMax - scale).childMasks[child] != 0;
  }
  static void recordPath(LevelCastHit&, int, Node, int) {}
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

bool LevelOctree::Level::contour(std::uint32_t i, std::uint32_t& bits) const {
  const std::uint64_t word = contourWords[i / 64];
  const unsigned bit = i % 64;
  if (!((word >> bit) & 1u)) return false;
  bits =
      contours[contourCounts[i / 64] + std::uint32_t(std::popcount(word & ((std::uint64_t(1) << bit) - 1)))];
  return true;
}

static_assert(kChildCountGroup == 8, "firstChild loads a group's masks as one 64-bit word");
static_assert(kPresenceCountGroup == 64, "contour() counts within one 64-bit presence word");

LevelOctree::LevelOctree(const std::vector<OctreeLevel>& levels) {
  const auto fail = [](std::size_t l, const std::string& what) {
    throw std::invalid_argument("LevelOctree: level " + std::to_string(l) + ": " + what);
  };
  if (levels.empty() || levels[0].voxels != 1) fail(0, "not the root alone");
  if (levels.size() > std::size_t(kMaxLevels) + 1) fail(levels.size() - 1, "deeper than the octree's levels");
  std::uint64_t expected = 1;  // voxels the level above's masks count
  for (std::size_t l = 0; l < levels.size(); ++l) {
    const OctreeLevel& in = levels[l];
    if (in.voxels != expected) fail(l, "its voxels are not the children the level above counts");
    if (in.childMasks.size() != in.voxels || in.contourBits.size() != in.voxels)
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
    const std::span<const std::uint64_t> words = in.contourBits.words();
    out.contourWords.assign(words.begin(), words.end());
    std::uint32_t contours = 0;
    for (const std::uint64_t w : out.contourWords) {
      out.contourCounts.push_back(contours);
      contours += std::uint32_t(std::popcount(w));
    }
    if (contours != in.contours.size()) fail(l, "its contours are not as many as their presence bits");
    out.contours = in.contours;
  }
}

LevelCastHit castRay(const LevelOctree& octree, const OctreeRay& ray, const CastOptions& options) {
  LevelCastHit hit;
  if (octree.levels() >= 2) castFromRoot(0u, ray, options, hit, LevelDescent{&octree});
  return hit;
}

}  // namespace svo
