// How the ray caster's loop (ray_setup.hpp) and the beam pass (beam.cpp) read an octree held as level arrays
// (level_raycast.hpp): BlockDescent's interface over a region's levels and the regions linked below them.
#pragma once

#include "ray_setup.hpp"
#include "svo/client/level_raycast.hpp"

namespace svo::ray_setup {

// continueRay's reading of level arrays: a parent is its region and its index in its level (kScaleMax - 1 -
// scale), and its children are the level below's from firstChild on, in slot order. A child on its region's
// deepest level where another region is linked is that region's base voxel, whose children are there.
struct LevelDescent {
  using Node = LevelNode;
  struct Parent {  // read once per PUSH or POP
    std::uint8_t validMask;
    std::uint32_t firstChild;
    const IndexedLevel* children;  // the level the children are on
    bool linkedBelow;              // the children are on their region's deepest level, and it has links
  };
  static const IndexedLevel& levelOf(const LevelRegion& region, int scale) {
    return region.levels[std::size_t(kScaleMax - 1 - scale - region.baseLevel)];
  }
  static Parent read(Node parent, int scale) {
    const LevelRegion& region = *parent.region;
    const IndexedLevel* level = &levelOf(region, scale);
    return {level->childMasks[parent.index], level->firstChild(parent.index), level + 1,
            !region.links.empty() && level + 2 == region.levels.data() + region.levels.size()};
  }
  static std::uint32_t childOf(const Parent& p, int slot) {
    return p.firstChild + std::uint32_t(childRank(p.validMask, slot));
  }
  static bool contour(Node, const Parent& p, int slot, int, Contour& c) {
    std::uint32_t bits;
    if (!p.children->contours.find(childOf(p, slot), bits)) return false;
    c = decodeContour(bits);
    return true;
  }
  // A child without children of its own is the hit.
  static bool child(Node parent, const Parent& p, int slot, int, Node& child) {
    child = {parent.region, childOf(p, slot)};
    if (p.children->childMask(child.index) != 0) return true;
    if (!p.linkedBelow) return false;
    const LevelRegion::Link* link = parent.region->linkAt(child.index);
    if (!link) return false;
    child = {link->region, child.index - link->first};
    return link->region->levels[0].childMask(child.index) != 0;
  }
  static void recordPath(LevelCastHit& hit, int scale, Node parent, int) { hit.pathParent[scale] = parent; }
};

}  // namespace svo::ray_setup
