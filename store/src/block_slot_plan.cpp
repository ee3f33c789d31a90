// The slot plan of a block layout (block_layout_parts.hpp): depth-first child runs, far slots behind them, a
// page header every 8 KB, and in the compressed layout runs that start on the half of a unit their siblings'
// pairing asks for.
#include <bit>
#include <cstdint>
#include <vector>

#include "block_layout_parts.hpp"

namespace svo::layout {
namespace {

bool isPageHeaderSlot(std::uint64_t slot) {
  return slot % kSlotsPerPage == 0;
}

// Siblings [begin, end) that go in one run starting on half `half` of a unit.
struct Segment {
  std::uint32_t begin, end;
  int half;
};

// One layout pass for a given set of far voxels. A voxel's far flag is read once, when its parent's run is
// reserved, before the voxel's own run is: so the pass marks the voxels whose run it puts out of reach as it
// goes, without changing its own outcome, and the caller repeats it until it marks none.
class SlotPlanner {
 public:
  // `plan` has an entry per voxel, zero or as the pass before left it: a pass writes every entry the one
  // before wrote (the same voxels are placed, and the far ones only grow in number).
  SlotPlanner(const Collected& collected, std::vector<std::uint8_t>& needsFar, std::uint32_t maxNearPointer,
              const UnitPlacement& units, SlotPlan& plan)
      : c_(collected), needsFar_(needsFar), maxNearPointer_(maxNearPointer), units_(units), plan_(plan) {}

  void plan() {
    next_ = units_.compressed && units_.rootHalf == 0 ? 2 : 1;  // slot 0 is the first page header
    plan_.linkSlots = 0;
    plan_.slotOf[0] = next_++;
    lastUsed_ = next_;
    place(0);
    plan_.slotCount = next_;
  }
  // Voxels this pass found out of reach, now marked far.
  std::uint32_t newlyFar() const { return newlyFar_; }

 private:
  // Reserves `count` consecutive slots inside one page (a run must not straddle a page header). With `half`
  // 0 or 1 the run starts on that half of a unit, and a run starting on a second half follows an empty slot,
  // so that its first descriptor has its unit to itself.
  std::uint32_t reserve(std::uint32_t count, int half = -1) {
    for (;;) {
      const std::uint32_t pageEnd = (next_ / kSlotsPerPage + 1) * kSlotsPerPage;
      if (isPageHeaderSlot(next_) || (half >= 0 && int(next_ % 2) != half) ||
          (half == 1 && !isPageHeaderSlot(next_ - 1) && next_ - 1 < lastUsed_)) {
        ++next_;
      } else if (next_ + count > pageEnd) {
        next_ = pageEnd;  // the rest of the page stays empty; the next page's header comes first
      } else {
        break;
      }
    }
    const std::uint32_t first = next_;
    next_ += count;
    lastUsed_ = next_;
    return first;
  }

  // Descriptors at `first`.. for children[begin, end), then their far slots.
  void placeRun(const std::uint32_t* children, std::uint32_t begin, std::uint32_t end, std::uint32_t first) {
    std::uint32_t farSlot = first + (end - begin);
    for (std::uint32_t k = begin; k < end; ++k) {
      plan_.slotOf[children[k]] = first + (k - begin);
      if (needsFar_[children[k]]) plan_.farSlotOf[children[k]] = farSlot++;
    }
  }
  std::uint32_t farCount(const std::uint32_t* children, std::uint32_t begin, std::uint32_t end) const {
    std::uint32_t count = 0;
    for (std::uint32_t k = begin; k < end; ++k) count += needsFar_[children[k]];
    return count;
  }
  // The compressed layout's runs of siblings: a new one wherever the next sibling cannot take the next slot's
  // half of a unit.
  std::vector<Segment> segmentsOf(const std::uint32_t* children, std::uint32_t count) const {
    std::vector<Segment> segments{{0, 1, units_.startHalf(children[0])}};
    for (std::uint32_t k = 1; k < count; ++k) {
      Segment& s = segments.back();
      const int half = (s.half + int(k - s.begin)) % 2;
      const bool fits =
          half == 0 ? units_.startHalf(children[k]) == 0 : units_.mayShare(children[k - 1], children[k]);
      if (fits) {
        s.end = k + 1;
      } else {
        segments.push_back({k, k + 1, units_.startHalf(children[k])});
      }
    }
    return segments;
  }

  // Depth first from queue entry q: the run of its voxel's non-leaf children (followed by their far slots),
  // then each child's subtree. In the compressed layout, where the children need more than one run to pair
  // into units as they must, the run holds links and each segment follows in a run of its own.
  void place(std::uint32_t q) {
    const Entry& e = c_.entries[q];
    const std::uint32_t nonLeaf = e.childMask & ~e.leafMask;
    if (nonLeaf == 0) return;
    std::uint32_t children[8], count = 0;
    for (std::uint32_t mask = e.childMask, c = e.firstChild; mask; mask &= mask - 1, ++c)
      if (nonLeaf & mask & (0u - mask)) children[count++] = c;
    std::uint32_t first;
    if (!units_.compressed) {
      first = reserve(count + farCount(children, 0, count));
      placeRun(children, 0, count, first);
    } else if (const std::vector<Segment> segments = segmentsOf(children, count); segments.size() == 1) {
      first = reserve(count + farCount(children, 0, count), segments[0].half);
      placeRun(children, 0, count, first);
    } else {
      first = reserve(count);
      for (std::uint32_t k = 0; k < count; ++k) plan_.linkOf[children[k]] = first + k;
      plan_.linkSlots += count;
      for (const Segment& s : segments)
        placeRun(children, s.begin, s.end,
                 reserve(s.end - s.begin + farCount(children, s.begin, s.end), s.half));
    }
    const std::uint32_t v = c_.queue[q].voxel;
    plan_.runOf[v] = first;
    if (!needsFar_[v] && first - plan_.slotOf[v] > maxNearPointer_) needsFar_[v] = 1, ++newlyFar_;
    // The children with children of their own are the queue entries from firstChildEntry on; stubs have none.
    const std::uint32_t entries = std::uint32_t(std::popcount(nonLeaf & ~std::uint32_t(e.stubMask)));
    for (std::uint32_t k = 0; k < entries; ++k) place(e.firstChildEntry + k);
  }

  const Collected& c_;
  std::vector<std::uint8_t>& needsFar_;
  const std::uint32_t maxNearPointer_;
  const UnitPlacement units_;
  SlotPlan& plan_;
  std::uint32_t next_ = 0, lastUsed_ = 0, newlyFar_ = 0;
};

}  // namespace

// Far pointers: lay out, mark every voxel whose run is out of reach, repeat until nothing changes. The marked
// set only grows, so this ends; in practice after one or two extra passes.
SlotPlan planSlots(std::size_t voxelCount, const Collected& collected, const LayoutOptions& options,
                   const UnitPlacement& units, std::uint64_t& farVoxels) {
  std::vector<std::uint8_t> needsFar(voxelCount, 0);
  SlotPlan plan;
  plan.slotOf.assign(voxelCount, 0);
  plan.runOf.assign(voxelCount, 0);
  plan.farSlotOf.assign(voxelCount, 0);
  plan.linkOf.assign(units.compressed ? voxelCount : 0, 0);
  farVoxels = 0;
  for (;;) {
    SlotPlanner planner(collected, needsFar, options.maxNearPointer, units, plan);
    planner.plan();
    if (planner.newlyFar() == 0) return plan;
    farVoxels += planner.newlyFar();
  }
}

}  // namespace svo::layout
