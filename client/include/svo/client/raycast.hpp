// The ESVO ray caster (paper sec. 6, Fig. 15): PUSH / ADVANCE / POP over a block, in the octree's [1,2]^3.
#pragma once

#include <array>
#include <bit>
#include <cstdint>
#include <optional>

#include <glm/vec3.hpp>

#include "svo/store/block.hpp"

namespace svo {

// A ray in octree space. The hit t is in the same units as `direction` (world distance when the caller
// passes a world-unit direction scaled by 1 / scene size).
struct OctreeRay {
  glm::vec3 origin{0.0f};
  glm::vec3 direction{0.0f, 0.0f, -1.0f};
  float tMin = 0.0f;  // nothing is hit before this t (the beam pass's bound, sec. 6.2)
  float tMax = 3.4e38f;
  // Level of detail: traversal stops at a voxel no larger than footprintOrigin + t * footprintSlope
  // (octree units). Zero slope and origin disable it.
  float footprintOrigin = 0.0f;
  float footprintSlope = 0.0f;
};

// The SIMD loop castPacket runs: the widest this CPU has, or a narrower one (each is castRay bit for bit;
// tests compare every one, and the bench can time them side by side). A loop the CPU lacks falls back to the
// next narrower one.
enum class PacketSimd : std::uint8_t {
  Widest,
  Avx512,  // 32 lanes in two halves of 16 (castTile's 8x4 pixel block), or 16 for up to 16 rays
  Avx2,    // 8 lanes: a packet of 32 rays cast as four quarters
  None,    // castRay, ray by ray
};
const char* nameOf(PacketSimd simd);  // "widest", "avx512", "avx2", "none"
bool cpuHas(PacketSimd simd);
// The loop castPacket runs on this CPU for `requested`.
PacketSimd packetSimdUsed(PacketSimd requested);

struct CastOptions {
  bool contours = true;  // intersect contour slabs (sec. 5.2); off: cube voxels
  // Iteration cap: a ray that would loop this often is reported as a miss (released code does the same).
  int maxIterations = 4096;
  PacketSimd simd = PacketSimd::Widest;  // castPacket's loop
  // Record each hit's ancestors (CastHit::pathParent, pathSlot), which attribute look-ups walk; a caller that
  // reads no attribute (depth alone) saves two stores per PUSH without them.
  bool recordPath = true;
};

struct CastHit {
  bool hit = false;
  float t = 0.0f;
  glm::vec3 position{0.0f};                 // clamped into the hit voxel's cube (sec. 6.1, "hit position")
  const ChildDescriptor* parent = nullptr;  // descriptor holding the hit voxel
  int childSlot = 0;                        // slot of the hit voxel in `parent`
  int scale = 0;                            // voxel size is 2^(scale - 23) octree units
  int iterations = 0;
  bool leaf = false;  // false when stopped by level of detail
  // Descriptor and slot of every ancestor by scale, for attribute inheritance: ancestor at scale s is child
  // `pathSlot[s]` of `pathParent[s]`. Valid for s in (scale, 22] where CastOptions::recordPath.
  const ChildDescriptor* pathParent[kMaxLevels];  // left uninitialized: written by each PUSH
  std::uint8_t pathSlot[kMaxLevels];

  // Octree units: 2^(scale - 23) built from its exponent bits (a normal float at every scale).
  float voxelSize() const { return std::bit_cast<float>(std::uint32_t(scale - kMaxLevels + 127) << 23); }
  glm::vec3 cubeMin{0.0f};  // hit voxel's cube, octree units
};

// Casts one ray through the block. Never returns NaN; never loops forever.
CastHit castRay(const BlockView& block, const OctreeRay& ray, const CastOptions& options = {});

// Rays castPacket casts together: the lanes of two AVX-512 registers (castTile: two 4x4 blocks of pixels side
// by side, one in each).
inline constexpr int kPacketLanes = 32;
// castRay for `count` <= kPacketLanes rays at once, in SIMD lanes (options.simd), else one by one; coherent
// rays (neighbouring pixels) keep the lanes busy together. hits[i] is castRay(block, rays[i], options) bit
// for bit.
void castPacket(const BlockView& block, const OctreeRay* rays, int count, const CastOptions& options,
                CastHit* hits);

// One attribute (colors or normals) of hit voxels, in either layout: the slot of the hit parent's unit (sec.
// 5.5), or the raw value, walking up the path while a voxel inherits (sec. 5.4). Each look-up is a chain of
// dependent loads (page header, info section, directory, lookup entry, value; for an inherited value, the
// same for each ancestor up to the nearest with a value of its own), and neighbouring pixels often hit
// siblings: hits on children of the parent read last share its look-up.
class SiblingAttribute {
 public:
  SiblingAttribute(const BlockView& block, AttachmentType raw);  // Color or Normal
  std::uint32_t value(const CastHit& hit);  // the raw layout's value (0 without the attachment)
  // Decoded, and kept per child of the current parent (neighbouring pixels often hit the same voxel): an
  // instance made for Color serves color, one made for Normal serves normal.
  glm::vec3 color(const CastHit& hit) { return kept(hit) ? decoded_[hit.childSlot] : lookUpColor(hit); }
  glm::vec3 normal(const CastHit& hit) { return kept(hit) ? decoded_[hit.childSlot] : lookUpNormal(hit); }

