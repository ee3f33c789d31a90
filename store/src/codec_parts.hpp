// Internal to the slice decoders (codec.cpp's into voxel records, level_arrays.cpp's into level arrays) and
// the encoder: the predictions a slice's values are coded against, and the checks of a slice's head.
#pragma once

#include <algorithm>
#include <array>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <span>
#include <string>

#include "svo/store/codec.hpp"
#include "svo/store/format.hpp"

namespace svo::codec {

static_assert(std::endian::native == std::endian::little, "slices are little-endian, as written in memory");

inline std::size_t bitBytes(std::size_t bits) {
  return (bits + 7) / 8;
}

// The position field (bits [13:7]) a contour of the child in `slot` is predicted to have: its parent's slab
// centre plane in the child's frame. Child units are half the parent's and its centre is a quarter of the
// parent off per axis, so with the parent's fields n (/31) and p (x 1.5/63, format.hpp) the plane
// n.u = p (1.5/63) becomes n.u' = 2 p - (21/31) sum(+-n_i) in child position steps. Integers only: the
// prediction is part of the format, so no compiler's floating point may round it differently. 0 when the
// parent has no contour. (Measured on the 20M terrain's v3 slices: the position plane 0.73 -> 0.55 B per
// leaf voxel.) Set up once per parent, asked once per child.
class ContourPositionPredictor {
 public:
  ContourPositionPredictor(bool parentHasContour, std::uint32_t parentContour) : has_(parentHasContour) {
    const ContourFields f = contourFields(parentContour);
    for (int k = 0; k < 3; ++k) normal_[k] = f.normal[k];
    twicePosition_ = 62 * f.position;
  }
  std::uint32_t operator()(int slot) const {
    return has_ ? bitsOf(numerator(normal_, twicePosition_, slot)) : 0;
  }
  // 31 x the prediction from the parent's fields, normal n and 62 p. A parent contour of 0 gives 0, as does
  // a parent without one.
  static constexpr int numerator(const int (&normal)[3], int twicePosition, int slot) {
    int reach = 0;  // sum of +-n_i, the sign from which half of the parent the child is in
    for (int k = 0; k < 3; ++k) reach += (slot >> k & 1) ? normal[k] : -normal[k];
    return twicePosition - 21 * reach;
  }
  static constexpr std::uint32_t bitsOf(int numerator) {
    const int rounded = (numerator >= 0 ? numerator + 15 : numerator - 15) / 31;  // half away from zero
    return std::uint32_t(std::clamp(rounded, -64, 63) & 127) << 7;
  }
  // The largest |numerator|: |p| <= 64, |reach| <= 3 x 32.
  static constexpr int kNumeratorBound = 62 * 64 + 21 * 96;

 private:
  bool has_;
  int normal_[3];
  int twicePosition_;  // 62 p: 31 x twice the parent's position field
};

// The normal fields a parent's contour predicts for its children's contours (kParentContourPrediction): its
// own, where it has one; else the prediction from each child's normal. A contour follows the geometry, which
// the parent's contour describes one scale up.
class ParentContourNormal {
 public:
  ParentContourNormal(bool parentHasContour, std::uint32_t parentContour) : has_(parentHasContour) {
    const ContourFields f = contourFields(parentContour);
    bits_ = packContourBits(f.normal[0], f.normal[1], f.normal[2], 0, 0);
  }
  // `fromChildNormal`: predictedContourNormalBits of the child's normal (0 in a store without normals).
  std::uint32_t operator()(std::uint32_t fromChildNormal) const { return has_ ? bits_ : fromChildNormal; }

