// Bit-exact encodings of the ESVO paper, section 5: child descriptors (Fig. 2), contours (Fig. 4),
// uncompressed colors and normals (Fig. 7), attribute lookup entries (Fig. 7c) and page headers.
#pragma once

#include <bit>
#include <cstdint>

#include <glm/geometric.hpp>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

namespace svo {

// Deepest octree the float-mantissa traversal can address (paper sec. 6: positions in [1,2], 23 bits).
inline constexpr int kMaxLevels = 23;
// Page size: a 32-bit page header sits at every 8 KB boundary (paper sec. 5.1).
inline constexpr std::uint32_t kPageBytes = 8192;
// The descriptor array is addressed in 64-bit slots; slot 0 of each page holds the page header.
inline constexpr std::uint32_t kSlotBytes = 8;
inline constexpr std::uint32_t kSlotsPerPage = kPageBytes / kSlotBytes;
// 15-bit relative child pointer in slots: reach 256 KB (paper sec. 5.1, released code).
inline constexpr std::uint32_t kMaxNearPointer = (1u << 15) - 1;
// 24-bit contour pointer and value pointers count 32-bit words.
inline constexpr std::uint32_t kMaxWordPointer = (1u << 24) - 1;

// ---------------------------------------------------------------------------------------------------------
// Child descriptor (Fig. 2). Word 0: [31:17] child pointer, [16] far, [15:8] valid mask, [7:0] leaf mask.
// Word 1: [31:8] contour pointer, [7:0] contour mask. Bit i of a mask is child slot i (x = bit 0, y = 1, z =
// 2).
struct ChildDescriptor {
  std::uint32_t topology = 0;
  std::uint32_t contour = 0;

  static constexpr std::uint32_t kFarBit = 1u << 16;
  static constexpr std::uint32_t kValidAndFarBits = 0x1FF00u;  // [16] far, [15:8] valid mask
  constexpr std::uint32_t childPointer() const { return topology >> 17; }
  constexpr bool far() const { return (topology & kFarBit) != 0; }
  constexpr std::uint8_t validMask() const { return std::uint8_t(topology >> 8); }
  constexpr std::uint8_t leafMask() const { return std::uint8_t(topology); }
  constexpr std::uint8_t nonLeafMask() const { return validMask() & ~leafMask(); }
  constexpr std::uint32_t contourPointer() const { return contour >> 8; }
  constexpr std::uint8_t contourMask() const { return std::uint8_t(contour); }

  // Paging (the client's block pool, docs/architecture.md): a descriptor with an empty valid mask never
  // describes real children. Without the far bit it is a *stub*: the voxel has children that are not
  // resident, and it renders as a leaf. With the far bit it is a *link*: the voxel's descriptor lives in
  // another block, `contour` slots away (signed), which keeps contour and attribute lookups inside that
  // block.
  // Tested on the whole word (valid mask and far bit at once): a ray caster's hot path.
  constexpr bool isStub() const { return (topology & kValidAndFarBits) == 0; }
  constexpr bool isLink() const { return (topology & kValidAndFarBits) == kFarBit; }
  constexpr std::int32_t linkOffset() const { return std::int32_t(contour); }
  static constexpr ChildDescriptor link(std::int32_t slots) { return {kFarBit, std::uint32_t(slots)}; }

