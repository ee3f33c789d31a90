// Block layout (block.hpp): the voxels collected breadth first, a slot plan (block_slot_plan.cpp: depth-first
// child runs, far pointers, a page header every 8 KB; in the compressed layout every run starts on a unit's
// first half, and siblings whose children come from different slices are laid out apart behind links), then
// the descriptors, contours and attachments of either attribute layout.
#include <algorithm>
#include <array>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <memory>
#include <numbers>
#include <stdexcept>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <glm/geometric.hpp>

#include "block_layout_parts.hpp"
#include "svo/store/block.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

InheritanceRule::InheritanceRule(const LayoutOptions& options)
    : colorSteps_(options.colorInheritSteps),
      normalCos_(std::cos(options.normalInheritDegrees * 3.14159265f / 180.0f)),
      equalOnly_(options.inheritEqualOnly) {}

bool InheritanceRule::color(std::uint32_t a, std::uint32_t b) const {
  if (equalOnly_) return a == b;
  for (int shift = 0; shift < 32; shift += 8)
    if (std::abs(int((a >> shift) & 255u) - int((b >> shift) & 255u)) > colorSteps_) return false;
  return true;
}
InheritanceRule::ParentNormal InheritanceRule::parentNormal(std::uint32_t parentEffective) const {
  if (equalOnly_) return {parentEffective, glm::vec3(0.0f), 0.0f};  // normal() compares the bits alone
  const glm::vec3 q = normalDirection(parentEffective);
  return {parentEffective, q, glm::dot(q, q)};
}
bool InheritanceRule::normal(std::uint32_t a, const ParentNormal& parent) const {
  if (a == parent.bits) return true;
  if (equalOnly_) return false;
  // The angle's cosine against the threshold without normalizing either: one square root, not two
  // normalizations (this test runs per voxel in every layout).
  const glm::vec3 p = normalDirection(a);
  return glm::dot(p, parent.direction) >= normalCos_ * std::sqrt(glm::dot(p, p) * parent.lengthSquared);
}

const char* nameOf(AttributeLayout layout) {
  return layout == AttributeLayout::Compressed ? "compressed" : "raw";
}

