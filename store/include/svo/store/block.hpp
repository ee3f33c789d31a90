// An ESVO block (paper sec. 5): a relocatable byte region holding the child-descriptor array (with far
// pointers and a page header at every 8 KB boundary), the info section, contour data and attachments.
// Every reference inside is relative, so a block stays valid when copied to any other 8 KB-aligned address.
//
// Layout, in order:
//   slots      64-bit slots. Slot 0 of every 8 KB page is the page header (int32: words from the page to the
//              info section). The root's descriptor is slot 1. A non-leaf voxel's non-leaf children occupy
//              consecutive slots; a far slot holds an int32 slot offset from itself to a child run.
//   info       BlockInfo followed by attachmentCount AttachmentEntry records.
//   contours   uint32 contour values; a descriptor's contour pointer counts words from the descriptor.
//   attachment per type, uncompressed: one AttributeLookup per slot (parallel to the slot array, gaps
//              included), then the uint32 values; value pointers count words from the attachment start
//              (an entry whose children all inherit points at the value they show: AttributeLookup).
//              Compressed: a unit per pair of slots (slot s in pair s / 2, half s % 2) where some child
//              is off the value its parent shows, no lookups: first a directory of two words per
//              kUnitGroup pairs (which pairs hold a unit; how many units the groups before hold), then the
//              units of the pairs that hold one, in slot order. A pair without a unit shows its children
//              with their parent's value (sec. 5.4's inheritance, for a whole unit at once).
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <vector>

#include "svo/store/attribute_units.hpp"
#include "svo/store/format.hpp"

namespace svo {

struct BlockInfo {
  std::uint32_t magic;            // kBlockInfoMagic
  std::int32_t slotsPointer;      // words from the info section to slot 0 (negative)
  std::uint32_t slotCount;        // slots including page headers and far pointers
  std::uint32_t rootSlot;         // slot of the root voxel's descriptor
  std::uint32_t contourCount;     // words of contour data
  std::uint32_t attachmentCount;  // entries that follow
};
struct AttachmentEntry {
  AttachmentType type;
  std::int32_t pointer;      // words from the info section to the attachment start (lookup array)
  std::uint32_t rootValue;   // the root voxel's own value: what a chain of inheriting voxels ends at
  std::uint32_t valueCount;  // values after the lookup array; units; exact values
};
inline constexpr std::uint32_t kBlockInfoMagic = 0x4f464e49;  // "INFO"

// Owned, 8 KB-aligned bytes; from 2 MB on, aligned to and backed by huge pages where the OS grants them.
class AlignedBytes {
 public:
  AlignedBytes() = default;
  // Zero-filled unless `zeroed` is false: a block pool's arena is only ever read where a block was copied in,
  // and leaving it untouched lets the OS map its pages on first use instead of at open.
  explicit AlignedBytes(std::size_t size, bool zeroed = true);
  std::byte* data() { return data_.get(); }
  const std::byte* data() const { return data_.get(); }
  std::size_t size() const { return size_; }

 private:
  struct Free {
    void operator()(std::byte* p) const;
  };
  std::unique_ptr<std::byte[], Free> data_;
  std::size_t size_ = 0;
};

// The compressed layout's unit directory: pairs of slots per directory entry, and its words for a block of
// `slotCount` slots. An entry is the group's presence mask (bit p: pair p holds a unit) and the index of its
// first unit among the attachment's units.
inline constexpr std::uint32_t kUnitGroup = 32;
inline constexpr std::uint32_t unitDirectoryWords(std::uint32_t slotCount) {
  return 2 * (((slotCount + 1) / 2 + kUnitGroup - 1) / kUnitGroup);
}

// How a block lays out colors and normals: uncompressed behind lookup entries, children inheriting their
// parent's value where it is left out (sec. 5.4), or compressed units of two sibling descriptors' children
// (sec. 5.5).
enum class AttributeLayout : std::uint8_t { Raw, Compressed };
const char* nameOf(AttributeLayout layout);  // "raw", "compressed"

// Read-only view of a block at an 8 KB-aligned address. All lookups go through relative pointers only.
class BlockView {
 public:
  BlockView() = default;
  // Validates the structure (magic, bounds of every section); throws std::runtime_error with what is wrong.
  BlockView(const std::byte* data, std::size_t size);
  // A view without the checks, for a block that was checked when it was made and has since been linked into
  // a block pool (its links lead outside it, which the checks would reject).
  static BlockView unchecked(const std::byte* data, std::size_t size);

