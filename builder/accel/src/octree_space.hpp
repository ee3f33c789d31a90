// The space both octrees subdivide (OAVM paper Sec. 2.1): cells addressed by level and Morton code, and the
// one subdivision rule they share, so that both build the same leaves with the same references.
#pragma once

#include <cstdint>
#include <vector>

#include <glm/vec3.hpp>

#include "common.hpp"

namespace svo::accel::detail {

using U64 = std::uint64_t;

// Morton codes interleave 21 bits per axis into 63 bits: the deepest level an octree can have.
inline constexpr int kMaxOctreeLevels = 21;

// ----- Morton codes (Sec. 2.1): parent = code >> 3, child = 8·code + F, F = x | y << 1 | z << 2 -----------
inline U64 spread(U64 v) {
  v &= 0x1fffff;
  v = (v | v << 32) & 0x1f00000000ffffULL;
  v = (v | v << 16) & 0x1f0000ff0000ffULL;
  v = (v | v << 8) & 0x100f00f00f00f00fULL;
  v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
  v = (v | v << 2) & 0x1249249249249249ULL;
  return v;
}
inline U64 morton(U64 x, U64 y, U64 z) {
  return spread(x) | spread(y) << 1 | spread(z) << 2;
}
inline U64 compact(U64 v) {
  v &= 0x1249249249249249ULL;
  v = (v ^ (v >> 2)) & 0x10c30c30c30c30c3ULL;
  v = (v ^ (v >> 4)) & 0x100f00f00f00f00fULL;
  v = (v ^ (v >> 8)) & 0x1f0000ff0000ffULL;
  v = (v ^ (v >> 16)) & 0x1f00000000ffffULL;
  v = (v ^ (v >> 32)) & 0x1fffff;
  return v;
}
inline glm::u64vec3 demorton(U64 code) {
  return {compact(code), compact(code >> 1), compact(code >> 2)};
}

// Integer box in finest-level units, [lo, hi).
struct IBox {
  glm::u64vec3 lo{0}, hi{0};
};

// ----- the shared subdivision ----------------------------------------------------------------------------
struct Space {
  dvec3 lo{0.0};
  double size = 1.0;  // root cube edge
  int maxLevel = 0;
  double fine = 1.0;  // edge of a finest-level cell
  Box worldBox(const IBox& b) const { return Box{lo + dvec3(b.lo) * fine, lo + dvec3(b.hi) * fine}; }
  IBox cell(int level, U64 code) const {
    const glm::u64vec3 c = demorton(code);
    const int shift = maxLevel - level;
    return IBox{c << U64(shift), (c + U64(1)) << U64(shift)};
  }
};

// The root cube over `bounds`; a negative `maxLevel` picks the depth from the triangle count `n`.
Space makeSpace(const Box& bounds, std::size_t n, int maxLevel);
// The triangle overlaps the cell grown by the store's fat margin.
bool overlapsCell(const TriangleStore& store, std::uint32_t id, const Box& cell);
// Decides whether a node is subdivided and gives each child its triangles; false means a leaf.
bool subdivide(const TriangleStore& store, const Space& space, const OctreeParams& p, int level, U64 code,
               const std::vector<std::uint32_t>& prims, std::vector<std::uint32_t> children[8]);

}  // namespace svo::accel::detail
