// ESVO ray casting (paper sec. 6, Fig. 15). The octree occupies [1,2]^3 so that the float mantissa bits of
// a position are its path through the tree; the coordinate system is mirrored so that every direction
// component is negative; the stack of (parent, t_max) is indexed by scale; POP finds the new scale from
// the highest differing bit of the old and new position. Variable names follow the paper.
#include "svo/client/raycast.hpp"

#include <algorithm>
#include <cmath>

#include "ray_setup.hpp"

namespace svo {

using namespace ray_setup;

CastHit castRay(const BlockView& block, const OctreeRay& ray, const CastOptions& options) {
  CastHit hit;
  MirroredRay m;
  if (!mirrorRay(ray, m)) return hit;
  const glm::vec3 d = m.d;
  const float tx_coef = m.tx_coef, ty_coef = m.ty_coef, tz_coef = m.tz_coef;
  const float tx_bias = m.tx_bias, ty_bias = m.ty_bias, tz_bias = m.tz_bias;
  const int octant_mask = m.octant_mask;
  float t_min = m.t_min, t_max = m.t_max;

  struct StackEntry {
    const ChildDescriptor* parent;
    float t_max;
  } stack[kScaleMax + 1];

  const ChildDescriptor* parent = block.root();
  ChildDescriptor descriptor{};
  bool cached = false;
  std::uint8_t validMask = 0, nonLeafMask = 0;
  int idx = m.idx;
  glm::vec3 pos = m.pos;
  int scale = kScaleMax - 1;
  float scale_exp2 = 0.5f;

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
      if (options.contours && (descriptor.contourMask() >> slot & 1))
        clipToContour(contourOf(parent, descriptor, slot), d, tx_center, ty_center, tz_center, scale_exp2,
                      t_min, tv_max);
      if (t_min <= tv_max) {
        const ChildDescriptor* child = (nonLeafMask >> slot & 1) ? BlockView::child(parent, slot) : nullptr;
        // A leaf, or (in a block pool) a voxel whose children are not resident: this is the hit.
        if (!child || child->isStub()) {
          found = true;
          hit.leaf = true;
          break;
        }
        // PUSH
        prefetchBelow(child);
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

  completeHit(ray, octant_mask, pos, scale_exp2, scale, t_min, parent, idx, hit);
  return hit;
}

SiblingAttribute::SiblingAttribute(const BlockView& block, AttachmentType raw)
    : raw_(raw),
      units_(raw == AttachmentType::Color ? AttachmentType::ColorUnits : AttachmentType::NormalUnits),
      rawEntry_(block.attachment(raw)),
      // Every block of a scene (a pool's regions too) lays its attributes out alike: the root block's
      // directory says whether a parent holds units, without a look-up through its page.
      unitsEntry_(block.attachment(units_)) {}

void SiblingAttribute::select(const ChildDescriptor* parent) {
  if (parent == parent_) return;
  parent_ = parent;
  unit_ = unitsEntry_ ? BlockView::unit(parent, units_) : std::nullopt;
  own_ = !unit_ && rawEntry_ ? BlockView::attributes(parent, raw_) : BlockView::Attributes{};
  inherited_.reset();
  inheritedUnit_.reset();
  decodedMask_ = 0;
}

template <class Decode>
glm::vec3 SiblingAttribute::keptOr(int childSlot, Decode decode) {
  if (!(decodedMask_ >> childSlot & 1u)) {
    decoded_[childSlot] = decode();
    decodedMask_ |= std::uint8_t(1u << childSlot);
  }
  return decoded_[childSlot];
}

namespace {

// Up the hit's path from its parent's parent: the first value `lookup(descriptor, slot)` gives, or nullopt.
template <class Lookup>
auto firstUpThePath(const CastHit& hit, Lookup lookup) -> decltype(lookup(hit.parent, 0)) {
  for (int s = hit.scale + 1; s < kScaleMax; ++s)
    if (auto v = lookup(hit.pathParent[s], hit.pathSlot[s])) return v;
  return std::nullopt;
}

}  // namespace

template <class Decode>
glm::vec3 SiblingAttribute::inheritedFromUnits(const CastHit& hit, Decode decode, glm::vec3 root) {
  if (!inheritedUnit_)
    inheritedUnit_ = firstUpThePath(hit, [&](const ChildDescriptor* d, int slot) -> std::optional<glm::vec3> {
                       if (const auto unit = BlockView::unit(d, units_)) return decode(*unit, slot);
                       return std::nullopt;
                     }).value_or(root);
  return *inheritedUnit_;
}

void SiblingAttribute::prefetch(const CastHit& hit) const {
  if (!hit.hit) return;
  if (unitsEntry_) {
    if (const auto unit = BlockView::unit(hit.parent, units_)) __builtin_prefetch(unit->words);
  } else if (rawEntry_) {
    const BlockView::Attributes own = BlockView::attributes(hit.parent, raw_);
    if (own.mask >> hit.childSlot & 1u) __builtin_prefetch(own.values + childRank(own.mask, hit.childSlot));
  }
}

std::uint32_t SiblingAttribute::value(const CastHit& hit) {
  if (!rawEntry_ || !hit.hit) return 0;
  select(hit.parent);
  if (const auto own = own_.at(hit.childSlot)) return *own;
  if (!inherited_)
    inherited_ = firstUpThePath(hit, [&](const ChildDescriptor* d, int slot) {
                   return BlockView::attribute(d, slot, raw_);
                 }).value_or(rawEntry_->rootValue);
  return *inherited_;
}

glm::vec3 SiblingAttribute::lookUpColor(const CastHit& hit) {
  select(hit.parent);
  return keptOr(hit.childSlot, [&] {
    const auto decode = [](const BlockView::UnitHalf& unit, int slot) {
      return glm::vec3(decodeColor(unit.color(slot)));
    };
    if (unit_) return decode(*unit_, hit.childSlot);
    if (unitsEntry_) return inheritedFromUnits(hit, decode, glm::vec3(decodeColor(unitsEntry_->rootValue)));
    return glm::vec3(decodeColor(value(hit)));
  });
}

glm::vec3 SiblingAttribute::lookUpNormal(const CastHit& hit) {
  select(hit.parent);
  return keptOr(hit.childSlot, [&] {
    const auto decode = [](const BlockView::UnitHalf& unit, int slot) { return unit.normal(slot); };
    if (unit_) return decode(*unit_, hit.childSlot);
    if (unitsEntry_) return inheritedFromUnits(hit, decode, decodeNormal(unitsEntry_->rootValue));
    return decodeNormal(value(hit));
  });
}

glm::vec3 hitColor(const BlockView& block, const CastHit& hit) {
  return SiblingAttribute(block, AttachmentType::Color).color(hit);
}

glm::vec3 hitNormal(const BlockView& block, const CastHit& hit) {
  return SiblingAttribute(block, AttachmentType::Normal).normal(hit);
}

std::uint32_t hitAttribute(const BlockView& block, const CastHit& hit, AttachmentType type) {
  return SiblingAttribute(block, type).value(hit);
}

}  // namespace svo
