#include "svo/store/codec.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstring>
#include <optional>
#include <string>
#include <tuple>
#include <type_traits>

#include "codec_parts.hpp"
#include "svo/store/format.hpp"

namespace svo {

using namespace codec;

namespace {

// Bits an order-0 entropy coder needs for the values the histograms count, each field apart.
template <class Histograms>
double entropyBits(const Histograms& histograms) {
  double bits = 0.0;
  for (const auto& h : histograms) {
    std::uint64_t n = 0;
    for (const std::uint32_t c : h) n += c;
    for (const std::uint32_t c : h)
      if (c) bits += double(c) * std::log2(double(n) / double(c));
  }
  return bits;
}

}  // namespace

std::size_t sliceRawBytes(const SliceHead& h) {
  std::size_t bytes = sizeof(SliceHead) + bitBytes(h.parentCount) + h.splitCount + bitBytes(h.voxelCount) +
                      kContourBytes * std::size_t(h.contourCount);
  if (h.attachments & 1u) bytes += bitBytes(h.voxelCount) + kColorBytes * std::size_t(h.colorCount);
  if (h.attachments & 2u) bytes += bitBytes(h.voxelCount) + kNormalBytes * std::size_t(h.normalCount);
  return bytes;
}

SliceParts slicePartsOf(const SliceInfo& s, bool hasColors, bool hasNormals) {
  SliceParts p;
  p.contours = bitBytes(s.voxelCount) + kContourBytes * s.contourCount;
  p.colors = hasColors ? bitBytes(s.voxelCount) + kColorBytes * s.colorCount : 0;
  p.normals = hasNormals ? bitBytes(s.voxelCount) + kNormalBytes * s.normalCount : 0;
  p.hierarchy = s.rawBytes - p.contours - p.colors - p.normals;
  return p;
}

// ---------------------------------------------------------------------------------------------------------
// Encoding.

void SliceSections::Bits::push(bool bit) {
  if (count_ % 64 == 0) words_.push_back(0);
  if (bit) words_.back() |= std::uint64_t(1) << (count_ % 64);
  ++count_;
}

void SliceSections::Bits::append(const Bits& other) {
  const unsigned shift = unsigned(count_ % 64);
  if (shift == 0) {
    words_.insert(words_.end(), other.words_.begin(), other.words_.end());
  } else {
    for (const std::uint64_t w : other.words_) {
      words_.back() |= w << shift;
      words_.push_back(w >> (64 - shift));
    }
  }
  count_ += other.count_;
  words_.resize((count_ + 63) / 64);  // bits past count_ are zero, so the dropped word is empty
}

void SliceSections::Bits::writeTo(std::vector<std::byte>& out) const {
  const std::size_t at = out.size();
  out.resize(at + bitBytes(count_));
  std::memcpy(out.data() + at, words_.data(), bitBytes(count_));
}

void SliceSections::addParent(const SliceParent& parent, std::span<const SliceChild> children) {
  assert(children.size() == std::size_t(std::popcount(unsigned(parent.childMask))));
  split_.push(parent.childMask != 0);
  if (parent.childMask == 0) return;
  masks_.push_back(parent.childMask);
  const ContourPositionPredictor position(parent.hasContour, parent.contour);
  const ParentContourNormal fromParent(parent.hasContour, parent.contour);
  const std::uint16_t parentCode = hasNormals_ ? octNormalCodeOf(parent.normal) : 0;
  const SliceChild* child = children.data();
  for (int slot = 0; slot < 8; ++slot) {
    if (!(parent.childMask >> slot & 1u)) continue;
    const SliceChild& c = *child++;
    const std::uint16_t code = hasNormals_ ? octNormalCodeOf(c.normal) : 0;
    contourBits_.push(c.hasContour);
    if (c.hasContour) {
      const std::uint32_t fromNormal = hasNormals_ ? predictedContourNormalBits(code) : 0;
      const ContourResidual a = contourResidual(c.contour, fromNormal | position(slot));
      const ContourResidual b = contourResidual(c.contour, fromParent(fromNormal));
      contours_.push_back(a);
      parentPredicted_.push_back({b[0], b[1], b[2]});
      for (int k = 0; k < 3; ++k) ++voxelNormalCounts_[k][a[k]], ++parentContourCounts_[k][b[k]];
    }
    if (hasColors_) {
      colorBits_.push(c.storesColor);
      if (c.storesColor) colors_.push_back(c.color);
    }
    if (hasNormals_) {
      normalBits_.push(c.storesNormal);
      if (c.storesNormal) normals_.push_back(normalResidual(code, parentCode));
    }
  }
}

void SliceSections::append(const SliceSections& o) {
  assert(hasColors_ == o.hasColors_ && hasNormals_ == o.hasNormals_);
  split_.append(o.split_), contourBits_.append(o.contourBits_);
  colorBits_.append(o.colorBits_), normalBits_.append(o.normalBits_);
  masks_.insert(masks_.end(), o.masks_.begin(), o.masks_.end());
  contours_.insert(contours_.end(), o.contours_.begin(), o.contours_.end());
  parentPredicted_.insert(parentPredicted_.end(), o.parentPredicted_.begin(), o.parentPredicted_.end());
  for (int k = 0; k < 3; ++k)
    for (int v = 0; v < 64; ++v) {
      voxelNormalCounts_[k][v] += o.voxelNormalCounts_[k][v];
      parentContourCounts_[k][v] += o.parentContourCounts_[k][v];
    }
  colors_.insert(colors_.end(), o.colors_.begin(), o.colors_.end());
  normals_.insert(normals_.end(), o.normals_.begin(), o.normals_.end());
}

std::vector<std::byte> encodeSlice(const SliceHead& plannedHead, const SliceSections& s) {
  SliceHead head = plannedHead;
  const bool fromParents = entropyBits(s.parentContourCounts_) < entropyBits(s.voxelNormalCounts_);
  if (fromParents) head.attachments |= kParentContourPrediction;
  std::vector<std::byte> out(sizeof head);
  std::memcpy(out.data(), &head, sizeof head);
  out.reserve(sliceRawBytes(head));
  const auto words = [&](const std::vector<std::uint32_t>& values) {
    const std::size_t at = out.size();
    out.resize(at + 4 * values.size());
    std::memcpy(out.data() + at, values.data(), 4 * values.size());
  };
  const auto planes = [&](const auto& values) {  // byte k of every value, then byte k + 1, ...
    for (std::size_t k = 0; k < std::tuple_size_v<typename std::decay_t<decltype(values)>::value_type>; ++k)
      for (const auto& v : values) out.push_back(std::byte(v[k]));
  };
  s.split_.writeTo(out);
  for (const std::uint8_t mask : s.masks_) out.push_back(std::byte(mask));
  s.contourBits_.writeTo(out);
  for (std::size_t k = 0; k < kContourBytes; ++k)  // the normal fields as the head says, then the rest
    for (std::size_t i = 0; i < s.contours_.size(); ++i)
      out.push_back(std::byte(fromParents && k < 3 ? s.parentPredicted_[i][k] : s.contours_[i][k]));
  if (head.attachments & 1u) s.colorBits_.writeTo(out), words(s.colors_);
  if (head.attachments & 2u) s.normalBits_.writeTo(out), planes(s.normals_);
  if (out.size() != sliceRawBytes(head))
    throw std::logic_error("writeStore: a slice's sections and head disagree");
  return out;
}

// ---------------------------------------------------------------------------------------------------------
// Decoding.

namespace {

// The lattice code of a parent's normal, as the encoder finds it (octNormalCodeOf): from the voxel's hint
// where that names its normal (a voxel decoded before), else found and remembered (siblings share their
// parent's normal and often their own).
class NormalCodes {
 public:
  std::uint16_t operator()(const SliceVoxel& v) {
    if (lattice_[v.normalCode] == v.normal) return std::uint16_t(canonical_[v.normalCode]);
    if (v.normal != normal_) normal_ = v.normal, code_ = octNormalCodeOf(v.normal);
    return code_;
  }