 private:
  bool has_;
  std::uint32_t bits_;
};

using ContourResidual = std::array<std::uint8_t, kContourBytes>;
using NormalResidual = std::array<std::uint8_t, kNormalBytes>;

// `predicted`: the normal fields predicted (from the voxel's normal, or its parent's contour) and the
// position field ContourPositionPredictor gives.
// Fields are differences modulo their widths (packContourBits masks them).
inline ContourResidual contourResidual(std::uint32_t contour, std::uint32_t predicted) {
  const ContourFields c = contourFields(contour), p = contourFields(predicted);
  ContourResidual r;
  for (int k = 0; k < 3; ++k) r[k] = std::uint8_t((c.normal[k] - p.normal[k]) & 63);
  r[3] = std::uint8_t((c.position - p.position) & 127), r[4] = std::uint8_t(c.thickness);
  return r;
}
// Adds every field at once: the sums of the fields without their top bits carry at most into those top bits,
// which the exclusive or then sets, so that no field carries into the next.
inline std::uint32_t contourOf(const ContourResidual& r, std::uint32_t predicted) {
  constexpr std::uint32_t kTopBits = packContourBits(32, 32, 32, 64, 64);  // each field's top bit
  const std::uint32_t residual = packContourBits(r[0], r[1], r[2], r[3], r[4]);
  const std::uint32_t p = predicted & ~std::uint32_t(127);  // the thickness is the residual's alone
  return ((residual & ~kTopBits) + (p & ~kTopBits)) ^ ((residual ^ p) & kTopBits);
}
inline NormalResidual normalResidual(std::uint16_t code, std::uint16_t parentCode) {
  return {std::uint8_t((code >> 8) - (parentCode >> 8)), std::uint8_t(code - parentCode)};
}
inline std::uint16_t normalCodeOf(const NormalResidual& r, std::uint16_t parentCode) {
  return std::uint16_t(std::uint8_t(r[0] + (parentCode >> 8)) << 8 | std::uint8_t(r[1] + parentCode));
}

inline bool bitAt(const std::byte* bits, std::size_t i) {
  return (std::to_integer<unsigned>(bits[i / 8]) >> (i % 8)) & 1u;
}

inline std::uint32_t wordAt(const std::byte* words, std::size_t i) {
  std::uint32_t w;
  std::memcpy(&w, words + 4 * i, 4);
  return w;
}

// Bits [i, i + 64) of a bit section of `count` bits (LSB first), those from `count` on cleared; i a multiple
// of 64. Reads no byte past the section.
inline std::uint64_t sectionWord(const std::byte* bits, std::size_t i, std::size_t count) {
  std::uint64_t word = 0;
  std::memcpy(&word, bits + i / 8, std::min<std::size_t>(8, bitBytes(count - i)));
  return count - i < 64 ? word & ((std::uint64_t(1) << (count - i)) - 1) : word;
}

// Where a slice's sections start behind its head (codec.hpp): the split bits, the valid masks, and each
// part's presence bits (its values follow them); null for a part the store does not have.
struct SectionStarts {
  const std::byte *split, *masks, *contours, *colors = nullptr, *normals = nullptr;
};
inline SectionStarts sectionStarts(const std::byte* cursor, const SliceHead& head,
                                   const StoreHeader& header) {
  SectionStarts at;
  at.split = cursor;
  at.masks = at.split + bitBytes(head.parentCount);
  at.contours = at.masks + head.splitCount;
  const std::byte* next = at.contours + bitBytes(head.voxelCount) + kContourBytes * head.contourCount;
  if (header.hasColors) {
    at.colors = next;
    next += bitBytes(head.voxelCount) + kColorBytes * head.colorCount;
  }
  if (header.hasNormals) at.normals = next;
  return at;
}

// The slice's head, checked against its directory entry, the store's attachments and its size.
inline SliceHead checkedHead(std::span<const std::byte> raw, const SliceInfo& s, const StoreHeader& header,
                             std::size_t parents) {
  if (parents != s.parentCount)
    throw SliceDecodeError("expects " + std::to_string(s.parentCount) + " parent voxels, its cube has " +
                           std::to_string(parents));
  SliceHead head;
  if (raw.size() < sizeof head) throw SliceDecodeError("shorter than its head");
  std::memcpy(&head, raw.data(), sizeof head);
  if (head.magic != kSliceMagic || head.parentCount != s.parentCount || head.voxelCount != s.voxelCount ||
      head.contourCount != s.contourCount || head.colorCount != s.colorCount ||
      head.normalCount != s.normalCount ||
      (head.attachments & ~kParentContourPrediction) !=
          sliceAttachments(header.hasColors, header.hasNormals) ||
      ((head.attachments & kParentContourPrediction) && header.version < kParentContourPredictionSince) ||
      head.splitCount > head.parentCount)
    throw SliceDecodeError("its head does not match the directory");
  if (sliceRawBytes(head) != raw.size()) throw SliceDecodeError("section sizes do not add up to its size");
  return head;
}

}  // namespace svo::codec