namespace {

using namespace layout;

// Level-order trees keep no first-child index or stub flag per voxel: collect counts the one and takes the
// other from the tree's ascending stub list, as it visits the voxels in index order.
template <class Tree>
constexpr bool kLevelOrder = std::is_same_v<Tree, LevelOrderTree>;

template <class Tree>
Collected collect(const Tree& tree, const LayoutOptions& options, LayoutStats& stats) {
  const std::size_t n = tree.voxels.size();
  // The compressed layout keeps no values here, but its units need the effective values too.
  const bool raw = options.attributes == AttributeLayout::Raw;
  const bool colors = tree.hasColors, normals = tree.hasNormals;
  const InheritanceRule inherits(options);
  Collected out;
  // Sized for the most there can be and written through pointers, then cut to what was written: no bounds
  // check or size update per value.
  out.queue.resize(n), out.entries.resize(n);
  // A value is written at its cursor before the cursor moves: one element where none is kept.
  out.contours.resize(n), out.colors.resize(raw && colors ? n : 1),
      out.normals.resize(raw && normals ? n : 1);
  Queued* const queue = out.queue.data();
  std::uint32_t* const contourOut = out.contours.data();
  std::uint32_t* const colorOut = out.colors.data();
  std::uint32_t* const normalOut = out.normals.data();
  std::size_t queued = 1, contourCount = 0, colorCount = 0, normalCount = 0;
  std::uint64_t inheritedColors = 0, inheritedNormals = 0, stubs = 0;
  std::uint32_t nextChild = 1;  // level order: the first child of the voxel visited next
  std::size_t nextStub = 0;     // level order: the first stub not yet passed
  // A child's value is written at its cursor, which moves where the child keeps a value of its own (raw
  // layout); `shown` and `shownAt` become the value the child's children inherit and where it is kept.
  const auto keep = [raw](bool own, std::uint32_t value, std::uint32_t& shown, std::uint32_t& shownAt,
                          std::uint32_t bit, std::uint32_t* values, std::size_t& count, std::uint32_t& mask) {
    values[count] = value;
    shown = own ? value : shown;
    shownAt = own ? std::uint32_t(count) : shownAt;
    count += raw && own;
    mask |= own ? bit : 0u;
  };
  queue[0] = {0, tree.voxels[0].color, tree.voxels[0].normal, kAtBlockRoot, kAtBlockRoot};
  for (std::size_t qi = 0; qi < queued; ++qi) {
    const Queued parent = queue[qi];
    const auto& r = tree.voxels[parent.voxel];
    std::uint32_t firstChild;
    if constexpr (kLevelOrder<Tree>) {
      firstChild = nextChild;
      nextChild += std::uint32_t(std::popcount(unsigned(r.childMask)));
      assert(nextChild <= n);
    } else {
      firstChild = r.firstChild;
    }
    const InheritanceRule::ParentNormal parentNormal =
        normals ? inherits.parentNormal(parent.normal) : InheritanceRule::ParentNormal{};
    const std::size_t contourFirst = contourCount, colorFirst = colorCount, normalFirst = normalCount,
                      firstChildEntry = queued;
    // Set bits only, and only voxels with children queued. No branch on a child's values: each output is
    // written at its cursor, and the cursor moves where the child has one.
    std::uint32_t contourMask = 0, colorMask = 0, normalMask = 0, leafMask = 0, stubMask = 0;
    for (std::uint32_t mask = r.childMask, c = firstChild; mask; mask &= mask - 1, ++c) {
      const std::uint32_t bit = mask & (0u - mask);
      const auto& child = tree.voxels[c];
      contourOut[contourCount] = child.contour;
      contourCount += child.hasContour;
      contourMask |= child.hasContour ? bit : 0u;
      Queued& q = queue[queued];
      q = {c, parent.color, parent.normal, parent.colorAt, parent.normalAt};
      if (colors)
        keep(!inherits.color(child.color, parent.color), child.color, q.color, q.colorAt, bit, colorOut,
             colorCount, colorMask);
      if (normals)
        keep(!inherits.normal(child.normal, parentNormal), child.normal, q.normal, q.normalAt, bit, normalOut,
             normalCount, normalMask);
      bool stub;
      if constexpr (kLevelOrder<Tree>) {
        while (nextStub < tree.stubs.size() && tree.stubs[nextStub] < c) ++nextStub;
        stub = nextStub < tree.stubs.size() && tree.stubs[nextStub] == c;
      } else {
        stub = child.stub;
      }
      const bool hasChildren = child.childMask != 0;
      stub &= !hasChildren;
      queued += hasChildren;
      stubMask |= stub ? bit : 0u;  // all-zero stub descriptor and lookup entries (format.hpp)
      leafMask |= !hasChildren && !stub ? bit : 0u;
    }
    out.entries[qi] = Entry{.contourFirst = std::uint32_t(contourFirst),
                            .colorFirst = std::uint32_t(colorFirst),
                            .normalFirst = std::uint32_t(normalFirst),
                            .firstChildEntry = std::uint32_t(firstChildEntry),
                            .firstChild = firstChild,
                            .childMask = r.childMask,
                            .contourMask = std::uint8_t(contourMask),
                            .colorMask = std::uint8_t(colorMask),
                            .normalMask = std::uint8_t(normalMask),
                            .leafMask = std::uint8_t(leafMask),
                            .stubMask = std::uint8_t(stubMask)};
    const int children = std::popcount(r.childMask);
    if (colors) inheritedColors += std::uint64_t(children - std::popcount(colorMask));
    if (normals) inheritedNormals += std::uint64_t(children - std::popcount(normalMask));
    stubs += std::uint64_t(std::popcount(stubMask));
  }
  out.queue.resize(queued), out.entries.resize(queued);
  out.contours.resize(contourCount), out.colors.resize(colorCount), out.normals.resize(normalCount);
  stats.inheritedColors += inheritedColors, stats.inheritedNormals += inheritedNormals;
  stats.descriptorSlots += stubs;
  return out;
}

// The raw layout's lookup entry of a voxel whose children's values start at `first` (after the `slotCount`
// entries); where none has its own, it points at the value they show, kept at `shownAt`.
std::uint32_t lookupEntry(std::uint32_t slotCount, std::uint32_t first, std::uint8_t mask,
                          std::uint32_t shownAt) {
  if (mask != 0) return AttributeLookup::make(slotCount + first, mask).bits;
  if (shownAt == kAtBlockRoot) return AttributeLookup::make(AttributeLookup::kShownByBlockRoot, 0).bits;
  const std::uint64_t pointer = std::uint64_t(slotCount) + shownAt;
  // Out of the pointer's reach (or on the root's code): the entry does not say, a look-up walks up.
  return AttributeLookup::make(pointer < AttributeLookup::kShownByBlockRoot ? std::uint32_t(pointer) : 0, 0)
      .bits;
}

// The compressed layout's units, before the block is sized: per pair of slots, a unit of the effective
// values (sec. 5.4) of the children of the descriptors in its two halves; carried units as they were. A pair
// goes without a unit where every child is within the inheritance tolerance of the value its parent shows
// (decoded from the pair above, or shown by an ancestor in turn), so that no unit's error spreads to the
// levels below it. Pairs hold siblings, so they are encoded a depth at a time, top down (what a parent
// shows is known before its children's pair is decided), and in parallel within a depth (in order on the
// calling thread where LayoutOptions::betweenPasses pauses it).
struct EncodedUnits {
  static constexpr std::uint8_t kColor = 1, kNormal = 2;
  std::uint32_t pairs = 0;
  std::vector<ColorUnit> colors;  // per pair; where kept
  std::vector<NormalUnit> normals;
  std::vector<std::uint8_t> kept;  // per pair: kColor | kNormal
  // Per pair, an exact normal unit's values by unit slot (null where the pair holds a grid unit or none).
  std::vector<std::unique_ptr<std::array<std::uint32_t, kUnitSlots>>> exactNormals;
  std::uint32_t colorCount = 0, normalCount = 0, exactNormalUnits = 0, exactNormalValues = 0;
  std::uint64_t halvesUsed = 0;
};

// The root's color and normal as the block shows them (TreeAttachments::shownRoot).
template <class Tree>
std::pair<std::uint32_t, std::uint32_t> shownRoot(const Tree& tree) {
  return tree.shownRoot.value_or(std::pair{tree.voxels[0].color, tree.voxels[0].normal});
}

template <class Tree>
class UnitEncoder {
 public:
  UnitEncoder(const Tree& tree, const SlotPlan& plan, const Collected& c, const LayoutOptions& options)
      : tree_(tree),
        plan_(plan),
        c_(c),
        rule_(tolerant(options)),
        exactSquaredChord_(squaredChord(options.exactNormalUnitDegrees)),
        pause_(options.betweenPasses) {
    out_.pairs = (plan.slotCount + 1) / 2;
    owner_.assign(std::size_t(out_.pairs) * 2, kNone);
    for (std::size_t q = 0; q < c.queue.size(); ++q) owner_[plan.slotOf[c.queue[q].voxel]] = std::uint32_t(q);
    out_.colors.resize(tree.hasColors ? out_.pairs : 0);
    out_.normals.resize(tree.hasNormals ? out_.pairs : 0);
    out_.exactNormals.resize(tree.hasNormals ? out_.pairs : 0);
    out_.kept.assign(out_.pairs, 0);
    shownColor_.resize(c.queue.size()), shownNormal_.resize(c.queue.size());
    std::tie(shownColor_[0], shownNormal_[0]) = shownRoot(tree);
  }

