#include "svo/store/block.hpp"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <memory>
#include <stdexcept>
#include <string>

#include <glm/geometric.hpp>

namespace svo {

// ---------------------------------------------------------------------------------------------------------
AlignedBytes::AlignedBytes(std::size_t size, bool zeroed) {
  const std::size_t rounded =
      std::max<std::size_t>(kPageBytes, (size + kPageBytes - 1) / kPageBytes * kPageBytes);
  auto* p = static_cast<std::byte*>(std::aligned_alloc(kPageBytes, rounded));
  if (!p) throw std::bad_alloc();
  if (zeroed) std::memset(p, 0, rounded);
  data_.reset(p);
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
std::int32_t pageHeader(const void* descriptor) {
  const auto page = reinterpret_cast<std::uintptr_t>(descriptor) & ~std::uintptr_t(kPageBytes - 1);
  return *reinterpret_cast<const std::int32_t*>(page);
}
bool isPageHeaderSlot(std::uint64_t slot) {
  return slot % kSlotsPerPage == 0;
}

[[noreturn]] void corrupt(const std::string& what) {
  throw std::runtime_error("corrupt block: " + what);
}

}  // namespace

const BlockInfo& BlockView::infoOf(const ChildDescriptor* descriptor) {
  const auto page = reinterpret_cast<std::uintptr_t>(descriptor) & ~std::uintptr_t(kPageBytes - 1);
  return *at<BlockInfo>(reinterpret_cast<const void*>(page), std::ptrdiff_t(pageHeader(descriptor)) * 4);
}

const ChildDescriptor* BlockView::child(const ChildDescriptor* parent, int slot) {
  const std::uint32_t pointer = parent->childPointer();
  const ChildDescriptor* run = parent + pointer;
  if (parent->far()) run += *reinterpret_cast<const std::int32_t*>(run);
  return followLink(run + childRank(parent->nonLeafMask(), slot));
}

std::optional<std::uint32_t> BlockView::contour(const ChildDescriptor* parent, int slot) {
  const std::uint8_t mask = parent->contourMask();
  if (!(mask >> slot & 1u)) return std::nullopt;
  const auto* words = at<std::uint32_t>(parent, std::ptrdiff_t(parent->contourPointer()) * 4);
  return words[childRank(mask, slot)];
}

std::optional<std::uint32_t> BlockView::attribute(const ChildDescriptor* parent, int slot,
                                                  AttachmentType type) {
  return attributes(parent, type).at(slot);
}

BlockView::Attributes BlockView::attributes(const ChildDescriptor* parent, AttachmentType type) {
  // Paper Fig. 8: page header -> info section -> attachment directory -> lookup entry -> values.
  const BlockInfo& info = infoOf(parent);
  const auto* entries = reinterpret_cast<const AttachmentEntry*>(&info + 1);
  const auto* slots = at<ChildDescriptor>(&info, std::ptrdiff_t(info.slotsPointer) * 4);
  const std::ptrdiff_t index = parent - slots;
  for (std::uint32_t a = 0; a < info.attachmentCount; ++a) {
    if (entries[a].type != type) continue;
    const auto* attachment = at<std::uint32_t>(&info, std::ptrdiff_t(entries[a].pointer) * 4);
    const AttributeLookup lookup{attachment[index]};
    return {lookup.mask(), attachment + lookup.valuePointer()};
  }
  return {};
}

const AttachmentEntry* BlockView::attachment(AttachmentType type) const {
  const auto* entries = reinterpret_cast<const AttachmentEntry*>(info_ + 1);
  for (std::uint32_t a = 0; a < info_->attachmentCount; ++a)
    if (entries[a].type == type) return &entries[a];
  return nullptr;
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
    const std::uint64_t words = std::uint64_t(info.slotCount) + entries[a].valueCount;
    if (begin < std::int64_t(directoryEnd) || std::uint64_t(begin) + words * 4 > size)
      corrupt("attachment runs past the end");
    if (entries[a].type != AttachmentType::Color && entries[a].type != AttachmentType::Normal)
      corrupt("unknown attachment type");
  }
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

// ---------------------------------------------------------------------------------------------------------
// Layout.
InheritanceRule::InheritanceRule(const LayoutOptions& options)
    : colorSteps_(options.colorInheritSteps),
      normalCos_(std::cos(options.normalInheritDegrees * 3.14159265f / 180.0f)),
      equalOnly_(options.inheritEqualOnly) {}

bool InheritanceRule::color(std::uint32_t a, std::uint32_t b) const {
  if (equalOnly_) return a == b;
  for (int shift = 0; shift < 32; shift += 8)
    if (std::abs(int((a >> shift) & 255u) - int((b >> shift) & 255u)) > colorSteps_) return false;
  return true;
}
InheritanceRule::ParentNormal InheritanceRule::parentNormal(std::uint32_t parentEffective) const {
  if (equalOnly_) return {parentEffective, glm::vec3(0.0f), 0.0f};  // normal() compares the bits alone
  const glm::vec3 q = normalDirection(parentEffective);
  return {parentEffective, q, glm::dot(q, q)};
}
bool InheritanceRule::normal(std::uint32_t a, const ParentNormal& parent) const {
  if (a == parent.bits) return true;
  if (equalOnly_) return false;
  // The angle's cosine against the threshold without normalizing either: one square root, not two
  // normalizations (this test runs per voxel in every layout).
  const glm::vec3 p = normalDirection(a);
  return glm::dot(p, parent.direction) >= normalCos_ * std::sqrt(glm::dot(p, p) * parent.lengthSquared);
}

namespace {

struct SlotPlan {
  std::vector<std::uint32_t> slotOf;     // voxel -> its descriptor slot (non-leaf voxels)
  std::vector<std::uint32_t> runOf;      // voxel -> first slot of its non-leaf children's run
  std::vector<std::uint32_t> farSlotOf;  // voxel -> its far slot, or 0
  std::uint32_t slotCount = 0;
};

// One layout pass for a given set of far voxels. A voxel's far flag is read once, when its parent's run is
// reserved, before the voxel's own run is: so the pass marks the voxels whose run it puts out of reach as it
// goes, without changing its own outcome, and the caller repeats it until it marks none.
class SlotPlanner {
 public:
  SlotPlanner(const VoxelTree& tree, std::vector<std::uint8_t>& needsFar, std::uint32_t maxNearPointer)
      : tree_(tree), needsFar_(needsFar), maxNearPointer_(maxNearPointer) {}

