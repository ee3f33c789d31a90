// The slice codec (format v5, and v4 read): one slice's decoded bytes from the voxels it adds, and back. The
// writer encodes (slice_plan.hpp); every reader, local or remote, decodes (store_reader.hpp). Compression and
// checksums are the reader's and writer's: the codec sees decoded bytes only.
//
// A slice adds one level below its *parents*: the voxels of the level above in its cube or run of
// sub-cubes, in Morton order. Its decoded bytes, little-endian:
//   head       SliceHead: magic and counts;
//   hierarchy  a split bit per parent (bit i in byte i / 8, LSB first), then a valid mask byte per split
//              parent: the new voxels, each parent's in slot order;
//   contours   a presence bit per new voxel, then 5 byte planes of the present ones (byte 0 of every value,
//              then byte 1, ...): the normal's three 6-bit fields minus those its voxel's normal predicts
//              (mod 64), or in a slice whose head has kParentContourPrediction (format v5) minus its parent
//              contour's where the parent has one; the position field minus the one its parent's contour
//              predicts (mod 128); the thickness;
//   colors     (stores with colors) a presence bit per new voxel, then the present ABGR words;
//   normals    (stores with normals) a presence bit per new voxel, then 2 byte planes of the present ones:
//              the octahedral code (format.hpp) minus its parent's effective normal's, per byte (mod 256).
// A voxel whose presence bit is clear has no contour, or inherits its parent's color or normal. Byte planes
// of prediction residuals are what zstd packs well: 2M-triangle terrain at 13 levels, on disk, 5.13 -> 2.60
// B per leaf voxel against plain values.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <stdexcept>
#include <vector>

#include "svo/store/store_types.hpp"

namespace svo {

inline constexpr std::uint32_t kSliceMagic = 0x45434c53;  // "SLCE"

// The head of a decoded slice; the counts must agree with the directory's and with the sections' sizes.
struct SliceHead {
  std::uint32_t magic;
  std::uint32_t parentCount, splitCount, voxelCount, contourCount, colorCount, normalCount;
  std::uint32_t attachments;  // sliceAttachments
};
static_assert(sizeof(SliceHead) == 32);

// A head's attachment bits: bit 0 colors, bit 1 normals.
constexpr std::uint32_t sliceAttachments(bool hasColors, bool hasNormals) {
  return (hasColors ? 1u : 0u) | (hasNormals ? 2u : 0u);
}
// Format v5, a head's bit 2: the slice's contour normals are coded against their parents' contours where
// those have one. The writer sets it where that costs less than the prediction from the voxels' normals:
// shading normals (meshes) stray from the geometry the contours follow, while a scan's or a volume's voxel
// normals give the contour's exactly.
inline constexpr std::uint32_t kParentContourPrediction = 4u;
inline constexpr std::uint32_t kParentContourPredictionSince = 5;  // the first format version with the bit

// Bytes per stored value: a contour residual, a color, a normal residual.
inline constexpr std::size_t kContourBytes = 5;
inline constexpr std::size_t kColorBytes = 4;
inline constexpr std::size_t kNormalBytes = 2;

// The decoded size of a slice with this head: the head and its sections.
std::size_t sliceRawBytes(const SliceHead& head);

// A slice's decoded bytes by part: presence bits go with their part; the head, split bits and valid masks
// are hierarchy.
struct SliceParts {
  std::uint64_t hierarchy = 0, contours = 0, colors = 0, normals = 0;
};
SliceParts slicePartsOf(const SliceInfo& slice, bool hasColors, bool hasNormals);

// ---------------------------------------------------------------------------------------------------------
// Encoding.

// A parent as its children's codes are predicted from it.
struct SliceParent {
  std::uint8_t childMask = 0;
  bool hasContour = false;  // false for the scene's root: the store keeps its attributes only
  std::uint32_t contour = 0;
  std::uint32_t normal = 0;  // effective (its own or inherited)
};
// A new voxel as a slice stores it.
struct SliceChild {
  bool hasContour = false;
  std::uint32_t contour = 0;
  bool storesColor = false;  // false: it inherits its parent's
  std::uint32_t color = 0;
  bool storesNormal = false;  // false: it inherits its parent's
  std::uint32_t normal = 0;   // effective: it predicts the contour's normal either way
};

// A slice's sections before they are laid out. Parts can be appended at any bit offset: a slice spanning
// several cells of an out-of-core build is assembled from each cell's part.
class SliceSections {
 public:
  SliceSections(bool hasColors, bool hasNormals) : hasColors_(hasColors), hasNormals_(hasNormals) {}
  // The next parent (Morton order) and its children in slot order, one per bit of its child mask.
  void addParent(const SliceParent& parent, std::span<const SliceChild> children);
  void append(const SliceSections& other);

 private:
  // Bits LSB-first, as slices store them, appendable at any bit offset.
  class Bits {
   public:
    void push(bool bit);
    void append(const Bits& other);
    void writeTo(std::vector<std::byte>& out) const;

   private:
    std::vector<std::uint64_t> words_;
    std::size_t count_ = 0;
  };
  using ContourResidual = std::array<std::uint8_t, kContourBytes>;
  using NormalResidual = std::array<std::uint8_t, kNormalBytes>;
  using ContourNormalResidual = std::array<std::uint8_t, 3>;

  bool hasColors_, hasNormals_;
  Bits split_, contourBits_, colorBits_, normalBits_;
  std::vector<std::uint8_t> masks_;
  std::vector<ContourResidual> contours_;               // normal fields against the voxels' normals
  std::vector<ContourNormalResidual> parentPredicted_;  // against the parents' contours where they have one
  // How often each value of each normal field's residual occurs under either prediction: the slice uses the
  // one of lower entropy (what zstd's Huffman coding of the planes comes near).
  using FieldHistograms = std::array<std::array<std::uint32_t, 64>, 3>;
  FieldHistograms voxelNormalCounts_{}, parentContourCounts_{};
  std::vector<std::uint32_t> colors_;
  std::vector<NormalResidual> normals_;

  friend std::vector<std::byte> encodeSlice(const SliceHead& head, const SliceSections& sections);
};

// The slice's decoded bytes: the head, then the sections. Throws std::logic_error when the sections do not
// add up to the head's counts (they come from different places for a slice spanning cells).
std::vector<std::byte> encodeSlice(const SliceHead& head, const SliceSections& sections);

// ---------------------------------------------------------------------------------------------------------
// Decoding.

// What is wrong with a slice's bytes; the reader adds the store and slice they came from
// (store_reader.hpp).
struct SliceDecodeError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Decodes a slice's bytes onto its parents (Morton order, with their contours and effective attributes, which
// predict their children's): sets their child masks and appends the new voxels to `children` in Morton
// order. `slice` is its directory entry, whose counts the head must repeat; `header` gives the store's
// attachment types. Throws SliceDecodeError when the bytes disagree with either or with the parents.
// `children` grows only where its capacity is short of the directory's voxel count, so it may hold the
// parents when it has room for that many more. `pause`, when set, is called after every kParentsBetweenPauses
// parents: a caller that must leave the cores to another thread for a while (a pager worker while a frame
// renders) waits there.
inline constexpr std::size_t kParentsBetweenPauses = 4096;  // about 0.3 ms of decoding (svo bench stream p99)
void decodeSlice(std::span<const std::byte> raw, const SliceInfo& slice, const StoreHeader& header,
                 std::span<SliceVoxel> parents, std::vector<SliceVoxel>& children,
                 const std::function<void()>& pause = {});

}  // namespace svo
