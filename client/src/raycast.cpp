// ESVO ray casting (paper sec. 6, Fig. 15). The octree occupies [1,2]^3 so that the float mantissa bits of
// a position are its path through the tree; the coordinate system is mirrored so that every direction
// component is negative; the stack of (parent, t_max) is indexed by scale; POP finds the new scale from
// the highest differing bit of the old and new position. Variable names follow the paper.
#include "svo/client/raycast.hpp"

#include <algorithm>
#include <bit>
#include <cmath>

namespace svo {
namespace {

constexpr int kScaleMax = kMaxLevels;  // s_max: 23 mantissa bits
// Direction components below 2^-23 of the largest one (rounded down to a power of two) are clamped to +-that
// (released code: 2^-23 for its unit-scale rays; relative here, since a ray's direction carries the scene's
// scale): no division by zero and no infinities, while still far steeper than any voxel the float positions
// can address.
constexpr float kMinDirection = 1.0f / float(1 << kScaleMax);
// Below this |n.d| a ray runs parallel to a contour slab: inside it or outside, never through it.
constexpr float kParallelContour = 1e-20f;

inline float asFloat(std::uint32_t bits) {
  return std::bit_cast<float>(bits);
}
inline std::uint32_t asBits(float f) {
  return std::bit_cast<std::uint32_t>(f);
}

}  // namespace

float CastHit::voxelSize() const {
  return std::ldexp(1.0f, scale - kScaleMax);
}

CastHit castRay(const BlockView& block, const OctreeRay& ray, const CastOptions& options) {
  CastHit hit;
  glm::vec3 d = ray.direction;
  const glm::vec3 o = ray.origin;
  if (!std::isfinite(d.x) || !std::isfinite(d.y) || !std::isfinite(d.z) || !std::isfinite(o.x) ||
      !std::isfinite(o.y) || !std::isfinite(o.z) || d == glm::vec3(0.0f))
    return hit;
  // A power of two, so that the clamped axis' t = position * coef - bias stays exact on the voxel grid (a
  // ray exactly in a voxel face keeps t = 0 there, not a rounding residue).
  const float minComponent =
      std::ldexp(kMinDirection, std::ilogb(std::max({std::abs(d.x), std::abs(d.y), std::abs(d.z)})));
  for (int i = 0; i < 3; ++i)
    if (std::abs(d[i]) < minComponent) d[i] = std::copysign(minComponent, d[i]);

  // t_x(x) = x * tx_coef - tx_bias, in the mirrored system where every direction component is negative.
  float tx_coef = 1.0f / -std::abs(d.x), ty_coef = 1.0f / -std::abs(d.y), tz_coef = 1.0f / -std::abs(d.z);
  float tx_bias = tx_coef * o.x, ty_bias = ty_coef * o.y, tz_bias = tz_coef * o.z;
  int octant_mask = 7;
  if (d.x > 0.0f) octant_mask ^= 1, tx_bias = 3.0f * tx_coef - tx_bias;
  if (d.y > 0.0f) octant_mask ^= 2, ty_bias = 3.0f * ty_coef - ty_bias;
  if (d.z > 0.0f) octant_mask ^= 4, tz_bias = 3.0f * tz_coef - tz_bias;

  // Active t-span: the root cube, clipped to [0, tMax].
  float t_min = std::max({2.0f * tx_coef - tx_bias, 2.0f * ty_coef - ty_bias, 2.0f * tz_coef - tz_bias});
  float t_max = std::min({tx_coef - tx_bias, ty_coef - ty_bias, tz_coef - tz_bias});
  t_min = std::max(t_min, std::max(ray.tMin, 0.0f));
  t_max = std::min(t_max, ray.tMax);
  if (!(t_min <= t_max)) return hit;

  struct StackEntry {
    const ChildDescriptor* parent;
    float t_max;
  } stack[kScaleMax + 1];

  const ChildDescriptor* parent = block.root();
  ChildDescriptor descriptor{};
  bool cached = false;
  std::uint8_t validMask = 0, nonLeafMask = 0;
  int idx = 0;
  glm::vec3 pos(1.0f);
  int scale = kScaleMax - 1;
  float scale_exp2 = 0.5f;
  if (1.5f * tx_coef - tx_bias > t_min) idx ^= 1, pos.x = 1.5f;
  if (1.5f * ty_coef - ty_bias > t_min) idx ^= 2, pos.y = 1.5f;
  if (1.5f * tz_coef - tz_bias > t_min) idx ^= 4, pos.z = 1.5f;

  int iterations = 0;
  bool found = false;
  while (scale < kScaleMax) {
    if (++iterations > options.maxIterations) break;
    if (!cached) {
      descriptor = *parent;
      validMask = descriptor.validMask();
      nonLeafMask = descriptor.nonLeafMask();
      cached = true;
    }
    // The t-value where the ray leaves the current cube: its lower corner in the mirrored system.
    const float tx_corner = pos.x * tx_coef - tx_bias;
    const float ty_corner = pos.y * ty_coef - ty_bias;
    const float tz_corner = pos.z * tz_coef - tz_bias;
    const float tc_max = std::min({tx_corner, ty_corner, tz_corner});

    const int slot = idx ^ octant_mask ^ 7;  // the child slot in unmirrored space
    if ((validMask >> slot & 1) && t_min <= t_max) {
      // Level of detail: the voxel is no larger than the ray's footprint where the ray leaves it.
      if (tc_max * ray.footprintSlope + ray.footprintOrigin >= scale_exp2) {
        found = true;
        break;
      }
      // INTERSECT: the cube, then the voxel's contour slab.
      float tv_max = std::min(t_max, tc_max);
      const float half = scale_exp2 * 0.5f;
      const float tx_center = half * tx_coef + tx_corner;
      const float ty_center = half * ty_coef + ty_corner;
      const float tz_center = half * tz_coef + tz_corner;
      if (options.contours && (descriptor.contourMask() >> slot & 1)) {
        const auto* words = reinterpret_cast<const std::uint32_t*>(parent) + descriptor.contourPointer();
        const Contour c = decodeContour(words[childRank(descriptor.contourMask(), slot)]);
        // Slab |n.(x - centre)/size - position| <= thickness/2 along x = o + t d, with n.(centre - o)
        // = sum n_i d_i t_center_i (t_center_i is where the ray crosses the centre plane of axis i).
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
      if (t_min <= tv_max) {
        const ChildDescriptor* child = nullptr;
        if (nonLeafMask >> slot & 1) {
          const ChildDescriptor* run = parent + descriptor.childPointer();
          if (descriptor.far()) run += *reinterpret_cast<const std::int32_t*>(run);
          child = followLink(run + childRank(nonLeafMask, slot));
        }
        // A leaf, or (in a block pool) a voxel whose children are not resident: this is the hit.
        if (!child || child->isStub()) {
          found = true;
          hit.leaf = true;
          break;
        }
        // PUSH
        // Fig. 15 stores the parent only when the child ends before it (tc_max < h). At the deepest scales
        // the two exits can round to the same float while the position bits still say the ray left the
        // child first, and POP would then read a stale or unwritten entry: store on every PUSH.
        stack[scale] = {parent, t_max};
        hit.pathParent[scale] = parent;
        hit.pathSlot[scale] = std::uint8_t(slot);
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
  hit.iterations = iterations;
  if (!found) return hit;

  // Undo the mirroring and clamp the hit position into the voxel's cube (sec. 6.1).
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
    hit.position[i] =
        std::min(std::max(o[i] + t_min * ray.direction[i], pos[i] + inset), pos[i] + scale_exp2 - inset);
  return hit;
}

std::uint32_t hitAttribute(const BlockView& block, const CastHit& hit, AttachmentType type) {
  const AttachmentEntry* entry = block.attachment(type);
  if (!entry || !hit.hit) return 0;
  if (auto v = BlockView::attribute(hit.parent, hit.childSlot, type)) return *v;
  for (int s = hit.scale + 1; s < kScaleMax; ++s) {
    if (auto v = BlockView::attribute(hit.pathParent[s], hit.pathSlot[s], type)) return *v;
  }
  return entry->rootValue;
}

}  // namespace svo