  SlotPlan plan() {
    const std::size_t n = tree_.voxels.size();
    plan_.slotOf.assign(n, 0);
    plan_.runOf.assign(n, 0);
    plan_.farSlotOf.assign(n, 0);
    next_ = 1;  // slot 0 is the first page header
    plan_.slotOf[0] = next_++;
    place(0);
    plan_.slotCount = next_;
    return std::move(plan_);
  }
  // Voxels this pass found out of reach, now marked far.
  std::uint32_t newlyFar() const { return newlyFar_; }

 private:
  bool isNonLeaf(std::uint32_t v) const { return tree_.voxels[v].childMask != 0 || tree_.voxels[v].stub; }

  // Reserves `count` consecutive slots inside one page (a run must not straddle a page header).
  std::uint32_t reserve(std::uint32_t count) {
    const std::uint32_t pageEnd = (next_ / kSlotsPerPage + 1) * kSlotsPerPage;
    if (isPageHeaderSlot(next_)) {
      ++next_;
    } else if (next_ + count > pageEnd) {
      next_ = pageEnd + 1;  // skip the rest of the page and the next page header
    }
    const std::uint32_t first = next_;
    next_ += count;
    return first;
  }

  // Depth first: the run of v's non-leaf children (followed by their far slots), then each child's subtree.
  void place(std::uint32_t v) {
    const VoxelRecord& r = tree_.voxels[v];
    std::uint32_t children[8], count = 0, farCount = 0;
    for (std::uint32_t mask = r.childMask, c = r.firstChild; mask; mask &= mask - 1, ++c) {
      if (isNonLeaf(c)) {
        children[count++] = c;
        farCount += needsFar_[c];
      }
    }
    if (count == 0) return;
    const std::uint32_t first = reserve(count + farCount);
    plan_.runOf[v] = first;
    if (!needsFar_[v] && first - plan_.slotOf[v] > maxNearPointer_) needsFar_[v] = 1, ++newlyFar_;
    std::uint32_t farSlot = first + count;
    for (std::uint32_t k = 0; k < count; ++k) {
      plan_.slotOf[children[k]] = first + k;
      if (needsFar_[children[k]]) plan_.farSlotOf[children[k]] = farSlot++;
    }
    for (std::uint32_t k = 0; k < count; ++k) place(children[k]);
  }