  EncodedUnits encode() {
    // The pairs by depth: the queue is breadth first, so each depth's descriptors follow the one above.
    std::vector<std::uint32_t> depthOf(c_.queue.size(), 0), pairs;
    std::vector<std::size_t> depthStart{0};
    std::vector<std::uint8_t> listed(out_.pairs, 0);
    for (std::size_t q = 0; q < c_.queue.size(); ++q) {
      for (std::uint32_t k = c_.entries[q].firstChildEntry; k < childEntriesEnd(q); ++k)
        depthOf[k] = depthOf[q] + 1;
      if (q > 0 && depthOf[q] != depthOf[q - 1]) depthStart.push_back(pairs.size());
      const std::uint32_t pair = plan_.slotOf[c_.queue[q].voxel] / 2;
      if (!listed[pair]) listed[pair] = 1, pairs.push_back(pair);
    }
    depthStart.push_back(pairs.size());
    if (pause_) {
      // On the calling thread, pausing every few pairs: a pager worker, whose threads the pager counts and
      // stops while a frame renders, must not spread onto every core.
      for (std::size_t i = 0; i < pairs.size(); ++i) {
        encodePair(pairs[i]);
        if (i % kPairsBetweenPauses == kPairsBetweenPauses - 1) pause_();
      }
    } else {
      for (std::size_t d = 0; d + 1 < depthStart.size(); ++d)
        tbb::parallel_for(tbb::blocked_range<std::size_t>(depthStart[d], depthStart[d + 1], 128),
                          [&](const auto& range) {
                            for (std::size_t i = range.begin(); i != range.end(); ++i) encodePair(pairs[i]);
                          });
    }
    for (std::uint32_t u = 0; u < out_.pairs; ++u) {
      out_.colorCount += (out_.kept[u] & EncodedUnits::kColor) != 0;
      out_.normalCount += (out_.kept[u] & EncodedUnits::kNormal) != 0;
      if (tree_.hasNormals && out_.exactNormals[u]) {
        ++out_.exactNormalUnits;
        out_.exactNormalValues += std::uint32_t(std::popcount(out_.normals[u].words[2]));
      }
    }
    out_.halvesUsed = c_.queue.size();  // each descriptor with children takes one half
    return std::move(out_);
  }