  const std::byte* base() const { return base_; }
  std::size_t size() const { return size_; }
  const BlockInfo& info() const { return *info_; }
  const ChildDescriptor* slots() const { return reinterpret_cast<const ChildDescriptor*>(base_); }
  const ChildDescriptor* root() const { return slots() + info_->rootSlot; }
  const AttachmentEntry* attachment(AttachmentType type) const;
  // An attachment's first word (its lookup array, units or exact values).
  const std::uint32_t* words(const AttachmentEntry& entry) const { return startOf(*info_, entry); }

  // Descriptor of the non-leaf child `slot` of `parent` (follows the near or far pointer, and a link).
  static const ChildDescriptor* child(const ChildDescriptor* parent, int slot);
  // The contour of child `slot` of `parent`, if its contour-mask bit is set.
  static std::optional<std::uint32_t> contour(const ChildDescriptor* parent, int slot);
  // Paper Fig. 8: page header -> info section -> attachment -> lookup entry -> value. nullopt when the
  // child's bit is clear (it inherits its parent's value).
  static std::optional<std::uint32_t> attribute(const ChildDescriptor* parent, int slot, AttachmentType type);
  // The same lookup done once for all of `parent`'s children: for walks that read every child (each lookup
  // is a chain of dependent loads).
  struct Attributes {
    std::uint8_t mask = 0;                      // children with a value of their own
    const std::uint32_t* values = nullptr;      // their values, in slot order
    const std::uint32_t* shownByAll = nullptr;  // mask 0: the value every child shows, where the entry says
    std::optional<std::uint32_t> at(int slot) const {
      if (!(mask >> slot & 1u)) return std::nullopt;
      return values[childRank(mask, slot)];
    }
    // The child's own value, or the one it inherits where the entry says which.
    std::optional<std::uint32_t> shown(int slot) const {
      if (shownByAll) return *shownByAll;
      return at(slot);
    }
  };
  static Attributes attributes(const ChildDescriptor* parent, AttachmentType type);
  // The same from a lookup entry already read: `lookupWord` of the raw attachment `entry` of a block whose
  // words start at `attachment`.
  static Attributes attributesOf(const AttachmentEntry& entry, const std::uint32_t* attachment,
                                 std::uint32_t lookupWord);
  static const BlockInfo& infoOf(const ChildDescriptor* descriptor);
  // The descriptor's slot index in the block holding it, given that block's info section.
  static std::ptrdiff_t slotIndexOf(const ChildDescriptor* descriptor, const BlockInfo& info);

  // Compressed layout: the unit holding `parent`'s children (ColorUnits or NormalUnits) and the half its
  // slots take in it, through page header and info section as Fig. 8 and the unit directory; nullopt
  // without that attachment, or where the children inherit `parent`'s value (no unit).
  struct UnitHalf {
    const std::uint32_t* words;
    int half;                                  // the children's unit slots are half * 8 + child slot
    std::uint32_t color(int childSlot) const;  // ABGR, alpha 255 (a ColorUnits unit)
    glm::vec3 normal(int childSlot) const;     // unit length (a NormalUnits unit)
  };
  static std::optional<UnitHalf> unit(const ChildDescriptor* parent, AttachmentType type);
  // Paper Fig. 8 up to the attachment: the first word of attachment `type` in the block with info section
  // `info` (nullptr without one).
  static const std::uint32_t* attachmentOf(const BlockInfo& info, AttachmentType type);
  static const AttachmentEntry* entryOf(const BlockInfo& info, AttachmentType type);
  // The first word of the attachment `entry` (one of `info`'s) describes.
  static const std::uint32_t* startOf(const BlockInfo& info, const AttachmentEntry& entry) {
    return reinterpret_cast<const std::uint32_t*>(&info) + std::ptrdiff_t(entry.pointer);
  }
  AttributeLayout attributeLayout() const;
  bool hasColors() const;
  bool hasNormals() const;

