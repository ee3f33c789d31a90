// What block_layout.cpp's passes hand each other: the voxels collected breadth first, and the slot plan
// (block_slot_plan.cpp) that the descriptors, contours and attachments are written by.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "svo/store/block.hpp"
#include "svo/store/store_types.hpp"  // UninitializedAllocator

namespace svo::layout {

struct SlotPlan {
  std::vector<std::uint32_t> slotOf;     // voxel -> its descriptor slot (non-leaf voxels)
  std::vector<std::uint32_t> runOf;      // voxel -> first slot of its non-leaf children's run
  std::vector<std::uint32_t> farSlotOf;  // voxel -> its far slot, or 0
  std::vector<std::uint32_t> linkOf;     // voxel laid out apart -> the link to it in its parent's run, or 0
  std::uint32_t slotCount = 0;
  std::uint32_t linkSlots = 0;
};

// The units voxel `v` carries from a block, or nullptr.
inline const CarriedUnit* carriedUnitOf(const TreeAttachments& tree, std::uint32_t v) {
  if (tree.carriedUnitOf.empty() || tree.carriedUnitOf[v] == kNoCarriedUnit) return nullptr;
  return &tree.carriedUnits[tree.carriedUnitOf[v]];
}

// What the compressed layout asks of the slot plan: runs whose descriptors pair into units as their children
// allow, the root's half, the slices that siblings' children come from (siblings from different slices do not
// share units), and the units carried from a block (siblings share one only where they shared it there).
struct UnitPlacement {
  bool compressed = false;
  const TreeAttachments* tree = nullptr;
  int rootHalf = 1;  // slot 1 (after the first page header), or slot 2 for a carried unit's first half

  const CarriedUnit* carried(std::uint32_t v) const { return carriedUnitOf(*tree, v); }
  // Whether sibling `b` may take the second half of the unit whose first half sibling `a` takes.
  bool mayShare(std::uint32_t a, std::uint32_t b) const {
    if (!tree->childSlice.empty() && tree->childSlice[a] != tree->childSlice[b]) return false;
    const CarriedUnit *x = carried(a), *y = carried(b);
    if (!x || !y) return !x && !y;
    return y->half == 1 && x->sameUnits(*y);
  }
  // The half a run must start `v` on: its carried unit's, else the first.
  int startHalf(std::uint32_t v) const {
    const CarriedUnit* c = carried(v);
    return c ? c->half : 0;
  }
};

// Per non-leaf voxel, breadth first from the root (so each child's effective, possibly inherited, value is
// known from its parent's): its children's contours and, in the raw layout, which children keep a value of
// their own. What the slot plan and the descriptors need is kept per queue entry, so the passes after this
// one read the voxels with children in queue order and never the leaves (three in four voxels).
struct Queued {
  std::uint32_t voxel, color, normal;  // the voxel and its effective values
  std::uint32_t colorAt, normalAt;     // raw layout: where those are kept (kAtBlockRoot: the root's value)
};
inline constexpr std::uint32_t kAtBlockRoot = ~0u;
struct Entry {
  std::uint32_t contourFirst, colorFirst, normalFirst;
  std::uint32_t firstChildEntry;  // queue entry of its first child with children (the others follow)
  std::uint32_t firstChild;       // its first child's record (VoxelRecord::firstChild)
  std::uint8_t childMask, contourMask, colorMask, normalMask, leafMask;
  std::uint8_t stubMask;  // children laid out as stubs: descriptor slots, not queued
};
template <class T>
using Scratch = std::vector<T, UninitializedAllocator<T>>;  // every element is written before it is read
struct Collected {
  Scratch<Queued> queue;
  Scratch<Entry> entries;
  Scratch<std::uint32_t> contours, colors, normals;
};

// Far pointers: lay out, mark every voxel whose run is out of reach, repeat until nothing changes. The marked
// set only grows, so this ends; in practice after one or two extra passes.
SlotPlan planSlots(std::size_t voxelCount, const Collected& collected, const LayoutOptions& options,
                   const UnitPlacement& units, std::uint64_t& farVoxels);

}  // namespace svo::layout
