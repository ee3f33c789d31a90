// The parts of ESVO ray casting (paper sec. 6, Fig. 15) that the single-ray loop (raycast.cpp) and the packet
// loop (raycast_packet.cpp) share, so that both compute every float the same way: the ray mirrored so that
// every direction component is negative, the contour slab intersection, and the hit completed from the
// loop's final state.
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
inline void completeHit(const OctreeRay& ray, int octant_mask, glm::vec3 pos, float scale_exp2, int scale,
                        float t_min, const ChildDescriptor* parent, int idx, CastHit& hit) {
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

}  // namespace svo::ray_setup
