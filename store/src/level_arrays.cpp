#include "svo/store/level_arrays.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cstring>

#include "codec_parts.hpp"
#include "svo/store/codec.hpp"
#include "svo/store/format.hpp"

namespace svo {

using namespace codec;

namespace {

// Bits set among the first `count` bits at `bits` (LSB first).
std::size_t countSet(const std::byte* bits, std::size_t count) {
  std::size_t set = 0;
  for (std::size_t i = 0; i < count; i += 64) set += std::size_t(std::popcount(sectionWord(bits, i, count)));
  return set;
}

// A vector grown by `count` elements, returning where they start.
template <class T>
T* grow(std::vector<T>& values, std::size_t count) {
  const std::size_t at = values.size();
  values.resize(at + count);
  return values.data() + at;
}

// A slice's sections after its head (codec.hpp), with the counts the hierarchy must agree with checked up
// front, so that the decoding loop reads in bounds without a check per voxel.
struct Sections {
  const std::byte *split, *masks, *contourBits;
  const std::uint8_t* contours;  // byte planes
  const std::byte *colorBits = nullptr, *normalBits = nullptr;
  const std::uint8_t *colors = nullptr, *normals = nullptr;  // ABGR words; byte planes
};

Sections checkedSections(std::span<const std::byte> raw, const SliceHead& head, const StoreHeader& header) {
  const SectionStarts at = sectionStarts(raw.data() + sizeof head, head, header);
  const auto values = [&](const std::byte* bits) {
    return reinterpret_cast<const std::uint8_t*>(bits + bitBytes(head.voxelCount));
  };
  Sections s{
      .split = at.split, .masks = at.masks, .contourBits = at.contours, .contours = values(at.contours)};
  if (at.colors) s.colorBits = at.colors, s.colors = values(at.colors);
  if (at.normals) s.normalBits = at.normals, s.normals = values(at.normals);
  if (countSet(s.split, head.parentCount) != head.splitCount)
    throw SliceDecodeError("split bits do not match the valid masks");
  std::size_t children = 0;
  for (std::uint32_t k = 0; k < head.splitCount; ++k) {
    const unsigned mask = std::to_integer<unsigned>(s.masks[k]);
    if (mask == 0) throw SliceDecodeError("a split voxel with no children");
    children += std::size_t(std::popcount(mask));
  }
  if (children != head.voxelCount) throw SliceDecodeError("valid masks do not match the voxel count");
  const auto present = [&](const std::byte* bits, std::uint32_t count) {
    if (bits && countSet(bits, head.voxelCount) != count)
      throw SliceDecodeError("presence bits do not match the values");
  };
  present(s.contourBits, head.contourCount), present(s.colorBits, head.colorCount);
  present(s.normalBits, head.normalCount);
  return s;
}

// The child slots of each valid mask's set bits, in slot order a byte each from the low byte on: a parent's
// children take theirs with one 8-byte store.
constexpr std::array<std::uint64_t, 256> kSlotsOfMask = [] {
  std::array<std::uint64_t, 256> slots{};
  for (unsigned mask = 0; mask < 256; ++mask)
    for (unsigned slot = 0, k = 0; slot < 8; ++slot)
      if (mask >> slot & 1) slots[mask] |= std::uint64_t(slot) << (8 * k++);
  return slots;
}();
// A contour's normal fields, [31:14] (format.hpp): ParentContourNormal's prediction from a parent's contour.
constexpr std::uint32_t kContourNormalFields = ~((std::uint32_t(1) << 14) - 1);
// ContourPositionPredictor's position field (bits [13:7]) by its numerator, from -kNumeratorBound on: a load
// in place of the rounding division and the clamp.
constexpr int kNumeratorBound = ContourPositionPredictor::kNumeratorBound;
constexpr std::array<std::uint8_t, 2 * kNumeratorBound + 1> kPositionFields = [] {
  std::array<std::uint8_t, 2 * kNumeratorBound + 1> fields{};
  for (int n = -kNumeratorBound; n <= kNumeratorBound; ++n)
    fields[std::size_t(n + kNumeratorBound)] = std::uint8_t(ContourPositionPredictor::bitsOf(n) >> 7);
  return fields;
}();
// The most children a parent has (a child mask's bits): expandHierarchy's stores write this many entries.
constexpr std::size_t kMaxChildren = 8;

// Per new voxel of a slice: its parent (as an index into the slice's parents) and its slot there. The values
// are then decoded in flat loops over the voxels that have them, without a loop per parent whose varying trip
// count mispredicts a branch per parent. Kept between slices (thread_local), so that it grows to the largest
// slice once.
struct ChildParents {
  std::vector<std::uint32_t> parent;
  std::vector<std::uint8_t> slot;
};

// What a slice's voxels are predicted from: their parents' shown contours and normal codes (the slice's first
// parent's on), and the parents' level's contour presence words with the first parent's index in it.
struct ParentsShown {
  const std::uint32_t* contours;
  const std::uint16_t* codes;
  const std::uint64_t* contourWords;
  std::size_t first;
  bool hasContour(std::size_t parent) const {
    const std::size_t i = first + parent;
    return (contourWords[i / 64] >> (i % 64)) & 1u;
  }
};

// Where a slice's voxels go: the present contours and normal codes, and every voxel's shown contour and code.
struct VoxelOutputs {
  std::uint32_t* contours;
  std::uint16_t* codes;
  std::uint32_t* shownContours;
  std::uint16_t* shownCodes;
};

// Sets the split parents' child masks (`masks`: the slice's first parent's on), fills `under`, and gives
// each new voxel its parent's shown normal code in `shownCodes` (room for kMaxChildren - 1 more). Branch free
// per parent but for the walk over the split bits: each parent stores kMaxChildren entries, and the next
// parent's overwrite those past its own children.
void expandHierarchy(const Sections& s, const SliceHead& head, const ParentsShown& parents,
                     std::uint8_t* masks, ChildParents& under, std::uint16_t* shownCodes) {
  const std::size_t room = std::size_t(head.voxelCount) + kMaxChildren;
  if (under.parent.size() < room) under.parent.resize(room), under.slot.resize(room);
  std::uint32_t* const parentOf = under.parent.data();
  std::uint8_t* const slotOf = under.slot.data();
  std::size_t split = 0, added = 0;
  for (std::uint32_t i = 0; i < head.parentCount; i += 64)
    for (std::uint64_t w = sectionWord(s.split, i, head.parentCount); w != 0; w &= w - 1) {
      const std::uint32_t parent = i + std::uint32_t(std::countr_zero(w));
      const std::uint8_t mask = std::to_integer<std::uint8_t>(s.masks[split++]);
      masks[parent] = mask;
      // Whole arrays copied at once: a vector store or two each, where stores of single entries would have to
      // keep their order with those to `masks`.
      std::uint32_t parent8[kMaxChildren];
      std::uint16_t code8[kMaxChildren];
      std::fill_n(parent8, kMaxChildren, parent), std::fill_n(code8, kMaxChildren, parents.codes[parent]);
      std::memcpy(parentOf + added, parent8, sizeof parent8),
          std::memcpy(shownCodes + added, code8, sizeof code8);
      std::memcpy(slotOf + added, &kSlotsOfMask[mask], kMaxChildren);
      added += std::size_t(std::popcount(mask));
    }
}

// The present normal codes of the slice's voxels, each against the code its voxel shows so far (its
// parent's, from expandHierarchy); the voxels found by walking the presence words' set bits, without a
// branch per voxel on its presence.
void decodeNormals(const Sections& s, const SliceHead& head, const VoxelOutputs& out) {
  const std::size_t voxels = head.voxelCount, count = head.normalCount;
  std::size_t normal = 0;
  for (std::size_t first = 0; first < voxels; first += 64)
    for (std::uint64_t w = sectionWord(s.normalBits, first, voxels); w != 0; w &= w - 1, ++normal) {
      const std::size_t i = first + std::size_t(std::countr_zero(w));
      const NormalResidual r{s.normals[normal], s.normals[count + normal]};
      out.codes[normal] = out.shownCodes[i] = normalCodeOf(r, out.shownCodes[i]);
    }
}

// What each present contour of the slice is coded against (`out.contours`, which decodeContours then turns
// into the contours): the prediction from its parent's contour and (kNormals) from its own normal code.
template <bool kNormals>
void predictContours(const Sections& s, const SliceHead& head, const ParentsShown& parents,
                     const ChildParents& under, const VoxelOutputs& out) {
  const std::uint32_t* const contourNormals = kNormals ? contourNormalPredictionTable() : nullptr;
  const bool parentContourPredicts = (head.attachments & kParentContourPrediction) != 0;
  const std::size_t voxels = head.voxelCount;
  std::size_t contour = 0;
  for (std::size_t first = 0; first < voxels; first += 64)
    for (std::uint64_t w = sectionWord(s.contourBits, first, voxels); w != 0; w &= w - 1, ++contour) {
      const std::size_t i = first + std::size_t(std::countr_zero(w));
      const std::uint32_t parent = under.parent[i];
      const std::uint32_t parentContour = parents.contours[parent];
      const ContourFields f = contourFields(parentContour);
      const std::uint32_t predictedNormal = parentContourPredicts && parents.hasContour(parent)
                                                ? parentContour & kContourNormalFields
                                            : kNormals ? contourNormals[out.shownCodes[i]]
                                                       : 0;
      const int numerator = ContourPositionPredictor::numerator(f.normal, 62 * f.position, under.slot[i]);
      out.contours[contour] =
          predictedNormal | std::uint32_t(kPositionFields[std::size_t(numerator + kNumeratorBound)]) << 7;
    }
}

// The slice's contours from their residuals' byte planes and their predictions (in `out.contours`): one pass
// over the planes in order, which the compiler vectorizes. Then each voxel with a contour shows it; those
// without keep the shown contour 0 they were grown with.
void decodeContours(const Sections& s, const SliceHead& head, const VoxelOutputs& out) {
  const std::size_t count = head.contourCount;
  const std::uint8_t* const planes = s.contours;
  std::uint32_t* const contours = out.contours;
  for (std::size_t k = 0; k < count; ++k)
    contours[k] = contourOf(
        {planes[k], planes[count + k], planes[2 * count + k], planes[3 * count + k], planes[4 * count + k]},
        contours[k]);
  const std::size_t voxels = head.voxelCount;
  std::size_t contour = 0;
  for (std::size_t first = 0; first < voxels; first += 64)
    for (std::uint64_t w = sectionWord(s.contourBits, first, voxels); w != 0; w &= w - 1)
      out.shownContours[first + std::size_t(std::countr_zero(w))] = contours[contour++];
}

}  // namespace

void PresenceBits::append(const std::byte* bits, std::size_t count) {
  const unsigned shift = unsigned(size_ % 64);
  std::size_t word = size_ / 64;
  words_.resize((size_ + count + 63) / 64, 0);
  for (std::size_t i = 0; i < count; i += 64, ++word) {
    const std::uint64_t w = sectionWord(bits, i, count);
    words_[word] |= w << shift;
    if (shift != 0 && word + 1 < words_.size()) words_[word + 1] |= w >> (64 - shift);
  }
  size_ += count;
}

void OctreeLevel::clear() {
  voxels = 0;
  childMasks.clear(), contours.clear(), colors.clear(), normalCodes.clear();
  contourBits.clear(), colorBits.clear(), normalBits.clear();
  shownContours.clear(), shownNormalCodes.clear();
}

OctreeLevel rootLevel(const StoreHeader& header) {
  OctreeLevel root;
  root.voxels = 1;
  root.childMasks.assign(1, 0);
  const std::byte none{0}, one{1};
  root.contourBits.append(&none, 1), root.shownContours.assign(1, 0);
  const std::uint16_t code = octNormalCodeOf(header.rootNormal);
  root.shownNormalCodes.assign(1, code);
  // The root's own values, which the voxels without one below it show.
  if (header.hasColors) root.colorBits.append(&one, 1), root.colors.assign(1, header.rootColor);
  if (header.hasNormals) root.normalBits.append(&one, 1), root.normalCodes.assign(1, code);
  return root;
}

void decodeSliceLevel(std::span<const std::byte> raw, const SliceInfo& slice, const StoreHeader& header,
                      OctreeLevel& parents, std::size_t firstParent, OctreeLevel& children) {
  if (firstParent + slice.parentCount > parents.voxels)
    throw SliceDecodeError("its parents run past their level");
  const SliceHead head = checkedHead(raw, slice, header, slice.parentCount);
  const Sections s = checkedSections(raw, head, header);
  children.voxels += head.voxelCount;
  children.contourBits.append(s.contourBits, head.voxelCount);
  if (s.colorBits) {
    children.colorBits.append(s.colorBits, head.voxelCount);
    std::memcpy(grow(children.colors, head.colorCount), s.colors, kColorBytes * head.colorCount);
  }
  if (s.normalBits) children.normalBits.append(s.normalBits, head.voxelCount);
  children.childMasks.resize(children.voxels, 0);
  parents.childMasks.resize(parents.voxels, 0);

  thread_local ChildParents under;
  const ParentsShown shown{.contours = parents.shownContours.data() + firstParent,
                           .codes = parents.shownNormalCodes.data() + firstParent,
                           .contourWords = parents.contourBits.words().data(),
                           .first = firstParent};
  const std::size_t codesShown = children.shownNormalCodes.size() + head.voxelCount;
  const VoxelOutputs out{.contours = grow(children.contours, head.contourCount),
                         .codes = grow(children.normalCodes, head.normalCount),
                         .shownContours = grow(children.shownContours, head.voxelCount),
                         .shownCodes = grow(children.shownNormalCodes, head.voxelCount + kMaxChildren - 1)};
  expandHierarchy(s, head, shown, parents.childMasks.data() + firstParent, under, out.shownCodes);
  children.shownNormalCodes.resize(codesShown);  // without expandHierarchy's room
  if (s.normals) {
    decodeNormals(s, head, out);
    predictContours<true>(s, head, shown, under, out);
  } else {
    predictContours<false>(s, head, shown, under, out);
  }
  decodeContours(s, head, out);
}

LevelArrayBytes bytesOf(std::span<const OctreeLevel> levels, const StoreHeader& header) {
  LevelArrayBytes b;
  const auto presence = [](std::size_t voxels) {
    return bitBytes(voxels) + 4 * ((voxels + kPresenceCountGroup - 1) / kPresenceCountGroup);
  };
  for (std::size_t l = 0; l < levels.size(); ++l) {
    const OctreeLevel& level = levels[l];
    if (l + 1 < levels.size())
      b.hierarchy += level.voxels + 4 * ((level.voxels + kChildCountGroup - 1) / kChildCountGroup);
    b.contours += presence(level.voxels) + 4 * level.contours.size();
    if (header.hasColors) b.colors += presence(level.voxels) + 4 * level.colors.size();
    if (header.hasNormals) b.normals += presence(level.voxels) + 2 * level.normalCodes.size();
  }
  return b;
}

}  // namespace svo