 private:
  // Whether the hit's value is kept (inline: neighbouring pixels mostly hit a voxel decoded already).
  bool kept(const CastHit& hit) const {
    return hit.parent == parent_ && (decodedMask_ >> hit.childSlot & 1u);
  }
  glm::vec3 lookUpColor(const CastHit& hit);   // linear RGB in [0, 1], kept
  glm::vec3 lookUpNormal(const CastHit& hit);  // unit length, kept
  void select(const ChildDescriptor* parent);
  // The child's decoded value: kept, or `decode()` kept.
  template <class Decode>
  glm::vec3 keptOr(int childSlot, Decode decode);
  // Compressed layout, the parent's pair without a unit: the value the parent shows, from the nearest
  // ancestor whose pair holds one (decoded as `decode(unit, slot)`), else the root's.
  template <class Decode>
  glm::vec3 inheritedFromUnits(const CastHit& hit, Decode decode, glm::vec3 root);
  AttachmentType raw_, units_;
  const AttachmentEntry* rawEntry_;
  const AttachmentEntry* unitsEntry_;
  const ChildDescriptor* parent_ = nullptr;
  std::optional<BlockView::UnitHalf> unit_;
  BlockView::Attributes own_;
  std::optional<std::uint32_t> inherited_;  // the value of the parent's children without their own
  std::optional<glm::vec3> inheritedUnit_;  // the same for a pair without a unit, decoded
  std::array<glm::vec3, 8> decoded_;        // by child slot, where decodedMask_ has its bit
  std::uint8_t decodedMask_ = 0;
};

// Both raw-layout attributes of hit voxels, colors and normals, as two SiblingAttribute::value give them,
// with the page header, info section and slot index read once per parent for both and the attachment
// directory once per block: neighbouring pixels mostly hit children of different parents, so each hit pays a
// parent's look-up (render's reader where the scene has no units; it decodes the values in batches).
class RawAttributePair {
 public:
  explicit RawAttributePair(const BlockView& block);
  // The hit's raw color and normal value; only for an attribute the block has.
  std::uint32_t color(const CastHit& hit) { return value(types_[kColor], hit); }
  std::uint32_t normal(const CastHit& hit) { return value(types_[kNormal], hit); }

 private:
  static constexpr int kColor = 0, kNormal = 1;
  struct Attribute {
    AttachmentType type;
    const AttachmentEntry* sceneEntry;       // the scene root block's: its root value ends a walk up the path
    const AttachmentEntry* entry = nullptr;  // the current parent's block's, and its words
    const std::uint32_t* words = nullptr;
    BlockView::Attributes own{};               // the current parent's lookup entry
    std::optional<std::uint32_t> inherited{};  // the value its children without their own show
  };
  std::uint32_t value(Attribute& a, const CastHit& hit) {
    if (hit.parent != parent_) select(hit.parent);
    if (const std::optional<std::uint32_t> shown = a.own.shown(hit.childSlot)) return *shown;
    return inherited(a, hit);
  }
  void select(const ChildDescriptor* parent);
  std::uint32_t inherited(Attribute& a, const CastHit& hit);
  const ChildDescriptor* parent_ = nullptr;
  const BlockInfo* info_ = nullptr;
  Attribute types_[2];
};

// Requests the Fig. 8 look-ups of hits' attributes a few packets before they are shaded (castTile with
// kLag), one dependent load per packet: each packet's call requests the page headers of its hits' parents,
// and advances every look-up of the kLag - 1 packets before it by one load (a lookup entry or unit
// directory word, then the values or unit, or up the path to the ancestor a value is inherited from). A
// load so has a packet's ray casting to arrive before the next one needs it, and the loads of different
// hits overlap, where a look-up done when its hit is shaded waits for each load in turn.
class AttributePrefetcher {
 public:
  // Packets between a packet's hits and their shading: a header, an entry and the values.
  static constexpr int kLag = 3;
  // Looks up what SiblingAttribute and RawAttributePair read in `block`'s scene: colors and normals, as
  // units where the block has them, else raw; nothing for a scene without either.
  explicit AttributePrefetcher(const BlockView& block);
  // The next packet's hits (count 0: no new packet; castTile's last ones).
  void packet(const CastHit* hits, int count);

 private:
  static constexpr int kMaxTypes = 2;
  // Both attributes' look-ups of a parent's children, together while they walk the same path.
  struct LookUp {
    const CastHit* hit;  // a hit on the parent the look-up starts at (hits on siblings share the path)
    const ChildDescriptor* descriptor;  // the parent, then ancestors while the children inherit
    std::uint8_t slots;                 // the descriptor's children whose values are wanted
    std::uint8_t types;                 // bit t: types_[t] is still looked up
    std::int8_t scale;                  // descriptor is hit->parent at hit->scale, else pathParent[scale]
    bool requested = false;             // the lookup entries (or directory words) are requested
    // One more load (typeOf: the prefetcher's types_); false when done.
    bool step(const AttachmentType* typeOf);
  };
  struct Packet {
    LookUp lookUps[kPacketLanes];
    int count = 0;
  };
  AttachmentType types_[kMaxTypes];
  int typeCount_ = 0;
  Packet packets_[kLag];  // the last kLag packets' look-ups, a ring
  int newest_ = 0;
};

// Resolves an attribute of the hit voxel, walking up the path while a voxel inherits (sec. 5.4): the raw
// layout's value.
std::uint32_t hitAttribute(const BlockView& block, const CastHit& hit, AttachmentType type);
// The hit voxel's color (linear RGB in [0, 1]) and unit normal in either attribute layout: the raw value, or
// its slot of the unit in the hit's parent descriptor (sec. 5.5).
glm::vec3 hitColor(const BlockView& block, const CastHit& hit);
glm::vec3 hitNormal(const BlockView& block, const CastHit& hit);

}  // namespace svo
