// The parts of ESVO ray casting (paper sec. 6, Fig. 15) that castRay (raycast.cpp) and the packet loop
// (raycast_packet.cpp) share, so that both compute every float the same way: the ray mirrored so that every
// direction component is negative, the contour slab intersection, the single-ray loop itself (castRay runs
// it from the root, the packet loop for its last few lanes from where they are, the level-array caster
// through its own reading of the octree), and the hit completed from the loop's final state.
#pragma once

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>

#include "svo/client/raycast.hpp"

namespace svo::ray_setup {

inline constexpr int kScaleMax = kMaxLevels;  // s_max: 23 mantissa bits
// Direction components below 2^-23 of the largest one (rounded down to a power of two) are clamped to +-that
// (released code: 2^-23 for its unit-scale rays; relative here, since a ray's direction carries the scene's
// scale): no division by zero and no infinities, while still far steeper than any voxel the float positions
// can address.
inline constexpr float kMinDirection = 1.0f / float(1 << kScaleMax);
// Below this |n.d| a ray runs parallel to a contour slab: inside it or outside, never through it.
inline constexpr float kParallelContour = 1e-20f;

// The child run and contours below a descriptor PUSH has just entered, requested while the ray intersects its
// child cubes: in an octree larger than the caches each PUSH otherwise waits for memory there.
inline void prefetchBelow(const ChildDescriptor* d) {
  __builtin_prefetch(d + d->childPointer());
  __builtin_prefetch(reinterpret_cast<const std::uint32_t*>(d) + d->contourPointer());
}

inline float asFloat(std::uint32_t bits) {
  return std::bit_cast<float>(bits);
}
inline std::uint32_t asBits(float f) {
  return std::bit_cast<std::uint32_t>(f);
}

// kMinDirection scaled by the power of two at or below `largest` (> 0, finite): std::ldexp(kMinDirection,
// std::ilogb(largest)), from the exponent bits where both are normal floats (no library calls per ray).
inline float minDirection(float largest) {
  const int exponent = int(asBits(largest) >> 23) - 127;  // ilogb of a normal float
  constexpr int kMinNormalExponent = -126;
  // `largest` subnormal, or a result below the normal floats: the library's rounding.
  if (exponent < kMinNormalExponent + kScaleMax) return std::ldexp(kMinDirection, std::ilogb(largest));
  return asFloat(std::uint32_t(exponent - kScaleMax + 127) << 23);
}

// A ray in the mirrored system, with its entry into the root's first child cube (scale kScaleMax - 1).
struct MirroredRay {
  glm::vec3 d{0.0f};                            // the direction, tiny components clamped
  float tx_coef = 0, ty_coef = 0, tz_coef = 0;  // t_x(x) = x * tx_coef - tx_bias
  float tx_bias = 0, ty_bias = 0, tz_bias = 0;
  int octant_mask = 7;
  float t_min = 0, t_max = 0;
  int idx = 0;
  glm::vec3 pos{1.0f};
};

// False when the ray cannot hit anything: a non-finite or zero vector, or no part of the root cube within
// [tMin, tMax].
inline bool mirrorRay(const OctreeRay& ray, MirroredRay& m) {
  glm::vec3 d = ray.direction;
  const glm::vec3 o = ray.origin;
  if (!std::isfinite(d.x) || !std::isfinite(d.y) || !std::isfinite(d.z) || !std::isfinite(o.x) ||
      !std::isfinite(o.y) || !std::isfinite(o.z) || d == glm::vec3(0.0f))
    return false;
  // A power of two, so that the clamped axis' t = position * coef - bias stays exact on the voxel grid (a
  // ray exactly in a voxel face keeps t = 0 there, not a rounding residue).
  const float minComponent = minDirection(std::max({std::abs(d.x), std::abs(d.y), std::abs(d.z)}));
  for (int i = 0; i < 3; ++i)
    if (std::abs(d[i]) < minComponent) d[i] = std::copysign(minComponent, d[i]);
  m.d = d;

  // t_x(x) = x * tx_coef - tx_bias, in the mirrored system where every direction component is negative.
  m.tx_coef = 1.0f / -std::abs(d.x), m.ty_coef = 1.0f / -std::abs(d.y), m.tz_coef = 1.0f / -std::abs(d.z);
  m.tx_bias = m.tx_coef * o.x, m.ty_bias = m.ty_coef * o.y, m.tz_bias = m.tz_coef * o.z;
  m.octant_mask = 7;
  if (d.x > 0.0f) m.octant_mask ^= 1, m.tx_bias = 3.0f * m.tx_coef - m.tx_bias;
  if (d.y > 0.0f) m.octant_mask ^= 2, m.ty_bias = 3.0f * m.ty_coef - m.ty_bias;
  if (d.z > 0.0f) m.octant_mask ^= 4, m.tz_bias = 3.0f * m.tz_coef - m.tz_bias;

  // Active t-span: the root cube, clipped to [0, tMax].
  m.t_min =
      std::max({2.0f * m.tx_coef - m.tx_bias, 2.0f * m.ty_coef - m.ty_bias, 2.0f * m.tz_coef - m.tz_bias});
  m.t_max = std::min({m.tx_coef - m.tx_bias, m.ty_coef - m.ty_bias, m.tz_coef - m.tz_bias});
  m.t_min = std::max(m.t_min, std::max(ray.tMin, 0.0f));
  m.t_max = std::min(m.t_max, ray.tMax);
  if (!(m.t_min <= m.t_max)) return false;

  m.idx = 0;
  m.pos = glm::vec3(1.0f);
  if (1.5f * m.tx_coef - m.tx_bias > m.t_min) m.idx ^= 1, m.pos.x = 1.5f;
  if (1.5f * m.ty_coef - m.ty_bias > m.t_min) m.idx ^= 2, m.pos.y = 1.5f;
  if (1.5f * m.tz_coef - m.tz_bias > m.t_min) m.idx ^= 4, m.pos.z = 1.5f;
  return true;
}

// The contour of child `slot` of `parent` (whose descriptor is `descriptor`).
inline Contour contourOf(const ChildDescriptor* parent, const ChildDescriptor& descriptor, int slot) {
  const auto* words = reinterpret_cast<const std::uint32_t*>(parent) + descriptor.contourPointer();
  return decodeContour(words[childRank(descriptor.contourMask(), slot)]);
}

// INTERSECT with the voxel's contour slab (sec. 5.2): |n.(x - centre)/size - position| <= thickness/2 along
// x = o + t d clips the span [t_min, tv_max]. n.(centre - o) = sum n_i d_i t_center_i (t_center_i is where
// the ray crosses the centre plane of axis i).
inline void clipToContour(const Contour& c, const glm::vec3& d, float tx_center, float ty_center,
                          float tz_center, float scale_exp2, float& t_min, float& tv_max) {
  const float den = c.normal.x * d.x + c.normal.y * d.y + c.normal.z * d.z;
  const float num = c.normal.x * d.x * tx_center + c.normal.y * d.y * ty_center +
                    c.normal.z * d.z * tz_center + scale_exp2 * c.position;
  const float halfWidth = 0.5f * scale_exp2 * c.thickness;
  if (std::abs(den) > kParallelContour) {
    const float inv = 1.0f / den;
    const float tmid = num * inv, tdiff = std::abs(halfWidth * inv);
    t_min = std::max(t_min, tmid - tdiff);
    tv_max = std::min(tv_max, tmid + tdiff);
  } else if (std::abs(num) > halfWidth) {
    tv_max = -1.0f;  // parallel and outside: the voxel's shape is not on this ray
  }
}

// The hit from the loop's state where it stopped: the mirroring undone and the hit position clamped into
// the voxel's cube (sec. 6.1).
template <class Node, class Hit>
void completeHit(const OctreeRay& ray, int octant_mask, glm::vec3 pos, float scale_exp2, int scale,
                 float t_min, Node parent, int idx, Hit& hit) {
  if ((octant_mask & 1) == 0) pos.x = 3.0f - scale_exp2 - pos.x;
  if ((octant_mask & 2) == 0) pos.y = 3.0f - scale_exp2 - pos.y;
  if ((octant_mask & 4) == 0) pos.z = 3.0f - scale_exp2 - pos.z;
  hit.hit = true;
  hit.t = t_min;
  hit.scale = scale;
  hit.parent = parent;
  hit.childSlot = idx ^ octant_mask ^ 7;
  hit.cubeMin = pos;
  const float inset = std::min(kMinDirection, 0.25f * scale_exp2);
  for (int i = 0; i < 3; ++i)
    hit.position[i] = std::min(std::max(ray.origin[i] + t_min * ray.direction[i], pos[i] + inset),
                               pos[i] + scale_exp2 - inset);
}

// How the loop reads a block's octree: a parent is a descriptor, whose words give its children's masks and
// contours and lead to their descriptors. (LevelDescent, level_raycast.cpp, reads arrays per level instead.)
struct BlockDescent {
  using Node = const ChildDescriptor*;
  struct Parent {  // a descriptor's words, read once per PUSH or POP
    ChildDescriptor descriptor;
    std::uint8_t validMask, nonLeafMask;
  };
  static Parent read(Node parent, int /*scale*/) {
    const ChildDescriptor d = *parent;
    return {d, d.validMask(), d.nonLeafMask()};
  }
  // The contour of child `slot`, where it has one.
  static bool contour(Node parent, const Parent& p, int slot, int /*scale*/, Contour& c) {
    if (!(p.descriptor.contourMask() >> slot & 1)) return false;
    c = contourOf(parent, p.descriptor, slot);
    return true;
  }
  // The child to PUSH into; false where child `slot` is the hit: a leaf, or (in a block pool) a voxel whose
  // children are not resident.
  static bool child(Node parent, const Parent& p, int slot, int /*scale*/, Node& child) {
    child = (p.nonLeafMask >> slot & 1) ? BlockView::child(parent, slot) : nullptr;
    if (!child || child->isStub()) return false;
    prefetchBelow(child);
    return true;
  }
  static void recordPath(CastHit& hit, int scale, Node parent, int slot) {
    hit.pathParent[scale] = parent;
    hit.pathSlot[scale] = std::uint8_t(slot);
  }
};

// castRay's loop state part way along a ray (names as in castRay); the stack of (parent, t_max) is indexed by
// scale.
template <class Node>
struct RayStackEntryOf {
  Node parent;
  float t_max;
};
template <class Node>
struct RayStateOf {
  Node parent;
  glm::vec3 pos;
  float scale_exp2, t_min, t_max;
  int idx, scale, iterations;
};
using RayStackEntry = RayStackEntryOf<BlockDescent::Node>;
using RayState = RayStateOf<BlockDescent::Node>;

// Fig. 15's loop from `s` on, for the mirrored ray `m` with its footprint: true where the ray hits (hit.leaf
// set at a leaf or a stub), false where it leaves the octree or reaches the iteration cap. PUSH writes the
// stack and the hit's path. castRay runs it from the root; the packet loop finishes its last few lanes with
// it. `descent` reads the octree (BlockDescent: a block's descriptors).
template <class Descent = BlockDescent, class Hit>
[[gnu::always_inline]] inline bool continueRay(const MirroredRay& m, float footprintSlope,
                                               float footprintOrigin, const CastOptions& options,
                                               RayStateOf<typename Descent::Node>& s,
                                               RayStackEntryOf<typename Descent::Node>* stack, Hit& hit,
                                               const Descent& descent = {}) {
  using Node = typename Descent::Node;
  const bool recordPath = options.recordPath;  // read once: the stores into `hit` might alias `options`
  const glm::vec3 d = m.d;
  const float tx_coef = m.tx_coef, ty_coef = m.ty_coef, tz_coef = m.tz_coef;
  const float tx_bias = m.tx_bias, ty_bias = m.ty_bias, tz_bias = m.tz_bias;
  const int octant_mask = m.octant_mask;
  Node parent = s.parent;
  glm::vec3 pos = s.pos;
  float scale_exp2 = s.scale_exp2, t_min = s.t_min, t_max = s.t_max;
  int idx = s.idx, scale = s.scale, iterations = s.iterations;
  typename Descent::Parent words{};
  bool cached = false;
  bool found = false;
  while (scale < kScaleMax) {
    if (++iterations > options.maxIterations) break;
    if (!cached) {
      words = descent.read(parent, scale);
      cached = true;
    }
    const std::uint8_t validMask = words.validMask;
    // The t-value where the ray leaves the current cube: its lower corner in the mirrored system.
    const float tx_corner = pos.x * tx_coef - tx_bias;
    const float ty_corner = pos.y * ty_coef - ty_bias;
    const float tz_corner = pos.z * tz_coef - tz_bias;
    const float tc_max = std::min({tx_corner, ty_corner, tz_corner});

    const int slot = idx ^ octant_mask ^ 7;  // the child slot in unmirrored space
    if ((validMask >> slot & 1) && t_min <= t_max) {
      // Level of detail: the voxel is no larger than the ray's footprint where the ray leaves it.
      if (tc_max * footprintSlope + footprintOrigin >= scale_exp2) {
        found = true;
        break;
      }
      // INTERSECT: the cube, then the voxel's contour slab.
      float tv_max = std::min(t_max, tc_max);
      const float half = scale_exp2 * 0.5f;
      const float tx_center = half * tx_coef + tx_corner;
      const float ty_center = half * ty_coef + ty_corner;
      const float tz_center = half * tz_coef + tz_corner;
      Contour contour;
      if (options.contours && descent.contour(parent, words, slot, scale, contour))
        clipToContour(contour, d, tx_center, ty_center, tz_center, scale_exp2, t_min, tv_max);
      if (t_min <= tv_max) {
        Node child;
        if (!descent.child(parent, words, slot, scale, child)) {  // this is the hit
          found = true;
          hit.leaf = true;
          break;
        }
        // PUSH. Fig. 15 stores the parent only when the child ends before it (tc_max < h). At the deepest
        // scales the two exits can round to the same float while the position bits still say the ray left
        // the child first, and POP would then read a stale or unwritten entry: store on every PUSH.
        stack[scale] = {parent, t_max};
        if (recordPath) descent.recordPath(hit, scale, parent, slot);
        parent = child;
        idx = 0;
        --scale;
        scale_exp2 = half;
        if (tx_center > t_min) idx ^= 1, pos.x += scale_exp2;
        if (ty_center > t_min) idx ^= 2, pos.y += scale_exp2;
        if (tz_center > t_min) idx ^= 4, pos.z += scale_exp2;
        t_max = tv_max;
        cached = false;
        continue;
      }
    }

    // ADVANCE: step to the next cube of the same scale along the ray.
    int step_mask = 0;
    if (tx_corner <= tc_max) step_mask ^= 1, pos.x -= scale_exp2;
    if (ty_corner <= tc_max) step_mask ^= 2, pos.y -= scale_exp2;
    if (tz_corner <= tc_max) step_mask ^= 4, pos.z -= scale_exp2;
    t_min = tc_max;
    idx ^= step_mask;

    // POP when a bit flipped against the ray direction: the ray left the parent.
    if ((idx & step_mask) != 0) {
      std::uint32_t differing_bits = 0;
      if (step_mask & 1) differing_bits |= asBits(pos.x) ^ asBits(pos.x + scale_exp2);
      if (step_mask & 2) differing_bits |= asBits(pos.y) ^ asBits(pos.y + scale_exp2);
      if (step_mask & 4) differing_bits |= asBits(pos.z) ^ asBits(pos.z + scale_exp2);
      scale = int(asBits(float(differing_bits)) >> 23) - 127;  // position of the highest differing bit
      if (scale >= kScaleMax) break;                           // left the octree
      scale_exp2 = asFloat(std::uint32_t(scale - kScaleMax + 127) << 23);
      parent = stack[scale].parent;
      t_max = stack[scale].t_max;
      // Round the position down to the new scale and read the child index from its bits.
      const std::uint32_t shx = asBits(pos.x) >> scale, shy = asBits(pos.y) >> scale,
                          shz = asBits(pos.z) >> scale;
      pos = glm::vec3(asFloat(shx << scale), asFloat(shy << scale), asFloat(shz << scale));
      idx = int((shx & 1) | ((shy & 1) << 1) | ((shz & 1) << 2));
      cached = false;
    }
  }
  s = {parent, pos, scale_exp2, t_min, t_max, idx, scale, iterations};
  return found;
}

// castRay: the ray from the root (node `root`, its children at scale kScaleMax - 1) until it hits or leaves,
// and the hit completed.
template <class Descent = BlockDescent, class Hit>
void castFromRoot(typename Descent::Node root, const OctreeRay& ray, const CastOptions& options, Hit& hit,
                  const Descent& descent = {}) {
  MirroredRay m;
  if (!mirrorRay(ray, m)) return;
  RayStackEntryOf<typename Descent::Node> stack[kScaleMax + 1];
  RayStateOf<typename Descent::Node> s{.parent = root,
                                       .pos = m.pos,
                                       .scale_exp2 = 0.5f,
                                       .t_min = m.t_min,
                                       .t_max = m.t_max,
                                       .idx = m.idx,
                                       .scale = kScaleMax - 1,
                                       .iterations = 0};
  const bool found = continueRay(m, ray.footprintSlope, ray.footprintOrigin, options, s, stack, hit, descent);
  hit.iterations = s.iterations;
  if (found) completeHit(ray, m.octant_mask, s.pos, s.scale_exp2, s.scale, s.t_min, s.parent, s.idx, hit);
}

}  // namespace svo::ray_setup
