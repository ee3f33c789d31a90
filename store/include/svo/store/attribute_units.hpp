// Compressed shading attributes (ESVO paper sec. 5.5, Figs. 9 and 10): the values of two sibling
// descriptors' child slots, 16 in all, share one unit of colors (two words) and one unit of normals (four
// words). Decoding is a few integer and float operations (the ray caster's shading step, and the GLSL caster
// with the same operations); encoding searches for the best fit.
#pragma once

#include <array>
#include <bit>
#include <cstdint>

#include <glm/vec3.hpp>

namespace svo {

// Two descriptors' eight child slots: slot i of the unit is child slot i % 8 of the pair's first (i < 8) or
// second descriptor (sec. 5.5).
inline constexpr int kUnitSlots = 16;
inline constexpr int kColorUnitWords = 2;
inline constexpr int kNormalUnitWords = 4;

// Colors, DXT1 without its transparency mode (sec. 5.5): word 0 holds two RGB565 endpoints, c0 in bits 15:0
// and c1 in bits 31:16 (red in bits 15:11 of each, blue in 4:0); word 1 holds 16 2-bit indices, slot i in
// bits 2i+1:2i, choosing c0, c1, (2 c0 + c1) / 3 or (c0 + 2 c1) / 3.
struct ColorUnit {
  std::array<std::uint32_t, kColorUnitWords> words{};
  bool operator==(const ColorUnit&) const = default;
};

// Normals (Fig. 10): word 0 is the base normal n_b as a point on the unit cube (the uncompressed encoding of
// format.hpp); word 1 the axis vectors n_u (bits 15:0) and n_v (bits 31:16), each three signed 4-bit
// components (x in bits 3:0, y in 7:4, z in 11:8) scaled by 2^(e - kNormalAxisExponentBias) with the 4-bit
// exponent e in bits 15:12; words 2 and 3 hold 16 4-bit selectors, slot i in bits 4 (i % 8) + 3 : 4 (i % 8)
// of word 2 + i / 8: bits 1:0 choose c_u and bits 3:2 c_v from {-1, -1/3, +1/3, +1}. The slot's normal is
// normalize(n_b + c_u n_u + c_v n_v).
struct NormalUnit {
  std::array<std::uint32_t, kNormalUnitWords> words{};
  bool operator==(const NormalUnit&) const = default;
};

// An exact unit: where no grid fits a pair's normals within LayoutOptions::exactNormalUnitDegrees, the block
// keeps their values instead of a grid (an extension of the paper's format). Word 1 is kExactNormalAxes
// (n_u's mantissas zero with exponent 15, which no grid unit holds: a grid unit with a zero n_u has exponent
// 0), word 2 the mask of the slots it holds, word 0 the offset in words from the unit's first word to their
// values, one cube-encoded normal (format.hpp) per slot of the mask in slot order, behind the attachment's
// units.
inline constexpr std::uint32_t kExactNormalAxes = 0xF000u;
constexpr bool isExact(const NormalUnit& unit) {
  return unit.words[1] == kExactNormalAxes;
}
// Slot `slot`'s value in the exact unit whose first word is at `unit` in its block.
inline std::uint32_t exactNormalBits(const std::uint32_t* unit, int slot) {
  return unit[unit[0] + std::uint32_t(std::popcount(unit[2] & ((1u << slot) - 1u)))];
}

// Axis scales run from 2^-kNormalAxisExponentBias (finer than the base normal's 15 and 14 bits resolve near
// a face centre) to 2^(15 - kNormalAxisExponentBias), so that 7 steps span the cube's diagonal.
inline constexpr int kNormalAxisExponentBias = 16;

// A unit with low squared error (8-bit RGB units) over the slots whose bit is set in `used`, found by
// search: the least for one or two distinct colors, and up to 8 distinct colors never more than with any
// two of them (rounded to RGB565) as endpoints. The other slots are don't-cares (index 0). Alpha is not
// kept. Deterministic: the same input gives the same bits everywhere.
ColorUnit encodeColorUnit(const std::array<std::uint32_t, kUnitSlots>& abgr, std::uint16_t used);
// Slot `slot`'s color as ABGR with alpha 255.
std::uint32_t decodeColorUnit(const ColorUnit& unit, int slot);

// A grid unit with low angular error over the used slots, found by search (it minimises the sum of 1 - cos
// over them); the other slots are don't-cares (selector 0). Normals need not be unit length but must be
// non-zero and finite (others are taken as +z). Deterministic as encodeColorUnit. `squaredError`, when given,
// receives the sum over the used slots of the squared distance between decoded and given directions (unit
// vectors: the squared chord, about the squared angle).
NormalUnit encodeNormalUnit(const std::array<glm::vec3, kUnitSlots>& normals, std::uint16_t used,
                            float* squaredError = nullptr);
// Slot `slot`'s normal, unit length (n_b when the sum is zero), of a grid unit (an exact unit's values are
// in its block: exactNormalBits).
glm::vec3 decodeNormalUnit(const NormalUnit& unit, int slot);

}  // namespace svo