 private:
  static constexpr std::uint32_t kNone = 0xFFFFFFFFu;
  // The tolerances, whatever the layout's inheritance: what a parent shows is decoded, never equal.
  static InheritanceRule tolerant(LayoutOptions options) {
    options.inheritEqualOnly = false;
    return InheritanceRule(options);
  }
  // The squared chord between unit vectors `degrees` apart (what encodeNormalUnit's error sums); infinite
  // for 0, where no unit is exact.
  static float squaredChord(float degrees) {
    if (!(degrees > 0.0f)) return std::numeric_limits<float>::infinity();
    const double chord = 2.0 * std::sin(double(degrees) * std::numbers::pi / 360.0);
    return float(chord * chord);
  }
  // The normal pair `u`'s unit shows at unit slot `slot`, as a decoder gives it (cube encoding).
  std::uint32_t shownNormalOf(std::uint32_t u, int slot) const {
    const auto& exact = out_.exactNormals[u];
    return encodeNormal(exact ? decodeNormal((*exact)[std::size_t(slot)])
                              : decodeNormalUnit(out_.normals[u], slot));
  }
  // The queue entries of entry q's children with children: from its firstChildEntry to the next entry's.
  std::uint32_t childEntriesEnd(std::size_t q) const {
    return q + 1 < c_.queue.size() ? c_.entries[q + 1].firstChildEntry : std::uint32_t(c_.queue.size());
  }

  // Decides and encodes pair `u` (what its descriptors show is known), then records what each child with
  // children shows.
  void encodePair(std::uint32_t u) {
    const std::uint32_t a = owner_[2 * std::size_t(u)], b = owner_[2 * std::size_t(u) + 1];
    const auto carried = [&](std::uint32_t q) {
      return q != kNone ? carriedUnitOf(tree_, c_.queue[q].voxel) : nullptr;
    };
    if (const CarriedUnit* kept = carried(a) ? carried(a) : carried(b)) {
      // Siblings read back from one pair land in one pair again (the pairing depends on the tree alone).
      assert(!carried(a) || !carried(b) || carried(a)->sameUnits(*carried(b)));
      assert((a == kNone || carried(a)) && (b == kNone || carried(b)));
      if (tree_.hasColors && kept->hasColor)
        out_.colors[u] = kept->color, out_.kept[u] |= EncodedUnits::kColor;
      if (tree_.hasNormals && kept->hasNormal) {
        out_.normals[u] = kept->normal, out_.kept[u] |= EncodedUnits::kNormal;
        if (isExact(kept->normal))
          out_.exactNormals[u] = std::make_unique<std::array<std::uint32_t, kUnitSlots>>(kept->exactNormals);
      }
    } else {
      encodeNew(u, a, b);
    }
    // What the children with children show: their slot of this pair's unit, or their parent's value.
    for (int half = 0; half < 2; ++half) {
      const std::uint32_t q = half == 0 ? a : b;
      if (q == kNone) continue;
      const Entry& e = c_.entries[q];
      std::uint32_t next = e.firstChildEntry;
      for (std::uint32_t mask = e.childMask, child = e.firstChild; mask; mask &= mask - 1, ++child) {
        if (tree_.voxels[child].childMask == 0) continue;
        const int slot = half * 8 + std::countr_zero(mask);
        shownColor_[next] =
            (out_.kept[u] & EncodedUnits::kColor) ? decodeColorUnit(out_.colors[u], slot) : shownColor_[q];
        shownNormal_[next] =
            (out_.kept[u] & EncodedUnits::kNormal) ? shownNormalOf(u, slot) : shownNormal_[q];
        ++next;
      }
    }
  }

