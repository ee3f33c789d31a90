#include "svo/store/level_arrays.hpp"

#include <algorithm>
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
  std::uint32_t* contourOut = grow(children.contours, head.contourCount);
  std::uint16_t* codeOut = grow(children.normalCodes, head.normalCount);
  std::uint32_t* shownContour = grow(children.shownContours, head.voxelCount);
  std::uint16_t* shownCode = grow(children.shownNormalCodes, head.voxelCount);
  parents.childMasks.resize(parents.voxels, 0);

  const std::uint32_t* const contourNormals = contourNormalPredictionTable();
  const bool parentContourPredicts = (head.attachments & kParentContourPrediction) != 0;
  const std::uint32_t contourCount = head.contourCount, normalCount = head.normalCount;
  std::uint32_t split = 0, added = 0, contour = 0, normal = 0;
  for (std::size_t i = 0; i < slice.parentCount; ++i) {
    if (!bitAt(s.split, i)) continue;
    const std::size_t parent = firstParent + i;
    const unsigned mask = std::to_integer<unsigned>(s.masks[split++]);
    parents.childMasks[parent] = std::uint8_t(mask);
    const bool parentHasContour = parents.contourBits[parent];
    const std::uint32_t parentContour = parents.shownContours[parent];
    const ContourPositionPredictor position(parentHasContour, parentContour);
    const ParentContourNormal fromParent(parentContourPredicts && parentHasContour, parentContour);
    const std::uint16_t parentCode = parents.shownNormalCodes[parent];
    for (unsigned rest = mask; rest != 0; rest &= rest - 1, ++added) {
      std::uint16_t code = parentCode;
      if (s.normals && bitAt(s.normalBits, added)) {
        code = normalCodeOf({s.normals[normal], s.normals[normalCount + normal]}, parentCode);
        codeOut[normal++] = code;
      }
      shownCode[added] = code;
      std::uint32_t value = 0;
      if (bitAt(s.contourBits, added)) {
        ContourResidual r;
        for (std::size_t plane = 0; plane < kContourBytes; ++plane)
          r[plane] = s.contours[plane * contourCount + contour];
        value =
            contourOf(r, fromParent(s.normals ? contourNormals[code] : 0) | position(std::countr_zero(rest)));
        contourOut[contour++] = value;
      }
      shownContour[added] = value;
    }
  }
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