  static constexpr ChildDescriptor make(std::uint32_t childPointer, bool far, std::uint8_t valid,
                                        std::uint8_t leaf, std::uint32_t contourPointer,
                                        std::uint8_t contourMask) {
    return {(childPointer << 17) | (std::uint32_t(far) << 16) | (std::uint32_t(valid) << 8) | leaf,
            (contourPointer << 8) | contourMask};
  }
};
static_assert(sizeof(ChildDescriptor) == kSlotBytes);

// The descriptor a link leads to (itself when it is not a link). Links chain where a region's entry voxel
// is also its parent region's (the pager: a run of sub-cubes, then one of those sub-cubes on its own).
inline const ChildDescriptor* followLink(const ChildDescriptor* d) {
  while (d->isLink()) d += d->linkOffset();
  return d;
}

// Index of a child among the set bits of `mask` below it: the k-th stored child (paper sec. 5.1).
constexpr int childRank(std::uint8_t mask, int slot) {
  return std::popcount(unsigned(mask) & ((1u << slot) - 1));
}

// ---------------------------------------------------------------------------------------------------------
// Contour (Fig. 4): [6:0] thickness (unsigned), [13:7] position (signed), [19:14] nz, [25:20] ny, [31:26] nx
// (signed). In the voxel's own frame u = (x - center) / size, so u in [-1/2, 1/2]^3, the contour is the slab
//   | n.u - position | <= thickness / 2,   n = (nx, ny, nz) / kContourNormalScale.
// With |n_i| <= 1 the projection n.u spans at most [-3/2, 3/2]; position and thickness are scaled to cover
// it.
inline constexpr float kContourNormalScale = 31.0f;            // 6-bit signed, +-31
inline constexpr float kContourPositionStep = 1.5f / 63.0f;    // 7-bit signed, +-63 covers +-3/2
inline constexpr float kContourThicknessStep = 3.0f / 127.0f;  // 7-bit unsigned, 127 covers 3

struct Contour {
  glm::vec3 normal{0.0f};  // quantized, components in [-1, 1]
  float position = 0.0f;   // slab centre along normal, voxel units
  float thickness = 0.0f;  // slab width along normal, voxel units
};

constexpr std::uint32_t packContourBits(int nx, int ny, int nz, int position, int thickness) {
  return (std::uint32_t(nx & 63) << 26) | (std::uint32_t(ny & 63) << 20) | (std::uint32_t(nz & 63) << 14) |
         (std::uint32_t(position & 127) << 7) | std::uint32_t(thickness & 127);
}
// The integer fields packContourBits packs: normal and position signed, thickness unsigned.
struct ContourFields {
  int normal[3];
  int position, thickness;
};
constexpr ContourFields contourFields(std::uint32_t bits) {
  const auto s = std::int32_t(bits);
  return {{s >> 26, (s << 6) >> 26, (s << 12) >> 26}, (s << 18) >> 25, int(bits & 127u)};
}
inline Contour decodeContour(std::uint32_t bits) {
  const ContourFields f = contourFields(bits);
  Contour c;
  c.normal = glm::vec3(float(f.normal[0]), float(f.normal[1]), float(f.normal[2])) / kContourNormalScale;
  c.position = float(f.position) * kContourPositionStep;
  c.thickness = float(f.thickness) * kContourThicknessStep;
  return c;
}
// Quantizes a normal to the 6-bit grid with its largest component at +-31 (keeps the most precision).
glm::ivec3 quantizeContourNormal(glm::dvec3 n);
// Encodes the slab [lo, hi] (projections onto the *quantized* normal, voxel units) conservatively: the stored
// slab always contains [lo, hi]. Returns false when the quantized slab would not be narrower than the cube.
bool encodeContour(glm::ivec3 qn, double lo, double hi, std::uint32_t& bits);

// ---------------------------------------------------------------------------------------------------------
// Uncompressed attributes (sec. 5.4, Fig. 7). Color: ABGR, 8 bits each, R in the low byte.
constexpr std::uint32_t packABGR(std::uint8_t r, std::uint8_t g, std::uint8_t b, std::uint8_t a = 255) {
  return (std::uint32_t(a) << 24) | (std::uint32_t(b) << 16) | (std::uint32_t(g) << 8) | r;
}
// Alpha is the voxel's coverage: 255 for a surface, a fog volume's density where it varies (volume import).
std::uint32_t encodeColor(glm::vec4 rgba);  // components in [0, 1], rounded
// Inline, as the renderer decodes one per shaded hit.
inline glm::vec4 decodeColor(std::uint32_t abgr) {
  return glm::vec4(float(abgr & 255u), float((abgr >> 8) & 255u), float((abgr >> 16) & 255u),
                   float(abgr >> 24)) /
         255.0f;
}
// The albedo a voxel without a color shows. A store that carries a fog volume's density but no colors gives
// its colors this grey, so the density changes no image.
inline constexpr float kNeutralGreyAlbedo = 0.8f;

// Normal as a point on the unit cube: [31:29] face (axis * 2 + negative), [28:14] u (15 bits), [13:0] v
// (14 bits); u, v are the two remaining coordinates in [-1, 1] in axis order.
inline constexpr std::uint32_t kNormalUMax = (1u << 15) - 1;  // 15-bit face coordinate (Fig. 7b)
inline constexpr std::uint32_t kNormalVMax = (1u << 14) - 1;  // 14-bit face coordinate (Fig. 7b)
std::uint32_t encodeNormal(glm::vec3 n);
// The normal's point on the unit cube (not unit length): decodeNormal without the normalization, inline for
// the layout's per-voxel inheritance test.
inline glm::vec3 normalDirection(std::uint32_t bits) {
  const std::uint32_t face = bits >> 29;
  const int axis = face >> 1 < 2 ? int(face >> 1) : 2;
  const float u = float((bits >> 14) & kNormalUMax) / float(kNormalUMax) * 2.0f - 1.0f;
  const float v = float(bits & kNormalVMax) / float(kNormalVMax) * 2.0f - 1.0f;
  const float w = (face & 1u) ? -1.0f : 1.0f;
  return axis == 0 ? glm::vec3(w, u, v) : axis == 1 ? glm::vec3(u, w, v) : glm::vec3(u, v, w);
}
// Unit length; inline, as the renderer decodes one per shaded hit.
inline glm::vec3 decodeNormal(std::uint32_t bits) {
  return glm::normalize(normalDirection(bits));
}

// The store's normal lattice (format v4): 16-bit octahedral codes, 8 bits per coordinate of the unit
// octahedron folded onto a square (Cigolle et al. 2014, "A Survey of Efficient Representations for
// Independent Unit Vectors", sec. 3.6). The builder rounds every normal onto it (latticeNormal), so the
// store keeps two bytes per normal without loss; blocks keep the cube encoding above (sec. 5.4). Lattice
// steps are 0.7 degrees at most: rounding moves a normal by under one degree.
inline constexpr int kOctNormalBits = 8;   // per coordinate: measured on the 20M terrain, 1.06 B/leaf stored
std::uint16_t octNormalCode(glm::vec3 n);  // nearest lattice point of a non-zero direction
glm::vec3 octNormalDirection(std::uint16_t code);  // unit length
// The cube encoding of each lattice point, by code (65536 entries, built on first use).
const std::uint32_t* latticeNormalTable();
inline std::uint32_t latticeNormalBits(std::uint16_t code) {
  return latticeNormalTable()[code];
}
// The cube-encoded normal rounded onto the lattice; latticeNormal(n) for a direction.
inline std::uint16_t octNormalCodeOf(std::uint32_t normalBits) {
  return octNormalCode(normalDirection(normalBits));
}
// octNormalCodeOf(latticeNormalBits(code)), by code: the code a lattice point's normal rounds to (a few codes
// on the octahedron's folded edges name the same point as another). Built on first use, as the tables above.
const std::uint32_t* canonicalNormalCodeTable();
inline std::uint32_t latticeNormal(glm::vec3 n) {
  return latticeNormalBits(octNormalCode(n));
}
// The contour normal (its 18 bits in place, [31:14]) that quantizeContourNormal gives for the lattice normal
// `code`: the store predicts a contour's normal from its voxel's normal (a table lookup).
const std::uint32_t* contourNormalPredictionTable();  // by code, as latticeNormalTable
inline std::uint32_t predictedContourNormalBits(std::uint16_t code) {
  return contourNormalPredictionTable()[code];
}

// Attribute lookup entry (Fig. 7c): [7:0] attribute mask, [31:8] value pointer in 32-bit words from the start
// of the attachment's value array. A child whose bit is clear inherits its parent's value. Where no child has
// a value of its own (mask 0), the pointer leads to the value they all show, so that a look-up ends at the
// parent instead of walking up the path: kShownByBlockRoot for the block root's (AttachmentEntry::rootValue),
// 0 where the entry does not say (walk up).
struct AttributeLookup {
  static constexpr std::uint32_t kShownByBlockRoot = 0xFFFFFF;
  std::uint32_t bits = 0;
  constexpr std::uint8_t mask() const { return std::uint8_t(bits); }
  constexpr std::uint32_t valuePointer() const { return bits >> 8; }
  static constexpr AttributeLookup make(std::uint32_t valuePointer, std::uint8_t mask) {
    return {(valuePointer << 8) | mask};
  }
};

// ---------------------------------------------------------------------------------------------------------
// Attachment types listed in a block's info section. A scene stores only the types it has, in one of two
// layouts (block.hpp, AttributeLayout): uncompressed values behind lookup entries (sec. 5.4), or compressed
// units indexed by descriptor slot (sec. 5.5, attribute_units.hpp). A block pool's region that more slices
// may deepen also keeps its deepest level's exact values, which the next slice is decoded on (the renderer
// never reads them).
enum class AttachmentType : std::uint32_t {
  Color = 1,
  Normal = 2,
  ColorUnits = 3,    // kColorUnitWords per pair of slots
  NormalUnits = 4,   // kNormalUnitWords per pair of slots
  ExactColors = 5,   // ABGR words, the deepest level in Morton order
  ExactNormals = 6,  // 16-bit lattice codes (two per word), the deepest level in Morton order
};

}  // namespace svo
