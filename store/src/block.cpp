#include "svo/store/block.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <stdexcept>
#include <string>

#include <sys/mman.h>

#include <glm/geometric.hpp>

namespace svo {
namespace {

// x86-64's transparent huge page: arenas of at least this size start on one and ask for them.
constexpr std::size_t kHugePageBytes = std::size_t(2) << 20;

}  // namespace

// ---------------------------------------------------------------------------------------------------------
AlignedBytes::AlignedBytes(std::size_t size, bool zeroed) {
  const std::size_t rounded =
      std::max<std::size_t>(kPageBytes, (size + kPageBytes - 1) / kPageBytes * kPageBytes);
  // A large arena (a block pool) starts on a huge page and asks the OS to back it with huge pages: a ray's
  // descent reads a few words from each of many pages, and 4 KB pages make most of those reads a TLB miss.
  // Embree asks the same for its BVH.
  const bool huge = rounded >= kHugePageBytes;
  void* p = nullptr;
  if (posix_memalign(&p, huge ? kHugePageBytes : kPageBytes, rounded) != 0) throw std::bad_alloc();
  if (huge) ::madvise(p, rounded, MADV_HUGEPAGE);  // a hint: where the OS declines, 4 KB pages serve
  if (zeroed) std::memset(p, 0, rounded);
  data_.reset(static_cast<std::byte*>(p));
  size_ = rounded;
}
void AlignedBytes::Free::operator()(std::byte* p) const {
  std::free(p);
}

// ---------------------------------------------------------------------------------------------------------
namespace {

template <class T>
const T* at(const void* p, std::ptrdiff_t bytes) {
  return reinterpret_cast<const T*>(static_cast<const std::byte*>(p) + bytes);
}
bool isPageHeaderSlot(std::uint64_t slot) {
  return slot % kSlotsPerPage == 0;
}

[[noreturn]] void corrupt(const std::string& what) {
  throw std::runtime_error("corrupt block: " + what);
}

// Each directory entry's first unit follows the units of the entries before it, and they hold `count`.
void checkUnitDirectory(const std::uint32_t* directory, std::uint64_t pairs, std::uint64_t count) {
  std::uint64_t units = 0;
  for (std::uint64_t group = 0; group * kUnitGroup < pairs; ++group) {
    const std::uint32_t mask = directory[2 * group], first = directory[2 * group + 1];
    const std::uint64_t inGroup = std::min<std::uint64_t>(kUnitGroup, pairs - group * kUnitGroup);
    if (first != units || (inGroup < kUnitGroup && mask >> inGroup != 0))
      corrupt("unit directory entry " + std::to_string(group) + " disagrees with the units before it");
    units += std::uint64_t(std::popcount(mask));
  }
  if (units != count)
    corrupt("unit directory holds " + std::to_string(units) + " units, not " + std::to_string(count));
}

// Each exact normal unit's values (attribute_units.hpp) lie behind the attachment's `count` units and within
// the `blockWords` words from the first unit to the block's end.
void checkExactNormalUnits(const std::uint32_t* units, std::uint64_t count, std::uint64_t blockWords) {
  for (std::uint64_t u = 0; u < count; ++u) {
    const std::uint32_t* unit = units + u * kNormalUnitWords;
    if (unit[1] != kExactNormalAxes) continue;
    const std::uint64_t first = u * kNormalUnitWords + unit[0], held = std::popcount(unit[2]);
    if (unit[2] >> kUnitSlots != 0 || held == 0 || first < count * kNormalUnitWords ||
        first + held > blockWords)
      corrupt("exact normal unit " + std::to_string(u) + " points outside the attachment's values");
  }
}

}  // namespace

std::optional<std::uint32_t> BlockView::contour(const ChildDescriptor* parent, int slot) {
  const std::uint8_t mask = parent->contourMask();
  if (!(mask >> slot & 1u)) return std::nullopt;
  const auto* words = at<std::uint32_t>(parent, std::ptrdiff_t(parent->contourPointer()) * 4);
  return words[childRank(mask, slot)];
}

std::optional<BlockView::UnitHalf> BlockView::unit(const ChildDescriptor* parent, AttachmentType type) {
  const BlockInfo& info = infoOf(parent);
  const std::uint32_t* directory = attachmentOf(info, type);
  if (!directory) return std::nullopt;
  const std::ptrdiff_t index = slotIndexOf(parent, info);
  const auto pair = std::uint32_t(index / 2);
  const std::uint32_t* entry = directory + 2 * (pair / kUnitGroup);
  const std::uint32_t bit = pair % kUnitGroup;
  if (!(entry[0] >> bit & 1u)) return std::nullopt;
  const std::uint32_t rank = entry[1] + std::uint32_t(std::popcount(entry[0] & ((1u << bit) - 1u)));
  const std::ptrdiff_t unitWords = type == AttachmentType::ColorUnits ? kColorUnitWords : kNormalUnitWords;
  return UnitHalf{directory + unitDirectoryWords(info.slotCount) + rank * unitWords, int(index % 2)};
}

const AttachmentEntry* BlockView::attachment(AttachmentType type) const {
  const auto* entries = reinterpret_cast<const AttachmentEntry*>(info_ + 1);
  for (std::uint32_t a = 0; a < info_->attachmentCount; ++a)
    if (entries[a].type == type) return &entries[a];
  return nullptr;
}
AttributeLayout BlockView::attributeLayout() const {
  return attachment(AttachmentType::ColorUnits) || attachment(AttachmentType::NormalUnits)
             ? AttributeLayout::Compressed
             : AttributeLayout::Raw;
}
bool BlockView::hasColors() const {
  return attachment(AttachmentType::Color) || attachment(AttachmentType::ColorUnits);
}
bool BlockView::hasNormals() const {
  return attachment(AttachmentType::Normal) || attachment(AttachmentType::NormalUnits);
}

namespace {

// Walks every descriptor reachable from the root and checks each pointer lands inside its section. Child
// runs always lie after their parent, so the walk ends even on hostile input.
void validatePointers(const BlockView& view) {
  const BlockInfo& info = view.info();
  const std::byte* base = view.base();
  const auto* infoBytes = reinterpret_cast<const std::byte*>(&info);
  const std::size_t infoOffset = std::size_t(infoBytes - base);
  const std::size_t contourBegin =
      infoOffset + sizeof(BlockInfo) + info.attachmentCount * sizeof(AttachmentEntry);
  const std::size_t contourEnd = contourBegin + std::size_t(info.contourCount) * 4;
  struct Item {
    std::uint32_t slot;
    int depth;
  };
  std::vector<Item> stack{{info.rootSlot, 0}};
  while (!stack.empty()) {
    const Item item = stack.back();
    stack.pop_back();
    const ChildDescriptor& d = view.slots()[item.slot];
    const std::uint8_t valid = d.validMask(), leaf = d.leafMask(), nonLeaf = d.nonLeafMask();
    if (d.isStub() && d.topology == 0 && d.contour == 0) continue;  // children not resident (paging)
    if (d.isLink()) {
      // A descriptor laid out apart (the compressed layout), always after the run that links to it.
      const std::int64_t target = std::int64_t(item.slot) + d.linkOffset();
      if (d.linkOffset() <= 0 || target >= std::int64_t(info.slotCount) ||
          isPageHeaderSlot(std::uint64_t(target)))
        corrupt("link out of range at slot " + std::to_string(item.slot));
      stack.push_back({std::uint32_t(target), item.depth});
      continue;
    }
    if (valid == 0) corrupt("descriptor at slot " + std::to_string(item.slot) + " has no children");
    if ((leaf & ~valid) != 0) corrupt("leaf mask outside valid mask at slot " + std::to_string(item.slot));
    if ((d.contourMask() & ~valid) != 0)
      corrupt("contour mask outside valid mask at slot " + std::to_string(item.slot));
    if (d.contourMask() != 0) {
      const std::size_t begin = std::size_t(item.slot) * kSlotBytes + std::size_t(d.contourPointer()) * 4;
      const std::size_t end = begin + std::size_t(std::popcount(unsigned(d.contourMask()))) * 4;
      if (begin < contourBegin || end > contourEnd)
        corrupt("contour pointer out of range at slot " + std::to_string(item.slot));
    }
    for (AttachmentType type : {AttachmentType::Color, AttachmentType::Normal}) {
      const AttachmentEntry* e = view.attachment(type);
      if (!e) continue;
      const auto* words = at<std::uint32_t>(&info, std::ptrdiff_t(e->pointer) * 4);
      const AttributeLookup lookup{words[item.slot]};
      if ((lookup.mask() & ~valid) != 0)
        corrupt("attribute mask outside valid mask at slot " + std::to_string(item.slot));
      const std::uint64_t end = std::uint64_t(lookup.valuePointer()) + std::popcount(unsigned(lookup.mask()));
      if (lookup.mask() && (lookup.valuePointer() < info.slotCount || end > info.slotCount + e->valueCount))
        corrupt("attribute pointer out of range at slot " + std::to_string(item.slot));
    }
    if (nonLeaf == 0) continue;
    if (item.depth + 1 >= kMaxLevels) corrupt("tree deeper than " + std::to_string(kMaxLevels) + " levels");
    std::uint64_t run = std::uint64_t(item.slot) + d.childPointer();
    if (d.childPointer() == 0) corrupt("null child pointer at slot " + std::to_string(item.slot));
    if (d.far()) {
      if (run >= info.slotCount || isPageHeaderSlot(run))
        corrupt("far slot out of range at slot " + std::to_string(item.slot));
      const std::int64_t offset = *reinterpret_cast<const std::int32_t*>(view.slots() + run);
      if (offset <= 0) corrupt("far pointer does not point forward at slot " + std::to_string(item.slot));
      run += std::uint64_t(offset);
    }
    const int count = std::popcount(unsigned(nonLeaf));
    for (int k = 0; k < count; ++k) {
      const std::uint64_t s = run + std::uint64_t(k);
      if (s >= info.slotCount || isPageHeaderSlot(s))
        corrupt("child run out of range at slot " + std::to_string(item.slot));
      stack.push_back({std::uint32_t(s), item.depth + 1});
    }
  }
}

}  // namespace

BlockView::BlockView(const std::byte* data, std::size_t size) : base_(data), size_(size) {
  if (reinterpret_cast<std::uintptr_t>(data) % kPageBytes != 0) corrupt("not 8 KB aligned");
  if (size < kPageBytes || size % kPageBytes != 0)
    corrupt("size " + std::to_string(size) + " is not a whole number of pages");
  const std::int64_t infoOffset = std::int64_t(*reinterpret_cast<const std::int32_t*>(data)) * 4;
  if (infoOffset <= 0 || std::uint64_t(infoOffset) + sizeof(BlockInfo) > size)
    corrupt("page header points outside the block");
  info_ = at<BlockInfo>(data, infoOffset);
  const BlockInfo& info = *info_;
  if (info.magic != kBlockInfoMagic) corrupt("bad info-section magic");
  if (std::int64_t(info.slotsPointer) * 4 != -infoOffset)
    corrupt("info section does not point back to slot 0");
  if (std::uint64_t(info.slotCount) * kSlotBytes > std::uint64_t(infoOffset))
    corrupt("slot array overlaps the info section");
  if (info.rootSlot == 0 || info.rootSlot >= info.slotCount || isPageHeaderSlot(info.rootSlot))
    corrupt("bad root slot");
  const std::uint64_t directoryEnd = std::uint64_t(infoOffset) + sizeof(BlockInfo) +
                                     std::uint64_t(info.attachmentCount) * sizeof(AttachmentEntry);
  if (info.attachmentCount > 16 || directoryEnd + std::uint64_t(info.contourCount) * 4 > size)
    corrupt("info section or contour data runs past the end");
  for (std::uint64_t page = 0; page * kSlotsPerPage < info.slotCount; ++page) {
    const std::int64_t header = *at<std::int32_t>(data, std::ptrdiff_t(page * kPageBytes));
    if (std::int64_t(page * kPageBytes) + header * 4 != infoOffset)
      corrupt("page header " + std::to_string(page) + " does not lead to the info section");
  }
  const auto* entries = reinterpret_cast<const AttachmentEntry*>(info_ + 1);
  for (std::uint32_t a = 0; a < info.attachmentCount; ++a) {
    const std::int64_t begin = infoOffset + std::int64_t(entries[a].pointer) * 4;
    const std::uint64_t count = entries[a].valueCount, pairs = (std::uint64_t(info.slotCount) + 1) / 2;
    std::uint64_t words = 0;
    switch (entries[a].type) {
      case AttachmentType::Color:
      case AttachmentType::Normal:
        words = std::uint64_t(info.slotCount) + count;
        break;
      case AttachmentType::ColorUnits:
        words = unitDirectoryWords(info.slotCount) + count * kColorUnitWords;
        break;
      case AttachmentType::NormalUnits:
        words = unitDirectoryWords(info.slotCount) + count * kNormalUnitWords;
        break;
      case AttachmentType::ExactColors:
        words = count;
        break;
      case AttachmentType::ExactNormals:
        words = (count + 1) / 2;
        break;
      default:
        corrupt("unknown attachment type");
    }
    const bool isUnits =
        entries[a].type == AttachmentType::ColorUnits || entries[a].type == AttachmentType::NormalUnits;
    if (begin < std::int64_t(directoryEnd) || std::uint64_t(begin) + words * 4 > size)
      corrupt("attachment runs past the end");
    if (isUnits) checkUnitDirectory(at<std::uint32_t>(data, begin), pairs, count);
    if (entries[a].type == AttachmentType::NormalUnits) {
      const std::uint64_t unitsBegin = std::uint64_t(begin) + unitDirectoryWords(info.slotCount) * 4;
      checkExactNormalUnits(at<std::uint32_t>(data, std::ptrdiff_t(unitsBegin)), count,
                            (size - unitsBegin) / 4);
    }
  }
  const bool raw = attachment(AttachmentType::Color) || attachment(AttachmentType::Normal);
  if (raw && attributeLayout() == AttributeLayout::Compressed) corrupt("both attribute layouts in one block");
  validatePointers(*this);
}

BlockView BlockView::unchecked(const std::byte* data, std::size_t size) {
  BlockView view;
  view.base_ = data;
  view.size_ = size;
  view.info_ = at<BlockInfo>(data, std::ptrdiff_t(*reinterpret_cast<const std::int32_t*>(data)) * 4);
  return view;
}

// Only layoutBlock makes blocks: their pointers hold by construction, and checking them again cost the pager
// a tenth of its layout time. The block tests check layout output with the validating BlockView.
Block::Block(AlignedBytes bytes)
    : bytes_(std::move(bytes)), view_(BlockView::unchecked(bytes_.data(), bytes_.size())) {}

std::uint32_t BlockView::UnitHalf::color(int childSlot) const {
  ColorUnit unit;
  std::memcpy(unit.words.data(), words, sizeof(unit.words));
  return decodeColorUnit(unit, half * 8 + childSlot);
}
glm::vec3 BlockView::UnitHalf::normal(int childSlot) const {
  NormalUnit unit;
  std::memcpy(unit.words.data(), words, sizeof(unit.words));
  const int slot = half * 8 + childSlot;
  return isExact(unit) ? decodeNormal(exactNormalBits(words, slot)) : decodeNormalUnit(unit, slot);
}

VoxelTree readBlock(const BlockView& block) {
  VoxelTree tree;
  const bool compressed = block.attributeLayout() == AttributeLayout::Compressed;
  const AttachmentType colorType = compressed ? AttachmentType::ColorUnits : AttachmentType::Color;
  const AttachmentType normalType = compressed ? AttachmentType::NormalUnits : AttachmentType::Normal;
  tree.hasColors = block.attachment(colorType) != nullptr;
  tree.hasNormals = block.attachment(normalType) != nullptr;
  VoxelRecord root;
  if (tree.hasColors) root.color = block.attachment(colorType)->rootValue;
  if (tree.hasNormals) root.normal = block.attachment(normalType)->rootValue;
  tree.voxels.push_back(root);
  // Breadth first: record i's children are appended contiguously when i is visited.
  std::deque<const ChildDescriptor*> descriptorOf{block.root()};
  for (std::size_t i = 0; i < tree.voxels.size(); ++i) {
    const ChildDescriptor* d = descriptorOf[i];
    if (!d) continue;
    const VoxelRecord parent = tree.voxels[i];
    tree.voxels[i].childMask = d->validMask();
    tree.voxels[i].stub = d->isStub();
    tree.voxels[i].firstChild = std::uint32_t(tree.voxels.size());
    const BlockView::Attributes colors =
        compressed ? BlockView::Attributes{} : BlockView::attributes(d, colorType);
    const BlockView::Attributes normals =
        compressed ? BlockView::Attributes{} : BlockView::attributes(d, normalType);
    const auto colorUnit = compressed ? BlockView::unit(d, colorType) : std::nullopt;
    const auto normalUnit = compressed ? BlockView::unit(d, normalType) : std::nullopt;
    for (int slot = 0; slot < 8; ++slot) {
      if (!(d->validMask() >> slot & 1u)) continue;
      VoxelRecord c;
      if (auto contour = BlockView::contour(d, slot)) c.hasContour = true, c.contour = *contour;
      // Read back in the uncompressed encodings: ABGR, and the cube encoding of the decoded normal.
      c.color = colorUnit ? colorUnit->color(slot) : colors.at(slot).value_or(parent.color);
      c.normal =
          normalUnit ? encodeNormal(normalUnit->normal(slot)) : normals.at(slot).value_or(parent.normal);
      tree.voxels.push_back(c);
      descriptorOf.push_back((d->leafMask() >> slot & 1u) ? nullptr : BlockView::child(d, slot));
    }
  }
  return tree;
}

}  // namespace svo