 private:
  const std::byte* base_ = nullptr;
  std::size_t size_ = 0;
  const BlockInfo* info_ = nullptr;
};

// The builder's octree before layout: one record per voxel, root first, children of a voxel contiguous and in
// slot order. A voxel without children is a leaf.
struct VoxelRecord {
  std::uint32_t firstChild = 0;
  std::uint8_t childMask = 0;
  bool hasContour = false;
  // Paging: the voxel has children that are not in this tree; it is laid out as a stub descriptor
  // (format.hpp) that the block pool can turn into a link to the block holding them. Only for voxels without
  // children.
  bool stub = false;
  std::uint32_t contour = 0;
  std::uint32_t color = 0;   // ABGR
  std::uint32_t normal = 0;  // cube-point encoding
};
// A compressed descriptor's units as a block holds them, to be laid out again unchanged.
struct CarriedUnit {
  ColorUnit color;
  NormalUnit normal;
  // An exact normal unit's values (attribute_units.hpp), by unit slot: those of its mask's slots are kept.
  std::array<std::uint32_t, kUnitSlots> exactNormals{};
  bool hasColor = false, hasNormal = false;  // the pair holds that unit (else its children inherit)
  std::uint8_t half = 0;                     // the descriptor's half of the pair
  // Both halves of one pair carry the same units.
  bool sameUnits(const CarriedUnit& o) const {
    return hasColor == o.hasColor && hasNormal == o.hasNormal && color == o.color && normal == o.normal &&
           exactNormals == o.exactNormals;
  }
};
inline constexpr std::uint32_t kNoCarriedUnit = 0xFFFFFFFFu;

// What a layout needs of a voxel tree besides its voxels: which attributes it has and, for the compressed
// layout, what a pool block carries over.
struct TreeAttachments {
  bool hasColors = false;
  bool hasNormals = false;