 private:
  const std::uint32_t* lattice_ = latticeNormalTable();
  const std::uint32_t* canonical_ = canonicalNormalCodeTable();
  std::uint32_t normal_ = 0;
  std::uint16_t code_ = octNormalCodeOf(0);
};

// A per-voxel section read alongside the hierarchy: a presence bit per new voxel, then `count` values.
class PresentValues {
 public:
  PresentValues(const std::byte* section, std::uint32_t voxelCount, std::uint32_t count)
      : bits_(section), values_(section + bitBytes(voxelCount)), count_(count) {}
  // Whether voxel i has a value, and then its index.
  bool take(std::size_t i, std::uint32_t& index) {
    if (!bitAt(bits_, i)) return false;
    if (taken_ == count_) throw SliceDecodeError("more presence bits than values");
    index = taken_++;
    return true;
  }
  void checkAllTaken() const {
    if (taken_ != count_) throw SliceDecodeError("fewer presence bits than values");
  }
  std::uint8_t planeByte(std::size_t plane, std::uint32_t k) const {
    return std::to_integer<std::uint8_t>(values_[plane * count_ + k]);
  }
  std::uint32_t word(std::uint32_t k) const { return wordAt(values_, k); }

 private:
  const std::byte* bits_;
  const std::byte* values_;
  std::uint32_t count_, taken_ = 0;
};

// The sections after the head at `cursor`, in one pass over the new voxels: the hierarchy sets the parents'
// child masks and appends their children (coordinates, inherited attributes), and each child takes its own
// values as it is appended. Normals before contours: a contour is coded against its voxel's normal.
void decodeSections(const SliceHead& head, const std::byte* cursor, const StoreHeader& header,
                    std::span<SliceVoxel> parents, std::vector<SliceVoxel>& children,
                    const std::function<void()>& pause) {
  const SectionStarts at = sectionStarts(cursor, head, header);
  const std::byte* const splitBits = at.split;
  const std::byte* const masks = at.masks;
  PresentValues contours(at.contours, head.voxelCount, head.contourCount);
  std::optional<PresentValues> colors, normals;
  if (at.colors) colors.emplace(at.colors, head.voxelCount, head.colorCount);
  if (at.normals) normals.emplace(at.normals, head.voxelCount, head.normalCount);
  const std::uint32_t* const lattice = latticeNormalTable();
  const std::uint32_t* const contourNormals = contourNormalPredictionTable();
  const bool parentContourPredicts = (head.attachments & kParentContourPrediction) != 0;

  const std::size_t firstAdded = children.size();
  // At most 8 children per split voxel, whose masks are bytes of this slice: a hostile count reserves no
  // more. Geometric growth: callers append a level's slices one after another to one vector (loadTree),
  // and an exact reserve per slice would copy the whole level every time.
  const std::size_t bound = std::min<std::size_t>(head.voxelCount, 8 * std::size_t(head.splitCount));
  if (firstAdded + bound > children.capacity())
    children.reserve(std::max(firstAdded + bound, 2 * children.capacity()));
  std::uint32_t split = 0;
  std::size_t added = 0;  // new voxels so far: the index into every per-voxel section
  NormalCodes codes;
  for (std::size_t i = 0; i < parents.size(); ++i) {
    if (pause && i % kParentsBetweenPauses == kParentsBetweenPauses - 1) pause();
    SliceVoxel& p = parents[i];
    if (!bitAt(splitBits, i)) continue;
    if (split == head.splitCount) throw SliceDecodeError("more split bits than valid masks");
    const std::uint8_t mask = std::to_integer<std::uint8_t>(masks[split++]);
    if (mask == 0) throw SliceDecodeError("a split voxel with no children");
    if (added + std::size_t(std::popcount(unsigned(mask))) > head.voxelCount)
      throw SliceDecodeError("valid masks do not match the voxel count");
    p.childMask = mask;
    const ContourPositionPredictor position(p.hasContour, p.contour);
    const ParentContourNormal fromParent(parentContourPredicts && p.hasContour, p.contour);
    const std::uint16_t parentCode = normals ? codes(p) : 0;
    for (unsigned rest = mask; rest != 0; rest &= rest - 1, ++added) {
      const int slot = std::countr_zero(rest);
      SliceVoxel& child = children.emplace_back();  // in place: no temporary to copy (store forwarding)
      child.coord = childCoord(p.coord, slot);
      child.color = p.color, child.normal = p.normal, child.normalCode = p.normalCode;
      std::uint16_t code = parentCode;
      std::uint32_t k;
      if (normals && normals->take(added, k)) {
        code = normalCodeOf({normals->planeByte(0, k), normals->planeByte(1, k)}, code);
        child.normal = lattice[code], child.normalCode = code;
      }
      if (colors && colors->take(added, k)) child.color = colors->word(k);
      if (contours.take(added, k)) {
        ContourResidual r;
        for (std::size_t plane = 0; plane < kContourBytes; ++plane) r[plane] = contours.planeByte(plane, k);
        child.hasContour = true;
        child.contour = contourOf(r, fromParent(normals ? contourNormals[code] : 0) | position(slot));
      }
    }
  }
  if (split != head.splitCount || added != head.voxelCount)
    throw SliceDecodeError("valid masks do not match the voxel count");
  if (normals) normals->checkAllTaken();
  if (colors) colors->checkAllTaken();
  contours.checkAllTaken();
}

}  // namespace

void decodeSlice(std::span<const std::byte> raw, const SliceInfo& slice, const StoreHeader& header,
                 std::span<SliceVoxel> parents, std::vector<SliceVoxel>& children,
                 const std::function<void()>& pause) {
  const SliceHead head = checkedHead(raw, slice, header, parents.size());
  decodeSections(head, raw.data() + sizeof head, header, parents, children, pause);
}

}  // namespace svo