  // A pair not carried from a block: its children's effective values, and a unit of each type where some
  // child is off the value its parent shows.
  void encodeNew(std::uint32_t u, std::uint32_t a, std::uint32_t b) {
    std::array<std::uint32_t, kUnitSlots> colors{}, normalBits{};
    std::uint16_t usedSlots = 0;
    bool ownColor = false, ownNormal = false;
    for (int half = 0; half < 2; ++half) {
      const std::uint32_t q = half == 0 ? a : b;
      if (q == kNone) continue;
      const Queued& parent = c_.queue[q];
      const Entry& e = c_.entries[q];
      const InheritanceRule::ParentNormal shown = rule_.parentNormal(shownNormal_[q]);
      for (std::uint32_t mask = e.childMask, child = e.firstChild; mask; mask &= mask - 1, ++child) {
        const int childSlot = std::countr_zero(mask), slot = half * 8 + childSlot;
        usedSlots |= std::uint16_t(1u << slot);
        colors[slot] = (e.colorMask >> childSlot & 1u) ? tree_.voxels[child].color : parent.color;
        normalBits[slot] = (e.normalMask >> childSlot & 1u) ? tree_.voxels[child].normal : parent.normal;
        ownColor |= !rule_.color(colors[slot], shownColor_[q]);
        ownNormal |= !rule_.normal(normalBits[slot], shown);
      }
    }
    if (tree_.hasColors && ownColor)
      out_.colors[u] = encodeColorUnit(colors, usedSlots), out_.kept[u] |= EncodedUnits::kColor;
    if (tree_.hasNormals && ownNormal) {
      std::array<glm::vec3, kUnitSlots> normals{};
      for (int slot = 0; slot < kUnitSlots; ++slot)
        if (usedSlots >> slot & 1u) normals[slot] = normalDirection(normalBits[slot]);
      float squaredError = 0.0f;
      out_.normals[u] = encodeNormalUnit(normals, usedSlots, &squaredError);
      out_.kept[u] |= EncodedUnits::kNormal;
      if (squaredError > exactSquaredChord_ * float(std::popcount(usedSlots))) {
        // No grid comes near enough: the pair keeps its children's values.
        out_.normals[u] = NormalUnit{{0u, kExactNormalAxes, usedSlots, 0u}};
        auto& exact = out_.exactNormals[u] = std::make_unique<std::array<std::uint32_t, kUnitSlots>>();
        for (int slot = 0; slot < kUnitSlots; ++slot)
          if (usedSlots >> slot & 1u) (*exact)[std::size_t(slot)] = normalBits[slot];
      }
    }
  }