  // Compressed layouts only; each vector is empty or has one entry per voxel.
  // The store slice that adds each voxel's children (StoreReader::loadTree): siblings share units only where
  // their children come from one slice, as a block pool's regions hold them.
  std::vector<std::uint32_t> childSlice;
  // Units a pool block already holds (the pager deepening a region): index into carriedUnits, or
  // kNoCarriedUnit for a descriptor whose units are encoded from its children's values.
  std::vector<std::uint32_t> carriedUnitOf;
  std::vector<CarriedUnit> carriedUnits;
  // The deepest level's exact values in Morton order (ExactColors, ExactNormals attachments): a pool block
  // keeps them while another slice may be decoded on them, since its units are lossy.
  std::vector<std::uint32_t> exactColors;
  std::vector<std::uint16_t> exactNormals;  // octahedral lattice codes (format.hpp)
  // The root's color (ABGR) and normal (cube encoding) as the blocks above show them (its parent's unit
  // decoded), where its own are the exact values a slice is decoded on: a pool region's cube voxel at its
  // parent region's deepest level. A pair of slots goes without a unit only where each child is within the
  // inheritance tolerance of the value its parent shows. Unset: the root's own values.
  std::optional<std::pair<std::uint32_t, std::uint32_t>> shownRoot;
};

struct VoxelTree : TreeAttachments {
  std::vector<VoxelRecord> voxels;
};

// The default of LayoutOptions::exactNormalUnitDegrees. Swept on the 2 M-triangle terrain at 10 levels (8, 6,
// 4, 3, 2.75, 2.5, 2 degrees): the normals' mean error against the raw layout falls from 1.82 to 0.80 degrees
// at 2.5 (1.01 at 3) with 23% of the units exact, the pool 10.68 -> 12.20 B per leaf voxel (raw: 14.96); the
// bunny's maximum error 46.7 -> 6.6 degrees for 0.01 B per leaf voxel. svo bench quality at 1 voxel per pixel
// barely follows it (the bunny loses 0.13 dB at 2.5, 0.11 at 0.3, nothing only at 0.05).
inline constexpr float kExactNormalUnitDegrees = 2.5f;
// The largest exact-unit angle a command line may ask for: a larger one would keep grid units whose normals
// point away from the values they stand for.
inline constexpr float kMaxExactNormalUnitDegrees = 90.0f;
struct LayoutOptions {
  // Largest near child pointer; smaller values force far pointers (tests).
  std::uint32_t maxNearPointer = kMaxNearPointer;
  // A child whose color is within this many 8-bit steps (per channel) of its parent's inherits it (sec. 5.4).
  int colorInheritSteps = 1;
  // A child whose normal is within this angle of its parent's inherits it (sec. 5.4).
  float normalInheritDegrees = 0.5f;
  // The tree's values are a store's effective values (slices decoded, inheritance applied): a child inherits
  // exactly where its value equals its parent's, as the store decided. The same blocks as the tolerances
  // give for a store written with them, without testing every voxel against them (the pager).
  bool inheritEqualOnly = false;
  AttributeLayout attributes = AttributeLayout::Raw;
  // Compressed layout: a pair whose grid unit misses its children's normals by more than this root mean
  // square angle keeps their values instead (an exact unit, attribute_units.hpp); 0 keeps none.
  float exactNormalUnitDegrees = kExactNormalUnitDegrees;
  // Called between the layout's passes (collecting the voxels, planning the slots, encoding units, writing),
  // and within the compressed layout's unit encoding after every kPairsBetweenPauses pairs: a caller that
  // must leave the cores to another thread for a while (a pager worker while a frame renders) waits there.
  // With it set, units are encoded on the calling thread alone (else on every core).
  std::function<void()> betweenPasses;
};
// The attribute choices a user makes for a pool or a store read whole (--attributes, --exact-normals): the
// LayoutOptions fields of the same names. Built from a layout alone, it takes the default angle.
struct AttributeOptions {
  AttributeLayout layout = AttributeLayout::Raw;
  float exactNormalUnitDegrees = kExactNormalUnitDegrees;
  AttributeOptions() = default;
  AttributeOptions(AttributeLayout layout, float exactNormalUnitDegrees = kExactNormalUnitDegrees)
      : layout(layout), exactNormalUnitDegrees(exactNormalUnitDegrees) {}
  bool compressed() const { return layout == AttributeLayout::Compressed; }
  void applyTo(LayoutOptions& options) const {
    options.attributes = layout;
    options.exactNormalUnitDegrees = exactNormalUnitDegrees;
  }
};

// About 0.2 ms of unit encoding (1.7 us a pair of the 2M terrain's units), as decodeSlice's
// kParentsBetweenPauses is of decoding.
inline constexpr std::size_t kPairsBetweenPauses = 128;

// Sec. 5.4: whether a child's attribute value is left out and inherited from its parent's effective value.
// Shared by the block layout and the slice store, so both leave out the same values.
class InheritanceRule {
 public:
  explicit InheritanceRule(const LayoutOptions& options);
  bool color(std::uint32_t child, std::uint32_t parentEffective) const;
  // The normal test takes the parent's side decoded once for all its children (decoding both normals for
  // every child was a quarter of the block layout's time).
  struct ParentNormal {
    std::uint32_t bits;
    glm::vec3 direction;
    float lengthSquared;
  };
  ParentNormal parentNormal(std::uint32_t parentEffective) const;
  bool normal(std::uint32_t child, const ParentNormal& parent) const;

 private:
  int colorSteps_;
  float normalCos_;
  bool equalOnly_;
};

struct LayoutStats {
  std::uint64_t descriptorSlots = 0, farSlots = 0, pageHeaderSlots = 0, paddingSlots = 0;
  std::uint64_t contourWords = 0, colorValues = 0, normalValues = 0, inheritedColors = 0,
                inheritedNormals = 0;
  std::uint64_t hierarchyBytes = 0, contourBytes = 0, attributeBytes = 0, totalBytes = 0;
  // Compressed layout: unit pairs, their halves that hold children, the slots linked to a descriptor laid
  // out apart so that siblings from different slices do not share units, and the exact values kept.
  std::uint64_t units = 0, unitHalvesUsed = 0, linkSlots = 0, exactBytes = 0;
  std::uint64_t colorUnitsKept = 0, normalUnitsKept = 0;      // pairs holding a unit (the others inherit)
  std::uint64_t exactNormalUnits = 0, exactNormalValues = 0;  // of normalUnitsKept: exact units, their values
  std::uint64_t colorBytes = 0, normalBytes = 0;  // attributeBytes by attribute (units or lookups + values)
};

class Block {
 public:
  Block() = default;
  Block(AlignedBytes bytes);  // validates
  BlockView view() const { return view_; }
  const AlignedBytes& bytes() const { return bytes_; }

