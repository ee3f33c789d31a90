// ESVO ray casting (paper sec. 6, Fig. 15). The octree occupies [1,2]^3 so that the float mantissa bits of
// a position are its path through the tree; the coordinate system is mirrored so that every direction
// component is negative; the stack of (parent, t_max) is indexed by scale; POP finds the new scale from
// the highest differing bit of the old and new position. Variable names follow the paper. The loop is
// continueRay (ray_setup.hpp), which the packet loop shares.
#include "svo/client/raycast.hpp"

#include <algorithm>
#include <bit>
#include <cmath>

#include "ray_setup.hpp"

namespace svo {

using namespace ray_setup;

CastHit castRay(const BlockView& block, const OctreeRay& ray, const CastOptions& options) {
  CastHit hit;
  castFromRoot(block.root(), ray, options, hit);
  return hit;
}

namespace {

// The compressed layout's attachment for raw attachment Color or Normal.
AttachmentType unitsOf(AttachmentType raw) {
  return raw == AttachmentType::Color ? AttachmentType::ColorUnits : AttachmentType::NormalUnits;
}

}  // namespace

SiblingAttribute::SiblingAttribute(const BlockView& block, AttachmentType raw)
    : raw_(raw),
      units_(unitsOf(raw)),
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

// The raw value a hit voxel without its own shows: its nearest ancestor's up the path, else `rootValue`.
std::uint32_t inheritedValue(const CastHit& hit, AttachmentType type, std::uint32_t rootValue) {
  return firstUpThePath(hit, [&](const ChildDescriptor* d,
                                 int slot) { return BlockView::attributes(d, type).shown(slot); })
      .value_or(rootValue);
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

namespace {

bool isUnits(AttachmentType type) {
  return type == AttachmentType::ColorUnits || type == AttachmentType::NormalUnits;
}

void prefetchPageHeader(const ChildDescriptor* descriptor) {
  __builtin_prefetch(reinterpret_cast<const void*>(reinterpret_cast<std::uintptr_t>(descriptor) &
                                                   ~std::uintptr_t(kPageBytes - 1)));
}

}  // namespace

AttributePrefetcher::AttributePrefetcher(const BlockView& block) {
  for (const AttachmentType raw : {AttachmentType::Color, AttachmentType::Normal}) {
    if (block.attachment(unitsOf(raw))) {
      types_[typeCount_++] = unitsOf(raw);
    } else if (block.attachment(raw)) {
      types_[typeCount_++] = raw;
    }
  }
}

bool AttributePrefetcher::LookUp::step(const AttachmentType* typeOf) {
  if (!requested) {  // the page header is in
    const BlockInfo& info = BlockView::infoOf(descriptor);
    const std::ptrdiff_t index = BlockView::slotIndexOf(descriptor, info);
    for (unsigned left = types; left != 0; left &= left - 1) {
      const int t = std::countr_zero(left);
      const std::uint32_t* attachment = BlockView::attachmentOf(info, typeOf[t]);
      if (!attachment) {
        types &= std::uint8_t(~(1u << t));
        continue;
      }
      __builtin_prefetch(isUnits(typeOf[t]) ? attachment + 2 * (index / 2 / kUnitGroup) : attachment + index);
    }
    requested = true;
    return types != 0;
  }
  for (unsigned left = types; left != 0; left &= left - 1) {
    const int t = std::countr_zero(left);
    const AttachmentType type = typeOf[t];
    bool inherits;  // the children asked for show an ancestor's value
    if (isUnits(type)) {
      const auto unit = BlockView::unit(descriptor, type);
      if (unit) __builtin_prefetch(unit->words);
      inherits = !unit;
    } else {
      const BlockView::Attributes own = BlockView::attributes(descriptor, type);
      if (own.mask & slots) __builtin_prefetch(own.values);
      if (own.shownByAll) __builtin_prefetch(own.shownByAll);  // the entry says what the children show
      inherits = !own.shownByAll && (slots & ~own.mask) != 0;
    }
    if (!inherits) types &= std::uint8_t(~(1u << t));
  }
  if (types == 0 || ++scale >= kScaleMax) return false;
  descriptor = hit->pathParent[scale];
  slots = std::uint8_t(1u << hit->pathSlot[scale]);
  requested = false;
  prefetchPageHeader(descriptor);
  return true;
}

void AttributePrefetcher::packet(const CastHit* hits, int count) {
  if (typeCount_ == 0) return;
  // The ring's oldest packet is shaded next: its slot takes the new one.
  newest_ = (newest_ + 1) % kLag;
  Packet& added = packets_[newest_];
  added.count = 0;
  const auto allTypes = std::uint8_t((1u << typeCount_) - 1);
  for (int i = 0; i < count; ++i) {
    const CastHit& h = hits[i];
    if (!h.hit) continue;
    const auto slot = std::uint8_t(1u << h.childSlot);
    if (added.count > 0 && added.lookUps[added.count - 1].hit->parent == h.parent) {
      added.lookUps[added.count - 1].slots |= slot;
      continue;
    }
    prefetchPageHeader(h.parent);
    added.lookUps[added.count++] = LookUp{&h, h.parent, slot, allTypes, std::int8_t(h.scale)};
  }
  for (int k = 1; k < kLag; ++k) {
    Packet& older = packets_[(newest_ + kLag - k) % kLag];
    int active = 0;
    for (int c = 0; c < older.count; ++c)
      if (older.lookUps[c].step(types_)) older.lookUps[active++] = older.lookUps[c];
    older.count = active;
  }
}

std::uint32_t SiblingAttribute::value(const CastHit& hit) {
  if (!rawEntry_ || !hit.hit) return 0;
  select(hit.parent);
  if (const auto shown = own_.shown(hit.childSlot)) return *shown;
  if (!inherited_) inherited_ = inheritedValue(hit, raw_, rawEntry_->rootValue);
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

RawAttributePair::RawAttributePair(const BlockView& block)
    : types_{{AttachmentType::Color, block.attachment(AttachmentType::Color)},
             {AttachmentType::Normal, block.attachment(AttachmentType::Normal)}} {}

void RawAttributePair::select(const ChildDescriptor* parent) {
  parent_ = parent;
  const BlockInfo& info = BlockView::infoOf(parent);
  if (&info != info_) {
    info_ = &info;
    for (Attribute& a : types_) {
      a.entry = a.sceneEntry ? BlockView::entryOf(info, a.type) : nullptr;
      a.words = a.entry ? BlockView::startOf(info, *a.entry) : nullptr;
    }
  }
  const std::ptrdiff_t index = BlockView::slotIndexOf(parent, info);
  for (Attribute& a : types_) {
    a.own = a.words ? BlockView::attributesOf(*a.entry, a.words, a.words[index]) : BlockView::Attributes{};
    a.inherited.reset();
  }
}

std::uint32_t RawAttributePair::inherited(Attribute& a, const CastHit& hit) {
  if (!a.inherited) a.inherited = inheritedValue(hit, a.type, a.sceneEntry->rootValue);
  return *a.inherited;
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