  const VoxelTree& tree_;
  std::vector<std::uint8_t>& needsFar_;
  const std::uint32_t maxNearPointer_;
  SlotPlan plan_;
  std::uint32_t next_ = 0, newlyFar_ = 0;
};

}  // namespace

Block layoutBlock(const VoxelTree& tree, const LayoutOptions& options, LayoutStats* statsOut,
                  std::vector<std::uint32_t>* descriptorSlot) {
  if (tree.voxels.empty() || tree.voxels[0].childMask == 0)
    throw std::invalid_argument("layoutBlock: the tree has no voxels below the root");
  // A run of 8 descriptors followed by up to 8 far slots must stay in reach of its own descriptors.
  if (options.maxNearPointer < 16 || options.maxNearPointer > kMaxNearPointer)
    throw std::invalid_argument("layoutBlock: maxNearPointer must be in [16, 32767]");
  const std::size_t n = tree.voxels.size();

  // Far pointers: lay out, mark every voxel whose run is out of reach, repeat until nothing changes. The
  // marked set only grows, so this ends; in practice after one or two extra passes.
  std::vector<std::uint8_t> needsFar(n, 0);
  SlotPlan plan;
  std::uint64_t farVoxels = 0;
  for (;;) {
    SlotPlanner planner(tree, needsFar, options.maxNearPointer);
    plan = planner.plan();
    if (planner.newlyFar() == 0) break;
    farVoxels += planner.newlyFar();
  }

  // Per non-leaf voxel: contours of its children, and which children's attributes differ from the parent's.
  // Breadth first from the root, so each child's effective (possibly inherited) value is known from its
  // parent; what the descriptors need is kept per queue entry, so the passes after this one read the voxels
  // with children in queue order and skip the leaves (three in four voxels).
  const InheritanceRule inherits(options);
  struct Queued {
    std::uint32_t voxel, color, normal;  // the voxel and its effective values
  };
  struct Entry {
    std::uint32_t contourFirst, colorFirst, normalFirst;
    std::uint8_t contourMask, colorMask, normalMask, leafMask;
  };
  std::vector<Queued> queue;
  std::vector<Entry> entries;
  queue.reserve(n / 2 + 1), entries.reserve(n / 2 + 1);
  std::vector<std::uint32_t> contours, colors, normals;
  contours.reserve(n), colors.reserve(tree.hasColors ? n : 0), normals.reserve(tree.hasNormals ? n : 0);
  LayoutStats stats;
  queue.push_back({0, tree.voxels[0].color, tree.voxels[0].normal});
  for (std::size_t qi = 0; qi < queue.size(); ++qi) {
    const Queued parent = queue[qi];
    const VoxelRecord& r = tree.voxels[parent.voxel];
    Entry& e = entries.emplace_back(Entry{std::uint32_t(contours.size()), std::uint32_t(colors.size()),
                                          std::uint32_t(normals.size()), 0, 0, 0, 0});
    const InheritanceRule::ParentNormal parentNormal =
        tree.hasNormals ? inherits.parentNormal(parent.normal) : InheritanceRule::ParentNormal{};
    // Set bits only, and only voxels with children queued.
    for (std::uint32_t mask = r.childMask, c = r.firstChild; mask; mask &= mask - 1, ++c) {
      const std::uint8_t bit = std::uint8_t(mask & (0u - mask));
      const VoxelRecord& child = tree.voxels[c];
      if (child.hasContour) contours.push_back(child.contour), e.contourMask |= bit;
      std::uint32_t color = parent.color, normal = parent.normal;
      if (tree.hasColors) {
        if (inherits.color(child.color, color)) {
          ++stats.inheritedColors;
        } else {
          colors.push_back(child.color), e.colorMask |= bit;
          color = child.color;
        }
      }
      if (tree.hasNormals) {
        if (inherits.normal(child.normal, parentNormal)) {
          ++stats.inheritedNormals;
        } else {
          normals.push_back(child.normal), e.normalMask |= bit;
          normal = child.normal;
        }
      }
      if (child.childMask != 0) {
        queue.push_back({c, color, normal});
      } else if (child.stub) {
        ++stats.descriptorSlots;  // all-zero stub descriptor and lookup entries (format.hpp)
      } else {
        e.leafMask |= bit;
      }
    }
  }

  // Byte layout: slots | info + directory | contours | attachments (lookup array + values).
  const std::uint32_t slotCount = plan.slotCount;
  const std::uint32_t attachmentCount = std::uint32_t(tree.hasColors) + std::uint32_t(tree.hasNormals);
  const std::size_t infoOffset = std::size_t(slotCount) * kSlotBytes;
  const std::size_t contourOffset =
      infoOffset + sizeof(BlockInfo) + attachmentCount * sizeof(AttachmentEntry);
  std::size_t cursor = contourOffset + contours.size() * 4;
  const std::size_t colorOffset = cursor;
  if (tree.hasColors) cursor += (std::size_t(slotCount) + colors.size()) * 4;
  const std::size_t normalOffset = cursor;
  if (tree.hasNormals) cursor += (std::size_t(slotCount) + normals.size()) * 4;
  if (cursor > std::size_t(INT32_MAX) * 4 ||
      slotCount + std::max(colors.size(), normals.size()) > kMaxWordPointer)
    throw BlockTooLarge("octree too large for one block (" + std::to_string(cursor >> 20) +
                        " MiB; its pointers reach 2^24 words): stream it through a block pool");

  AlignedBytes bytes(cursor);
  std::byte* base = bytes.data();
  auto* slots = reinterpret_cast<ChildDescriptor*>(base);
  for (std::uint32_t page = 0; std::size_t(page) * kSlotsPerPage < slotCount; ++page)
    *reinterpret_cast<std::int32_t*>(base + std::size_t(page) * kPageBytes) =
        std::int32_t((infoOffset - std::size_t(page) * kPageBytes) / 4);

  auto* info = reinterpret_cast<BlockInfo*>(base + infoOffset);
  *info = BlockInfo{kBlockInfoMagic, -std::int32_t(infoOffset / 4),  slotCount,
                    plan.slotOf[0],  std::uint32_t(contours.size()), attachmentCount};
  auto* directory = reinterpret_cast<AttachmentEntry*>(info + 1);
  if (!contours.empty()) std::memcpy(base + contourOffset, contours.data(), contours.size() * 4);
  std::uint32_t* colorWords = reinterpret_cast<std::uint32_t*>(base + colorOffset);
  std::uint32_t* normalWords = reinterpret_cast<std::uint32_t*>(base + normalOffset);
  if (tree.hasColors) {
    *directory++ = {AttachmentType::Color, std::int32_t((colorOffset - infoOffset) / 4), tree.voxels[0].color,
                    std::uint32_t(colors.size())};
    if (!colors.empty()) std::memcpy(colorWords + slotCount, colors.data(), colors.size() * 4);
  }
  if (tree.hasNormals) {
    *directory++ = {AttachmentType::Normal, std::int32_t((normalOffset - infoOffset) / 4),
                    tree.voxels[0].normal, std::uint32_t(normals.size())};
    if (!normals.empty()) std::memcpy(normalWords + slotCount, normals.data(), normals.size() * 4);
  }

  for (std::size_t qi = 0; qi < queue.size(); ++qi) {
    const std::uint32_t v = queue[qi].voxel;
    const VoxelRecord& r = tree.voxels[v];
    const std::uint32_t slot = plan.slotOf[v];
    const Entry& e = entries[qi];
    std::uint32_t pointer = 0;
    bool far = false;
    if (plan.runOf[v] != 0) {
      if (plan.farSlotOf[v] != 0) {
        far = true;
        pointer = plan.farSlotOf[v] - slot;
        *reinterpret_cast<std::int32_t*>(&slots[plan.farSlotOf[v]]) =
            std::int32_t(plan.runOf[v] - plan.farSlotOf[v]);
      } else {
        pointer = plan.runOf[v] - slot;
      }
      assert(pointer <= options.maxNearPointer);
    }
    std::uint32_t contourPointer = 0;
    if (e.contourMask) {
      const std::size_t words =
          (contourOffset + std::size_t(e.contourFirst) * 4 - std::size_t(slot) * kSlotBytes) / 4;
      if (words > kMaxWordPointer)
        throw BlockTooLarge(
            "octree too large for one block (a contour pointer is out of 24-bit reach): stream it through "
            "a block pool");
      contourPointer = std::uint32_t(words);
    }
    slots[slot] = ChildDescriptor::make(pointer, far, r.childMask, e.leafMask, contourPointer, e.contourMask);
    if (tree.hasColors) colorWords[slot] = AttributeLookup::make(slotCount + e.colorFirst, e.colorMask).bits;
    if (tree.hasNormals)
      normalWords[slot] = AttributeLookup::make(slotCount + e.normalFirst, e.normalMask).bits;
    ++stats.descriptorSlots;
  }

  stats.farSlots = farVoxels;
  stats.pageHeaderSlots = (slotCount + kSlotsPerPage - 1) / kSlotsPerPage;
  stats.paddingSlots = slotCount - stats.descriptorSlots - stats.farSlots - stats.pageHeaderSlots;
  stats.contourWords = contours.size();
  stats.colorValues = colors.size();
  stats.normalValues = normals.size();
  // As the paper counts (sec. 5.6): a slot's first word is hierarchy, its second (contour pointer and mask)
  // belongs to the contours with the contour values.
  stats.hierarchyBytes = std::uint64_t(slotCount) * 4;
  stats.contourBytes = std::uint64_t(slotCount) * 4 + contours.size() * 4;
  stats.attributeBytes = (tree.hasColors ? (std::uint64_t(slotCount) + colors.size()) * 4 : 0) +
                         (tree.hasNormals ? (std::uint64_t(slotCount) + normals.size()) * 4 : 0);
  stats.totalBytes = bytes.size();
  if (statsOut) *statsOut = stats;
  if (descriptorSlot) *descriptorSlot = std::move(plan.slotOf);
  return Block(std::move(bytes));
}

VoxelTree readBlock(const BlockView& block) {
  VoxelTree tree;
  tree.hasColors = block.attachment(AttachmentType::Color) != nullptr;
  tree.hasNormals = block.attachment(AttachmentType::Normal) != nullptr;
  VoxelRecord root;
  if (tree.hasColors) root.color = block.attachment(AttachmentType::Color)->rootValue;
  if (tree.hasNormals) root.normal = block.attachment(AttachmentType::Normal)->rootValue;
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
    const BlockView::Attributes colors = BlockView::attributes(d, AttachmentType::Color);
    const BlockView::Attributes normals = BlockView::attributes(d, AttachmentType::Normal);
    for (int slot = 0; slot < 8; ++slot) {
      if (!(d->validMask() >> slot & 1u)) continue;
      VoxelRecord c;
      if (auto contour = BlockView::contour(d, slot)) c.hasContour = true, c.contour = *contour;
      c.color = colors.at(slot).value_or(parent.color);
      c.normal = normals.at(slot).value_or(parent.normal);
      tree.voxels.push_back(c);
      descriptorOf.push_back((d->leafMask() >> slot & 1u) ? nullptr : BlockView::child(d, slot));
    }
  }
  return tree;
}

}  // namespace svo