 private:
  AlignedBytes bytes_;
  BlockView view_;
};

// A tree that does not fit one block: a block's relative pointers reach 2^24 words (sec. 5.1). A block pool
// holds such a tree as many blocks (the paging client).
struct BlockTooLarge : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Lays a voxel tree out as one block (depth-first child runs, far pointers where a run is out of reach), its
// attributes as options.attributes says. `descriptorSlot`, when given, receives each voxel's descriptor slot
// (0 for leaves; the descriptor itself, not a link to it). Throws BlockTooLarge.
Block layoutBlock(const VoxelTree& tree, const LayoutOptions& options = {}, LayoutStats* stats = nullptr,
                  std::vector<std::uint32_t>* descriptorSlot = nullptr);

// Inverse of layoutBlock up to inheritance: walks the block and rebuilds the voxel records with every
// attribute resolved (inherited values filled in; compressed units decoded: colors as ABGR, normals in the
// cube encoding). Used by tests and tools.
VoxelTree readBlock(const BlockView& block);

// The look-ups a ray caster makes per step or per shaded hit, inline: each is a few dependent loads.
inline const ChildDescriptor* BlockView::child(const ChildDescriptor* parent, int slot) {
  const ChildDescriptor* run = parent + parent->childPointer();
  if (parent->far()) run += *reinterpret_cast<const std::int32_t*>(run);
  return followLink(run + childRank(parent->nonLeafMask(), slot));
}

inline const BlockInfo& BlockView::infoOf(const ChildDescriptor* descriptor) {
  const auto page = reinterpret_cast<std::uintptr_t>(descriptor) & ~std::uintptr_t(kPageBytes - 1);
  const std::int32_t header = *reinterpret_cast<const std::int32_t*>(page);
  return *reinterpret_cast<const BlockInfo*>(page + std::uintptr_t(std::ptrdiff_t(header) * 4));
}

inline std::ptrdiff_t BlockView::slotIndexOf(const ChildDescriptor* descriptor, const BlockInfo& info) {
  const auto* words = reinterpret_cast<const std::uint32_t*>(&info);
  return descriptor - reinterpret_cast<const ChildDescriptor*>(words + std::ptrdiff_t(info.slotsPointer));
}

inline const AttachmentEntry* BlockView::entryOf(const BlockInfo& info, AttachmentType type) {
  const auto* entries = reinterpret_cast<const AttachmentEntry*>(&info + 1);
  for (std::uint32_t a = 0; a < info.attachmentCount; ++a)
    if (entries[a].type == type) return &entries[a];
  return nullptr;
}

inline const std::uint32_t* BlockView::attachmentOf(const BlockInfo& info, AttachmentType type) {
  const AttachmentEntry* entry = entryOf(info, type);
  return entry ? startOf(info, *entry) : nullptr;
}

inline BlockView::Attributes BlockView::attributes(const ChildDescriptor* parent, AttachmentType type) {
  // Paper Fig. 8: page header -> info section -> attachment directory -> lookup entry -> values.
  const BlockInfo& info = infoOf(parent);
  const AttachmentEntry* entry = entryOf(info, type);
  if (!entry) return {};
  const std::uint32_t* attachment = startOf(info, *entry);
  return attributesOf(*entry, attachment, attachment[slotIndexOf(parent, info)]);
}

inline BlockView::Attributes BlockView::attributesOf(const AttachmentEntry& entry,
                                                     const std::uint32_t* attachment,
                                                     std::uint32_t lookupWord) {
  const AttributeLookup lookup{lookupWord};
  Attributes a{lookup.mask(), attachment + lookup.valuePointer()};
  if (lookup.mask() == 0 && lookup.valuePointer() != 0)
    a.shownByAll = lookup.valuePointer() == AttributeLookup::kShownByBlockRoot ? &entry.rootValue : a.values;
  return a;
}

inline std::optional<std::uint32_t> BlockView::attribute(const ChildDescriptor* parent, int slot,
                                                         AttachmentType type) {
  return attributes(parent, type).at(slot);
}

}  // namespace svo