  const Tree& tree_;
  const SlotPlan& plan_;
  const Collected& c_;
  const InheritanceRule rule_;
  const float exactSquaredChord_;  // per used slot, mean
  const std::function<void()>& pause_;
  std::vector<std::uint32_t> owner_;                     // slot -> queue entry
  std::vector<std::uint32_t> shownColor_, shownNormal_;  // per queue entry: the value the voxel shows
  EncodedUnits out_;
};

// Where each section starts, in bytes from the block's start: slots | info + directory | contours |
// attachments (raw: lookup array + values per type; compressed: unit directory + units per type, then exact
// values).
struct Sections {
  std::size_t info = 0, contours = 0, color = 0, normal = 0, exactColors = 0, exactNormals = 0, end = 0;
  std::uint32_t attachmentCount = 0;
};

Sections sections(const TreeAttachments& tree, const LayoutOptions& options, std::uint32_t slotCount,
                  const Collected& c, const EncodedUnits& units) {
  Sections s;
  const bool compressed = options.attributes == AttributeLayout::Compressed;
  s.attachmentCount = std::uint32_t(tree.hasColors) + std::uint32_t(tree.hasNormals) +
                      std::uint32_t(!tree.exactColors.empty()) + std::uint32_t(!tree.exactNormals.empty());
  s.info = std::size_t(slotCount) * kSlotBytes;
  s.contours = s.info + sizeof(BlockInfo) + s.attachmentCount * sizeof(AttachmentEntry);
  std::size_t cursor = s.contours + c.contours.size() * 4;
  s.color = cursor;
  if (tree.hasColors)
    cursor += compressed
                  ? (unitDirectoryWords(slotCount) + std::size_t(units.colorCount) * kColorUnitWords) * 4
                  : (std::size_t(slotCount) + c.colors.size()) * 4;
  s.normal = cursor;
  if (tree.hasNormals)
    cursor += compressed ? (unitDirectoryWords(slotCount) +
                            std::size_t(units.normalCount) * kNormalUnitWords + units.exactNormalValues) *
                               4
                         : (std::size_t(slotCount) + c.normals.size()) * 4;
  s.exactColors = cursor;
  cursor += tree.exactColors.size() * 4;
  s.exactNormals = cursor;
  cursor += (tree.exactNormals.size() + 1) / 2 * 4;
  s.end = cursor;
  if (cursor > std::size_t(INT32_MAX) * 4 ||
      slotCount + std::max(c.colors.size(), c.normals.size()) > kMaxWordPointer)
    throw BlockTooLarge("octree too large for one block (" + std::to_string(cursor >> 20) +
                        " MiB; its pointers reach 2^24 words): stream it through a block pool");
  return s;
}

// One compressed attachment at `words`: the unit directory (kUnitGroup pairs per entry), then the kept units.
template <class Unit>
void writeUnits(const EncodedUnits& encoded, const std::vector<Unit>& units, std::uint8_t kind,
                std::uint32_t slotCount, std::uint32_t* words) {
  constexpr std::size_t kWords = std::tuple_size_v<decltype(Unit::words)>;
  std::uint32_t* out = words + unitDirectoryWords(slotCount);
  std::uint32_t count = 0;
  for (std::uint32_t pair = 0; pair < encoded.pairs; ++pair) {
    std::uint32_t* entry = words + 2 * (pair / kUnitGroup);
    if (pair % kUnitGroup == 0) entry[1] = count;
    if (!(encoded.kept[pair] & kind)) continue;
    entry[0] |= 1u << (pair % kUnitGroup);
    std::memcpy(out + std::size_t(count++) * kWords, units[pair].words.data(), kWords * 4);
  }
}

// The exact normal units' values behind the normal attachment's units (written by writeUnits), in the
// units' order, and each exact unit's offset to its values.
void writeExactNormals(const EncodedUnits& encoded, std::uint32_t slotCount, std::uint32_t* words) {
  std::uint32_t* unit = words + unitDirectoryWords(slotCount);
  std::uint32_t* values = unit + std::size_t(encoded.normalCount) * kNormalUnitWords;
  for (std::uint32_t pair = 0; pair < encoded.pairs; ++pair) {
    if (!(encoded.kept[pair] & EncodedUnits::kNormal)) continue;
    if (const auto& exact = encoded.exactNormals[pair]) {
      unit[0] = std::uint32_t(values - unit);
      for (std::uint32_t mask = unit[2]; mask; mask &= mask - 1) *values++ = (*exact)[std::countr_zero(mask)];
    }
    unit += kNormalUnitWords;
  }
}

template <class Tree>
Block layOutTree(const Tree& tree, const LayoutOptions& options, LayoutStats* statsOut,
                 std::vector<std::uint32_t>* descriptorSlot) {
  if (tree.voxels.empty() || tree.voxels[0].childMask == 0)
    throw std::invalid_argument("layoutBlock: the tree has no voxels below the root");
  // A run of 8 descriptors followed by up to 8 far slots must stay in reach of its own descriptors.
  if (options.maxNearPointer < 16 || options.maxNearPointer > kMaxNearPointer)
    throw std::invalid_argument("layoutBlock: maxNearPointer must be in [16, 32767]");
  const std::size_t n = tree.voxels.size();
  const bool compressed = options.attributes == AttributeLayout::Compressed;
  const auto sized = [n](const auto& v) { return v.empty() || v.size() == n; };
  if (!sized(tree.childSlice) || !sized(tree.carriedUnitOf))
    throw std::invalid_argument("layoutBlock: childSlice and carriedUnitOf need one entry per voxel");
  if (!compressed && (!tree.carriedUnitOf.empty() || !tree.exactColors.empty() || !tree.exactNormals.empty()))
    throw std::invalid_argument("layoutBlock: carried units and exact values need the compressed layout");

  UnitPlacement units;
  units.compressed = compressed;
  units.tree = &tree;
  if (compressed && units.carried(0)) units.rootHalf = units.carried(0)->half;
  LayoutStats stats;
  const auto pause = [&] {
    if (options.betweenPasses) options.betweenPasses();
  };
  const Collected c = collect(tree, options, stats);
  pause();
  std::uint64_t farVoxels = 0;
  SlotPlan plan = planSlots(n, c, options, units, farVoxels);
  pause();
  const std::uint32_t slotCount = plan.slotCount;
  const EncodedUnits encoded =
      compressed ? UnitEncoder<Tree>(tree, plan, c, options).encode() : EncodedUnits{};
  if (compressed) pause();
  const Sections s = sections(tree, options, slotCount, c, encoded);

  AlignedBytes bytes(s.end);
  std::byte* base = bytes.data();
  auto* slots = reinterpret_cast<ChildDescriptor*>(base);
  for (std::uint32_t page = 0; std::size_t(page) * kSlotsPerPage < slotCount; ++page)
    *reinterpret_cast<std::int32_t*>(base + std::size_t(page) * kPageBytes) =
        std::int32_t((s.info - std::size_t(page) * kPageBytes) / 4);

  auto* info = reinterpret_cast<BlockInfo*>(base + s.info);
  *info = BlockInfo{kBlockInfoMagic, -std::int32_t(s.info / 4),        slotCount,
                    plan.slotOf[0],  std::uint32_t(c.contours.size()), s.attachmentCount};
  auto* directory = reinterpret_cast<AttachmentEntry*>(info + 1);
  if (!c.contours.empty()) std::memcpy(base + s.contours, c.contours.data(), c.contours.size() * 4);
  auto* colorWords = reinterpret_cast<std::uint32_t*>(base + s.color);
  auto* normalWords = reinterpret_cast<std::uint32_t*>(base + s.normal);
  const auto words = [&](std::size_t offset) { return std::int32_t((offset - s.info) / 4); };
  if (tree.hasColors) {
    *directory++ = {compressed ? AttachmentType::ColorUnits : AttachmentType::Color, words(s.color),
                    compressed ? shownRoot(tree).first : tree.voxels[0].color,
                    std::uint32_t(compressed ? encoded.colorCount : c.colors.size())};
    if (!c.colors.empty()) std::memcpy(colorWords + slotCount, c.colors.data(), c.colors.size() * 4);
  }
  if (tree.hasNormals) {
    *directory++ = {compressed ? AttachmentType::NormalUnits : AttachmentType::Normal, words(s.normal),
                    compressed ? shownRoot(tree).second : tree.voxels[0].normal,
                    std::uint32_t(compressed ? encoded.normalCount : c.normals.size())};
    if (!c.normals.empty()) std::memcpy(normalWords + slotCount, c.normals.data(), c.normals.size() * 4);
  }
  if (!tree.exactColors.empty()) {
    *directory++ = {AttachmentType::ExactColors, words(s.exactColors), 0,
                    std::uint32_t(tree.exactColors.size())};
    std::memcpy(base + s.exactColors, tree.exactColors.data(), tree.exactColors.size() * 4);
  }
  if (!tree.exactNormals.empty()) {
    *directory++ = {AttachmentType::ExactNormals, words(s.exactNormals), 0,
                    std::uint32_t(tree.exactNormals.size())};
    std::memcpy(base + s.exactNormals, tree.exactNormals.data(), tree.exactNormals.size() * 2);
  }

  for (std::size_t qi = 0; qi < c.queue.size(); ++qi) {
    const std::uint32_t v = c.queue[qi].voxel;
    const std::uint32_t slot = plan.slotOf[v];
    const Entry& e = c.entries[qi];
    std::uint32_t pointer = 0;
    bool far = false;
    if (plan.runOf[v] != 0) {
      if (plan.farSlotOf[v] != 0) {
        far = true;
        pointer = plan.farSlotOf[v] - slot;
        *reinterpret_cast<std::int32_t*>(&slots[plan.farSlotOf[v]]) =
            std::int32_t(plan.runOf[v] - plan.farSlotOf[v]);
      } else {
        pointer = plan.runOf[v] - slot;
      }
      assert(pointer <= options.maxNearPointer);
    }
    std::uint32_t contourPointer = 0;
    if (e.contourMask) {
      const std::size_t contourWords =
          (s.contours + std::size_t(e.contourFirst) * 4 - std::size_t(slot) * kSlotBytes) / 4;
      if (contourWords > kMaxWordPointer)
        throw BlockTooLarge(
            "octree too large for one block (a contour pointer is out of 24-bit reach): stream it through "
            "a block pool");
      contourPointer = std::uint32_t(contourWords);
    }
    slots[slot] = ChildDescriptor::make(pointer, far, e.childMask, e.leafMask, contourPointer, e.contourMask);
    if (!compressed && tree.hasColors)
      colorWords[slot] = lookupEntry(slotCount, e.colorFirst, e.colorMask, c.queue[qi].colorAt);
    if (!compressed && tree.hasNormals)
      normalWords[slot] = lookupEntry(slotCount, e.normalFirst, e.normalMask, c.queue[qi].normalAt);
    ++stats.descriptorSlots;
  }
  for (std::size_t v = 0; v < plan.linkOf.size(); ++v)
    if (plan.linkOf[v] != 0)
      slots[plan.linkOf[v]] =
          ChildDescriptor::link(std::int32_t(plan.slotOf[v]) - std::int32_t(plan.linkOf[v]));
  if (compressed) {
    if (tree.hasColors) writeUnits(encoded, encoded.colors, EncodedUnits::kColor, slotCount, colorWords);
    if (tree.hasNormals) {
      writeUnits(encoded, encoded.normals, EncodedUnits::kNormal, slotCount, normalWords);
      writeExactNormals(encoded, slotCount, normalWords);
    }
    stats.units = encoded.pairs;
    stats.unitHalvesUsed = encoded.halvesUsed;
    stats.colorUnitsKept = encoded.colorCount;
    stats.normalUnitsKept = encoded.normalCount;
    stats.exactNormalUnits = encoded.exactNormalUnits;
    stats.exactNormalValues = encoded.exactNormalValues;
  }

  stats.farSlots = farVoxels;
  stats.linkSlots = plan.linkSlots;
  stats.pageHeaderSlots = (slotCount + kSlotsPerPage - 1) / kSlotsPerPage;
  stats.paddingSlots =
      slotCount - stats.descriptorSlots - stats.farSlots - stats.pageHeaderSlots - stats.linkSlots;
  stats.contourWords = c.contours.size();
  stats.colorValues = c.colors.size();
  stats.normalValues = c.normals.size();
  // As the paper counts (sec. 5.6): a slot's first word is hierarchy, its second (contour pointer and mask)
  // belongs to the contours with the contour values.
  stats.hierarchyBytes = std::uint64_t(slotCount) * 4;
  stats.contourBytes = std::uint64_t(slotCount) * 4 + c.contours.size() * 4;
  stats.colorBytes = tree.hasColors ? s.normal - s.color : 0;
  stats.normalBytes = tree.hasNormals ? s.exactColors - s.normal : 0;
  stats.attributeBytes = stats.colorBytes + stats.normalBytes;
  stats.exactBytes = s.end - s.exactColors;
  stats.totalBytes = bytes.size();
  if (statsOut) *statsOut = stats;
  if (descriptorSlot) *descriptorSlot = std::move(plan.slotOf);
  return Block(std::move(bytes));
}

}  // namespace

Block layoutBlock(const VoxelTree& tree, const LayoutOptions& options, LayoutStats* stats,
                  std::vector<std::uint32_t>* descriptorSlot) {
  return layOutTree(tree, options, stats, descriptorSlot);
}

Block layoutBlock(const LevelOrderTree& tree, const LayoutOptions& options, LayoutStats* stats,
                  std::vector<std::uint32_t>* descriptorSlot) {
  for (std::size_t k = 0; k < tree.stubs.size(); ++k)
    if (tree.stubs[k] >= tree.voxels.size() || tree.voxels[tree.stubs[k]].childMask != 0 ||
        (k > 0 && tree.stubs[k] <= tree.stubs[k - 1]))
      throw std::invalid_argument("layoutBlock: stubs must be ascending voxels without children");
  return layOutTree(tree, options, stats, descriptorSlot);
}

}  // namespace svo
