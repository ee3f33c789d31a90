// The compressed attribute layout of a block (sec. 5.5; block.hpp, attribute_units.hpp): the same octree as
// the raw layout, every descriptor's children in one half of the unit its slot pair owns (checked against
// units encoded here from the tree), no unit where every child inherits its parent's value, siblings whose
// children come from different slices apart behind links, units carried from a block laid out again
// unchanged, the exact values a pool keeps, and bad bytes refused.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstring>
#include <functional>
#include <map>
#include <random>
#include <string>

#include <glm/geometric.hpp>

#include "svo/store/attribute_units.hpp"
#include "svo/store/block.hpp"
#include "svo/store/format.hpp"

namespace {

using svo::AttachmentType;
using svo::AttributeLayout;

constexpr double kPi = 3.14159265358979323846;

// A random tree whose attributes vary smoothly, as a surface's do: each child's color a few steps from its
// parent's, its normal a few degrees off.
svo::VoxelTree smoothTree(std::mt19937_64& rng, int depth, double childProbability) {
  svo::VoxelTree tree;
  tree.hasColors = tree.hasNormals = true;
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<float> g(0.0f, 1.0f);
  tree.voxels.push_back({});
  tree.voxels[0].color = svo::packABGR(120, 90, 60);
  tree.voxels[0].normal = svo::encodeNormal({0.3f, 0.5f, 0.8f});
  std::vector<std::pair<std::uint32_t, int>> queue{{0, 0}};
  for (std::size_t q = 0; q < queue.size(); ++q) {
    const auto [v, level] = queue[q];
    if (level == depth) continue;
    std::uint8_t mask = 0;
    for (int slot = 0; slot < 8; ++slot)
      if (u(rng) < childProbability || (slot == 7 && mask == 0)) mask |= std::uint8_t(1u << slot);
    tree.voxels[v].childMask = mask;
    tree.voxels[v].firstChild = std::uint32_t(tree.voxels.size());
    const svo::VoxelRecord parent = tree.voxels[v];
    for (int k = 0; k < std::popcount(unsigned(mask)); ++k) {
      svo::VoxelRecord c;
      const auto channel = [&](int shift) {
        return std::uint8_t(
            std::clamp(int((parent.color >> shift) & 255u) + int(std::lround(6.0f * g(rng))), 0, 255));
      };
      c.color = svo::packABGR(channel(0), channel(8), channel(16));
      c.normal =
          svo::encodeNormal(svo::decodeNormal(parent.normal) + 0.05f * glm::vec3(g(rng), g(rng), g(rng)));
      c.hasContour = u(rng) < 0.3;
      c.contour = svo::packContourBits(5, -3, 20, 4, 30);
      tree.voxels.push_back(c);
      queue.push_back({std::uint32_t(tree.voxels.size() - 1), level + 1});
    }
  }
  return tree;
}

double degreesBetween(glm::vec3 a, glm::vec3 b) {
  return std::acos(std::clamp(double(glm::dot(glm::normalize(a), glm::normalize(b))), -1.0, 1.0)) * 180.0 /
         kPi;
}

// The voxel laid out at each descriptor slot.
std::map<std::uint32_t, std::uint32_t> voxelAtSlot(const std::vector<std::uint32_t>& slotOf) {
  std::map<std::uint32_t, std::uint32_t> at;
  for (std::uint32_t v = 0; v < slotOf.size(); ++v)
    if (slotOf[v] != 0) at[slotOf[v]] = v;
  return at;
}

// The unit words of `type` for the pair of slots (2 pair, 2 pair + 1), straight from the bytes: page header
// of page 0 -> info section -> attachment directory (Fig. 8) -> the unit directory's entry of the pair (its
// presence bit, the units before it counted here from every entry's mask); nullptr where the pair holds none.
const std::uint32_t* unitFromBytes(const svo::BlockView& view, AttachmentType type, std::uint32_t pair) {
  const auto* base = reinterpret_cast<const std::uint32_t*>(view.base());
  const std::int32_t infoWords = std::int32_t(base[0]);
  const auto* info = reinterpret_cast<const svo::BlockInfo*>(base + infoWords);
  const auto* entries = reinterpret_cast<const svo::AttachmentEntry*>(info + 1);
  const std::uint32_t pairs = (info->slotCount + 1) / 2, groups = (pairs + 31) / 32;
  for (std::uint32_t a = 0; a < info->attachmentCount; ++a) {
    if (entries[a].type != type) continue;
    const std::uint32_t* directory = base + infoWords + entries[a].pointer;
    if (!(directory[2 * (pair / 32)] >> (pair % 32) & 1u)) return nullptr;
    std::uint32_t before = 0;
    for (std::uint32_t p = 0; p < pair; ++p) before += directory[2 * (p / 32)] >> (p % 32) & 1u;
    return directory + 2 * groups +
           before * (type == AttachmentType::ColorUnits ? svo::kColorUnitWords : svo::kNormalUnitWords);
  }
  return nullptr;
}

// Sec. 5.4's effective values, the raw layout's default rule: a child within its tolerance of its parent's
// effective value takes that value. Records are in breadth-first order (parents before children).
std::vector<svo::VoxelRecord> effectiveValues(const svo::VoxelTree& tree) {
  const svo::InheritanceRule rule{svo::LayoutOptions{}};
  std::vector<svo::VoxelRecord> out = tree.voxels;
  for (std::size_t v = 0; v < out.size(); ++v) {
    const svo::VoxelRecord& r = out[v];
    for (int k = 0; k < std::popcount(unsigned(r.childMask)); ++k) {
      svo::VoxelRecord& c = out[r.firstChild + k];
      if (rule.color(c.color, r.color)) c.color = r.color;
      if (rule.normal(c.normal, rule.parentNormal(r.normal))) c.normal = r.normal;
    }
  }
  return out;
}

svo::Block layOut(const svo::VoxelTree& tree, AttributeLayout attributes, svo::LayoutStats* stats = nullptr,
                  std::vector<std::uint32_t>* slotOf = nullptr) {
  svo::LayoutOptions options;
  options.attributes = attributes;
  return svo::layoutBlock(tree, options, stats, slotOf);
}

TEST(BlockUnits, EveryUnitHoldsItsTwoDescriptorsChildrenAsEncodedFromTheTree) {
  std::mt19937_64 rng(5);
  for (int t = 0; t < 6; ++t) {
    const svo::VoxelTree tree = smoothTree(rng, 5, 0.45);
    svo::LayoutStats stats;
    std::vector<std::uint32_t> slotOf;
    const svo::Block block = layOut(tree, AttributeLayout::Compressed, &stats, &slotOf);
    const svo::BlockView view(block.bytes().data(), block.bytes().size());  // validates
    ASSERT_EQ(view.attributeLayout(), AttributeLayout::Compressed);
    EXPECT_EQ(view.attachment(AttachmentType::Color), nullptr);  // no lookups beside the units
    EXPECT_EQ(stats.units, (view.info().slotCount + 1) / 2);
    const auto at = voxelAtSlot(slotOf);
    const std::vector<svo::VoxelRecord> effective = effectiveValues(tree);
    // What each voxel shows, top down (records are breadth first): its slot of its parent's pair's unit as
    // the bytes hold it, or its parent's shown value where the pair holds none.
    std::vector<std::uint32_t> shownColor(tree.voxels.size()), shownNormal(tree.voxels.size());
    shownColor[0] = tree.voxels[0].color, shownNormal[0] = tree.voxels[0].normal;
    const svo::InheritanceRule rule{svo::LayoutOptions{}};
    std::map<std::uint32_t, std::pair<bool, bool>> ownValues;  // pair -> some child off its parent's shown
    for (std::uint32_t v = 0; v < tree.voxels.size(); ++v) {
      const svo::VoxelRecord& r = tree.voxels[v];
      if (r.childMask == 0) continue;
      const std::uint32_t pair = slotOf[v] / 2, half = slotOf[v] % 2;
      const std::uint32_t* colorWords = unitFromBytes(view, AttachmentType::ColorUnits, pair);
      const std::uint32_t* normalWords = unitFromBytes(view, AttachmentType::NormalUnits, pair);
      auto& [ownColor, ownNormal] = ownValues[pair];
      for (int slot = 0, k = 0; slot < 8; ++slot) {
        if (!(r.childMask >> slot & 1u)) continue;
        const std::uint32_t c = r.firstChild + k++;
        ownColor |= !rule.color(effective[c].color, shownColor[v]);
        ownNormal |= !rule.normal(effective[c].normal, rule.parentNormal(shownNormal[v]));
        svo::ColorUnit color;
        svo::NormalUnit normal;
        if (colorWords) std::memcpy(color.words.data(), colorWords, 8);
        if (normalWords) std::memcpy(normal.words.data(), normalWords, 16);
        const int unitSlot = int(half) * 8 + slot;
        shownColor[c] = colorWords ? svo::decodeColorUnit(color, unitSlot) : shownColor[v];
        shownNormal[c] =
            !normalWords ? shownNormal[v]
            : isExact(normal)
                ? svo::encodeNormal(svo::decodeNormal(svo::exactNormalBits(normalWords, unitSlot)))
                : svo::encodeNormal(svo::decodeNormalUnit(normal, unitSlot));
      }
    }
    std::uint64_t halves = 0, colorUnits = 0, normalUnits = 0, exactUnits = 0;
    for (std::uint32_t pair = 0; pair < stats.units; ++pair) {
      std::array<std::uint32_t, svo::kUnitSlots> colors{};
      std::array<glm::vec3, svo::kUnitSlots> normals{};
      std::array<std::uint32_t, svo::kUnitSlots> exactBits{};
      std::uint16_t used = 0;
      bool any = false;
      for (int half = 0; half < 2; ++half) {
        const auto it = at.find(2 * pair + half);
        if (it == at.end() || tree.voxels[it->second].childMask == 0) continue;
        any = true, ++halves;
        const svo::VoxelRecord& r = effective[it->second];
        for (int slot = 0, k = 0; slot < 8; ++slot) {
          if (!(r.childMask >> slot & 1u)) continue;
          const svo::VoxelRecord& c = effective[r.firstChild + k++];
          used |= std::uint16_t(1u << (half * 8 + slot));
          colors[half * 8 + slot] = c.color;
          normals[half * 8 + slot] = svo::normalDirection(c.normal);
          exactBits[half * 8 + slot] = c.normal;
        }
      }
      const std::uint32_t* colorWords = unitFromBytes(view, AttachmentType::ColorUnits, pair);
      const std::uint32_t* normalWords = unitFromBytes(view, AttachmentType::NormalUnits, pair);
      // A pair holds a unit exactly where some child is off the value its parent shows.
      ASSERT_EQ(colorWords != nullptr, any && ownValues[pair].first) << pair;
      ASSERT_EQ(normalWords != nullptr, any && ownValues[pair].second) << pair;
      if (colorWords) {
        ++colorUnits;
        ASSERT_EQ(std::memcmp(colorWords, svo::encodeColorUnit(colors, used).words.data(), 8), 0) << pair;
      }
      if (normalWords) {
        ++normalUnits;
        // The grid unit, or where it misses the children by more than the exact-unit angle, their values.
        float squared = 0.0f;
        const svo::NormalUnit grid = svo::encodeNormalUnit(normals, used, &squared);
        const double rms =
            2.0 * std::asin(std::sqrt(double(squared) / std::popcount(used)) / 2.0) * 180.0 / kPi;
        if (rms <= double(svo::kExactNormalUnitDegrees)) {
          ASSERT_EQ(std::memcmp(normalWords, grid.words.data(), 16), 0) << pair;
        } else {
          ++exactUnits;
          ASSERT_EQ(normalWords[1], svo::kExactNormalAxes) << pair;
          ASSERT_EQ(normalWords[2], used) << pair;
          for (int slot = 0; slot < svo::kUnitSlots; ++slot)
            if (used >> slot & 1u)
              ASSERT_EQ(svo::exactNormalBits(normalWords, slot), exactBits[slot]) << pair;
        }
      }
    }
    EXPECT_EQ(stats.unitHalvesUsed, halves);
    EXPECT_EQ(stats.colorUnitsKept, colorUnits);
    EXPECT_EQ(stats.normalUnitsKept, normalUnits);
    EXPECT_EQ(stats.exactNormalUnits, exactUnits);
    // Read back: the raw layout's structure and contours, values within the units' error.
    const svo::VoxelTree raw = svo::readBlock(layOut(tree, AttributeLayout::Raw).view());
    const svo::VoxelTree back = svo::readBlock(view);
    ASSERT_EQ(back.voxels.size(), tree.voxels.size());
    double colorSquares = 0.0, angles = 0.0, worstAngle = 0.0;
    for (std::size_t i = 1; i < tree.voxels.size(); ++i) {
      const svo::VoxelRecord &a = back.voxels[i], &b = raw.voxels[i];
      ASSERT_EQ(a.childMask, b.childMask) << i;
      ASSERT_EQ(a.hasContour, b.hasContour) << i;
      if (a.hasContour) ASSERT_EQ(a.contour, b.contour) << i;
      for (int shift = 0; shift < 24; shift += 8) {
        const double d = double((a.color >> shift) & 255u) - double((tree.voxels[i].color >> shift) & 255u);
        colorSquares += d * d;
      }
      const double angle =
          degreesBetween(svo::decodeNormal(a.normal), svo::decodeNormal(tree.voxels[i].normal));
      angles += angle, worstAngle = std::max(worstAngle, angle);
    }
    const double n = double(tree.voxels.size() - 1);
    // Colors within a few 8-bit steps of a smooth tree's: a unit's 16 children scatter by about 6 steps per
    // channel around two parents (themselves 6 apart), which four colors on one line follow to about 4 steps
    // (RGB565 steps are 8 and 4). Normals within a degree on average (two siblings' children span ~10 degrees
    // here).
    EXPECT_LT(std::sqrt(colorSquares / (3.0 * n)), 5.0);
    EXPECT_LT(angles / n, 1.0);
    EXPECT_LT(worstAngle, 6.0);
  }
}

// Where every child of both descriptors of a pair is within the inheritance tolerance of the value its parent
// shows (sec. 5.4), the pair holds no unit of that attribute: its children read back with that value.
TEST(BlockUnits, APairWhoseChildrenAllInheritHoldsNoUnitAndShowsItsParentsValue) {
  std::mt19937_64 rng(21);
  svo::VoxelTree tree = smoothTree(rng, 4, 0.5);
  // The two deepest levels' normals (colors left as they are) are one axis, which a unit holds exactly: the
  // level above shows it, and the deepest level, equal to it, needs no normal unit.
  const std::uint32_t up = svo::encodeNormal({0.0f, 0.0f, 1.0f});
  std::vector<int> depth(tree.voxels.size(), 0);
  for (std::size_t v = 0; v < tree.voxels.size(); ++v)
    for (int k = 0; k < std::popcount(unsigned(tree.voxels[v].childMask)); ++k) {
      depth[tree.voxels[v].firstChild + k] = depth[v] + 1;
      if (depth[v] >= 2) tree.voxels[tree.voxels[v].firstChild + k].normal = up;
    }
  svo::LayoutStats stats;
  std::vector<std::uint32_t> slotOf;
  const svo::Block block = layOut(tree, AttributeLayout::Compressed, &stats, &slotOf);
  const svo::BlockView view(block.bytes().data(), block.bytes().size());  // validates
  const svo::VoxelTree back = svo::readBlock(view);
  std::uint32_t without = 0;
  for (std::uint32_t v = 0; v < tree.voxels.size(); ++v) {
    const svo::VoxelRecord& r = tree.voxels[v];
    if (r.childMask == 0 || depth[v] != 3) continue;
    const svo::ChildDescriptor* d = view.slots() + slotOf[v];
    // The pair's partner is a sibling at the same depth: neither has a normal unit, both keep a color unit.
    EXPECT_FALSE(svo::BlockView::unit(d, AttachmentType::NormalUnits)) << v;
    EXPECT_TRUE(svo::BlockView::unit(d, AttachmentType::ColorUnits)) << v;
    ++without;
    for (int k = 0; k < std::popcount(unsigned(r.childMask)); ++k)
      EXPECT_EQ(back.voxels[r.firstChild + k].normal, back.voxels[v].normal) << v;
  }
  EXPECT_GT(without, 10u);
  EXPECT_LT(stats.normalUnitsKept, stats.colorUnitsKept);
  // The bytes: the normal attachment holds only the kept units behind its directory.
  const svo::AttachmentEntry* normals = view.attachment(AttachmentType::NormalUnits);
  ASSERT_NE(normals, nullptr);
  EXPECT_EQ(normals->valueCount, stats.normalUnitsKept);
  EXPECT_EQ(
      stats.normalBytes,
      (svo::unitDirectoryWords(view.info().slotCount) + stats.normalUnitsKept * svo::kNormalUnitWords) * 4);
}

TEST(BlockUnits, SiblingsWhoseChildrenComeFromDifferentSlicesSitApartBehindLinks) {
  std::mt19937_64 rng(9);
  svo::VoxelTree tree = smoothTree(rng, 4, 0.6);
  // The root's first child takes its children from slice 10, the others from slice 11, as two runs of
  // sub-cubes would: the second child would share the first's unit, so it starts a run of its own.
  tree.childSlice.assign(tree.voxels.size(), 1);
  const svo::VoxelRecord& root = tree.voxels[0];
  ASSERT_GE(std::popcount(unsigned(root.childMask)), 2);
  for (int k = 0; k < std::popcount(unsigned(root.childMask)); ++k)
    tree.childSlice[root.firstChild + k] = k == 0 ? 10 : 11;
  svo::LayoutStats stats;
  std::vector<std::uint32_t> slotOf;
  const svo::Block block = layOut(tree, AttributeLayout::Compressed, &stats, &slotOf);
  const svo::BlockView view(block.bytes().data(), block.bytes().size());
  EXPECT_GT(stats.linkSlots, 0u);
  // No unit holds descriptors whose children come from two slices.
  const auto at = voxelAtSlot(slotOf);
  for (const auto& [slot, voxel] : at) {
    const auto partner = at.find(slot ^ 1u);
    if (partner == at.end() || tree.voxels[voxel].childMask == 0 ||
        tree.voxels[partner->second].childMask == 0)
      continue;
    EXPECT_EQ(tree.childSlice[voxel], tree.childSlice[partner->second])
        << "slots " << slot << ", " << (slot ^ 1u);
  }
  // The links lead to the same octree: structure and values read back as without the slices.
  svo::VoxelTree plain = tree;
  plain.childSlice.clear();
  const svo::VoxelTree a = svo::readBlock(view),
                       b = svo::readBlock(layOut(plain, AttributeLayout::Compressed).view());
  ASSERT_EQ(a.voxels.size(), b.voxels.size());
  for (std::size_t i = 0; i < a.voxels.size(); ++i) {
    EXPECT_EQ(a.voxels[i].childMask, b.voxels[i].childMask) << i;
    EXPECT_EQ(a.voxels[i].contour, b.voxels[i].contour) << i;
  }
}

TEST(BlockUnits, CarriedUnitsAreLaidOutUnchangedAndTheExactValuesKept) {
  std::mt19937_64 rng(13);
  const svo::VoxelTree tree = smoothTree(rng, 4, 0.5);
  std::vector<std::uint32_t> slotOf;
  const svo::Block first = layOut(tree, AttributeLayout::Compressed, nullptr, &slotOf);
  // Carry every descriptor's units, the root's as a first half (it then moves to slot 2).
  svo::VoxelTree again = tree;
  again.carriedUnitOf.assign(tree.voxels.size(), svo::kNoCarriedUnit);
  for (std::uint32_t v = 0; v < tree.voxels.size(); ++v) {
    if (tree.voxels[v].childMask == 0) continue;
    const svo::ChildDescriptor* d = first.view().slots() + slotOf[v];
    svo::CarriedUnit unit;
    const auto colors = svo::BlockView::unit(d, AttachmentType::ColorUnits);
    const auto normals = svo::BlockView::unit(d, AttachmentType::NormalUnits);
    if (colors) std::memcpy(unit.color.words.data(), colors->words, 8), unit.hasColor = true;
    if (normals) std::memcpy(unit.normal.words.data(), normals->words, 16), unit.hasNormal = true;
    unit.half = std::uint8_t(v == 0 ? 0 : slotOf[v] % 2);
    // Changed values would be re-encoded differently: the layout must not look at them.
    again.voxels[v].color ^= 0x00FFFFFFu;
    again.carriedUnitOf[v] = std::uint32_t(again.carriedUnits.size());
    again.carriedUnits.push_back(unit);
  }
  again.exactColors = {svo::packABGR(1, 2, 3), svo::packABGR(4, 5, 6, 7)};
  again.exactNormals = {11, 65535, 300};
  std::vector<std::uint32_t> slotAgain;
  svo::LayoutStats stats;
  const svo::Block second = layOut(again, AttributeLayout::Compressed, &stats, &slotAgain);
  const svo::BlockView view(second.bytes().data(), second.bytes().size());
  EXPECT_EQ(slotAgain[0], 2u);
  std::uint32_t pairsWithoutUnits = 0;
  for (std::uint32_t v = 0; v < tree.voxels.size(); ++v) {
    if (tree.voxels[v].childMask == 0) continue;
    const auto normal = svo::BlockView::unit(view.slots() + slotAgain[v], AttachmentType::NormalUnits);
    const auto color = svo::BlockView::unit(view.slots() + slotAgain[v], AttachmentType::ColorUnits);
    const svo::CarriedUnit& carried = again.carriedUnits[again.carriedUnitOf[v]];
    ASSERT_EQ(normal.has_value(), carried.hasNormal) << v;
    ASSERT_EQ(color.has_value(), carried.hasColor) << v;
    pairsWithoutUnits += !carried.hasNormal || !carried.hasColor;
    if (normal) {
      EXPECT_EQ(normal->half, v == 0 ? 0 : int(slotAgain[v] % 2));
      EXPECT_EQ(std::memcmp(normal->words, carried.normal.words.data(), 16), 0) << v;
    }
    if (color) EXPECT_EQ(std::memcmp(color->words, carried.color.words.data(), 8), 0) << v;
  }
  EXPECT_LT(pairsWithoutUnits, tree.voxels.size());  // most pairs carry their units
  const svo::AttachmentEntry* colors = view.attachment(AttachmentType::ExactColors);
  const svo::AttachmentEntry* normals = view.attachment(AttachmentType::ExactNormals);
  ASSERT_TRUE(colors && normals);
  EXPECT_EQ(colors->valueCount, 2u);
  EXPECT_EQ(view.words(*colors)[1], svo::packABGR(4, 5, 6, 7));
  const auto* codes = reinterpret_cast<const std::uint16_t*>(view.words(*normals));
  EXPECT_EQ(codes[0], 11);
  EXPECT_EQ(codes[2], 300);
  EXPECT_EQ(stats.exactBytes, 2u * 4 + 2u * 4);  // three codes in two words
  // The raw layout takes neither.
  EXPECT_THROW(layOut(again, AttributeLayout::Raw), std::invalid_argument);
}

// Two siblings whose 16 children face every way, as the two sides of a thin sheet or a box's corner do: no
// grid of the paper's format comes within degrees of them, so their pair keeps the values (an exact unit),
// which read back as the raw layout's to the cube encoding's precision. Without exact units the grid's error
// is tens of degrees. An exact unit whose values point outside the block is refused.
TEST(BlockUnits, APairNoGridFitsKeepsItsNormalsExactly) {
  svo::VoxelTree tree;
  tree.hasNormals = true;
  tree.voxels.resize(1 + 2 + 16);
  tree.voxels[0] = {.firstChild = 1, .childMask = 0b11, .normal = svo::encodeNormal({0.0f, 0.0f, 1.0f})};
  for (int half = 0; half < 2; ++half) {
    svo::VoxelRecord& parent = tree.voxels[std::size_t(1 + half)];
    parent = {.firstChild = std::uint32_t(3 + 8 * half), .childMask = 0xFF};
    parent.normal = svo::encodeNormal({half ? -1.0f : 1.0f, 0.2f, 0.3f});
  }
  for (int k = 0; k < 16; ++k) {  // a Fibonacci sphere: 16 directions spread evenly
    const double z = 1.0 - (k + 0.5) / 8.0, r = std::sqrt(1.0 - z * z),
                 phi = k * kPi * (3.0 - std::sqrt(5.0));
    tree.voxels[std::size_t(3 + k)].normal =
        svo::encodeNormal(glm::vec3(r * std::cos(phi), r * std::sin(phi), z));
  }
  const svo::VoxelTree raw = svo::readBlock(layOut(tree, AttributeLayout::Raw).view());
  const auto meanError = [&](const svo::LayoutOptions& options, svo::LayoutStats& stats, svo::Block& block) {
    std::vector<std::uint32_t> slotOf;
    block = svo::layoutBlock(tree, options, &stats, &slotOf);
    const svo::VoxelTree back = svo::readBlock(svo::BlockView(block.bytes().data(), block.bytes().size()));
    double sum = 0.0;
    for (std::size_t v = 3; v < back.voxels.size(); ++v)
      sum +=
          degreesBetween(svo::decodeNormal(back.voxels[v].normal), svo::decodeNormal(raw.voxels[v].normal));
    return sum / 16.0;
  };
  svo::LayoutOptions options;
  options.attributes = AttributeLayout::Compressed;
  svo::LayoutStats stats;
  svo::Block block;
  EXPECT_LT(meanError(options, stats, block), 1e-3);
  EXPECT_EQ(stats.exactNormalUnits, 1u);
  EXPECT_EQ(stats.exactNormalValues, 16u);
  // Its pair's unit: the exact unit, values behind the units.
  const std::uint32_t* unit = nullptr;
  for (std::uint32_t pair = 0; pair < stats.units && !unit; ++pair) {
    const std::uint32_t* u = unitFromBytes(block.view(), AttachmentType::NormalUnits, pair);
    if (u && u[1] == svo::kExactNormalAxes) unit = u;
  }
  ASSERT_NE(unit, nullptr);
  EXPECT_EQ(unit[2], 0xFFFFu);
  // Pointing past the block's end is refused.
  svo::AlignedBytes spoiled(block.bytes().size());
  std::memcpy(spoiled.data(), block.bytes().data(), spoiled.size());
  const std::size_t unitOffset = std::size_t(reinterpret_cast<const std::byte*>(unit) - block.bytes().data());
  reinterpret_cast<std::uint32_t*>(spoiled.data() + unitOffset)[0] = std::uint32_t(spoiled.size());
  EXPECT_THROW(svo::BlockView(spoiled.data(), spoiled.size()), std::runtime_error);
  // Without exact units, a grid: degrees off on average.
  options.exactNormalUnitDegrees = 0.0f;
  EXPECT_GT(meanError(options, stats, block), 10.0);
  EXPECT_EQ(stats.exactNormalUnits, 0u);
}

// A pool keeps the deepest level's normals as their 16-bit lattice codes: every code must come back from the
// cube encoding the voxels hold.
TEST(BlockUnits, LatticeNormalCodesSurviveTheCubeEncoding) {
  int lost = 0;
  for (std::uint32_t code = 0; code < 65536; ++code) {
    const std::uint32_t bits = svo::latticeNormalBits(std::uint16_t(code));
    lost += svo::latticeNormalBits(svo::octNormalCodeOf(bits)) != bits;
  }
  EXPECT_EQ(lost, 0);
}

TEST(BlockUnits, ATruncatedUnitArrayOrAWrongUnitCountIsRefused) {
  std::mt19937_64 rng(17);
  const svo::Block block = layOut(smoothTree(rng, 4, 0.5), AttributeLayout::Compressed);
  const std::vector<std::byte> original(block.bytes().data(), block.bytes().data() + block.bytes().size());
  svo::AlignedBytes bytes(original.size());
  const auto check = [&](const std::function<void(std::byte*)>& spoil, const char* what) {
    std::memcpy(bytes.data(), original.data(), original.size());
    spoil(bytes.data());
    EXPECT_THROW(svo::BlockView(bytes.data(), bytes.size()), std::runtime_error) << what;
  };
  const svo::BlockView view = block.view();
  const std::size_t infoOffset = std::size_t(reinterpret_cast<const std::byte*>(&view.info()) - view.base());
  const std::size_t entry = infoOffset + sizeof(svo::BlockInfo);
  check([&](std::byte* b) { reinterpret_cast<svo::AttachmentEntry*>(b + entry)->valueCount += 1; },
        "unit count");
  check([&](std::byte* b) { reinterpret_cast<svo::AttachmentEntry*>(b + entry)->pointer = 0x3FFFFFFF; },
        "unit array past the end");
  check([&](std::byte* b) { reinterpret_cast<svo::AttachmentEntry*>(b + entry)->type = AttachmentType(9); },
        "unknown type");
  // The unit directory: an entry's first unit past the units before it, or a presence bit more or less.
  const auto directory = [&](std::byte* b) {
    const auto* e = reinterpret_cast<const svo::AttachmentEntry*>(b + entry);
    return reinterpret_cast<std::uint32_t*>(b + infoOffset + std::ptrdiff_t(e->pointer) * 4);
  };
  check([&](std::byte* b) { directory(b)[1] += 1; }, "first unit index");
  check([&](std::byte* b) { directory(b)[0] ^= 1u; }, "presence bit");
}

}  // namespace
