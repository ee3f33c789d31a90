// layoutBlock of a level-order tree (the pager's decoded slices, laid out without copying them into records)
// against layoutBlock of the records treeOfLevels makes of the same levels: the same bytes and the same
// descriptor slots, in both attribute layouts, with stubs, far pointers and carried values, and with a hook
// between the layout's passes.
#include <gtest/gtest.h>

#include <bit>
#include <cstdint>
#include <cstring>
#include <random>
#include <set>
#include <vector>

#include "reference.hpp"
#include "svo/store/store_types.hpp"

namespace {

// Random levels from one root down: each voxel of a level splits with probability `split` into a random
// non-empty set of children, whose contours, colors and normals are random or, half the time, their
// parent's (so that inheritance and units both occur). Coordinates follow the slots (Morton order).
svo::VoxelLevels randomLevels(std::mt19937_64& rng, int depth, double split) {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  svo::VoxelLevels levels{{{.color = 0xff336699u, .normal = svo::encodeNormal({0.0f, 0.0f, 1.0f})}}};
  for (int level = 1; level <= depth; ++level) {
    std::vector<svo::SliceVoxel> next;
    for (svo::SliceVoxel& parent : levels.back()) {
      if (level > 1 && uni(rng) >= split) continue;
      parent.childMask = std::uint8_t(1u + rng() % 255u);
      for (int slot = 0; slot < 8; ++slot) {
        if (!(parent.childMask >> slot & 1u)) continue;
        svo::SliceVoxel c{.coord = svo::childCoord(parent.coord, slot)};
        c.hasContour = uni(rng) < 0.5;
        c.contour = c.hasContour ? std::uint32_t(rng()) : 0u;
        c.color = uni(rng) < 0.5 ? parent.color : std::uint32_t(rng());
        const glm::vec3 n(float(uni(rng)) - 0.5f, float(uni(rng)) - 0.5f, 0.25f);
        c.normal = uni(rng) < 0.5 ? parent.normal : svo::encodeNormal(glm::normalize(n));
        next.push_back(c);
      }
    }
    if (next.empty()) break;
    levels.push_back(std::move(next));
  }
  return levels;
}

struct Case {
  svo::AttributeLayout attributes;
  std::uint32_t maxNearPointer;
};

TEST(LevelOrderLayout, EqualsTheRecordsLayout) {
  std::mt19937_64 rng(20261129);
  for (const Case& layoutCase :
       {Case{svo::AttributeLayout::Raw, svo::kMaxNearPointer}, Case{svo::AttributeLayout::Raw, 16},
        Case{svo::AttributeLayout::Compressed, svo::kMaxNearPointer},
        Case{svo::AttributeLayout::Compressed, 16}}) {
    std::uint64_t farSlots = 0;    // the short reach must lead to far pointers, or the case tests nothing
    int pausesWithinEncoding = 0;  // and the compressed cases must pause within the units' encoding
    for (int trial = 0; trial < 12; ++trial) {
      const svo::VoxelLevels levels = randomLevels(rng, 2 + trial % 7, 0.6);
      svo::VoxelTree records = svo::treeOfLevels(levels, true, true);
      svo::LevelOrderTree tree;
      for (const auto& level : levels) tree.voxels.insert(tree.voxels.end(), level.begin(), level.end());
      ASSERT_EQ(tree.voxels.size(), records.voxels.size());
      // Every fifth voxel without children is a stub in both.
      for (std::uint32_t v = 1, leaves = 0; v < records.voxels.size(); ++v)
        if (records.voxels[v].childMask == 0 && leaves++ % 5 == 0) {
          records.voxels[v].stub = true;
          tree.stubs.push_back(v);
        }
      if (layoutCase.attributes == svo::AttributeLayout::Compressed) {
        // The deepest level's exact values, as a pool block keeps them.
        for (const svo::SliceVoxel& v : levels.back()) {
          records.exactColors.push_back(v.color);
          records.exactNormals.push_back(std::uint16_t(v.normal));
        }
      }
      static_cast<svo::TreeAttachments&>(tree) = records;
      svo::LayoutOptions options;
      options.attributes = layoutCase.attributes;
      options.maxNearPointer = layoutCase.maxNearPointer;
      std::vector<std::uint32_t> slotsOfRecords, slotsOfLevels;
      svo::LayoutStats stats;
      const svo::Block expected = svo::layoutBlock(records, options, &stats, &slotsOfRecords);
      farSlots += stats.farSlots;
      // A hook between the passes, and between every few pairs' units, changes nothing (a pager worker
      // pauses there; units are then encoded on its thread alone).
      int pauses = 0;
      options.betweenPasses = [&] { ++pauses; };
      const svo::Block got = svo::layoutBlock(tree, options, nullptr, &slotsOfLevels);
      if (layoutCase.attributes == svo::AttributeLayout::Compressed) {
        std::set<std::uint32_t> pairsEncoded;  // the pairs holding a descriptor with children
        for (std::size_t v = 0; v < records.voxels.size(); ++v)
          if (records.voxels[v].childMask != 0) pairsEncoded.insert(slotsOfRecords[v] / 2);
        EXPECT_EQ(pauses, 3 + int(pairsEncoded.size() / svo::kPairsBetweenPauses));
        pausesWithinEncoding += int(pairsEncoded.size() / svo::kPairsBetweenPauses);
      } else {
        EXPECT_EQ(pauses, 2);
      }
      SCOPED_TRACE("trial " + std::to_string(trial) + ", " + svo::nameOf(layoutCase.attributes) +
                   ", near pointers up to " + std::to_string(layoutCase.maxNearPointer));
      ASSERT_EQ(got.bytes().size(), expected.bytes().size());
      EXPECT_EQ(std::memcmp(got.bytes().data(), expected.bytes().data(), got.bytes().size()), 0);
      EXPECT_EQ(slotsOfLevels, slotsOfRecords);
    }
    if (layoutCase.maxNearPointer < svo::kMaxNearPointer) EXPECT_GT(farSlots, 0u);
    if (layoutCase.attributes == svo::AttributeLayout::Compressed) EXPECT_GT(pausesWithinEncoding, 0);
  }
}

TEST(LevelOrderLayout, RejectsStubsThatAreNotAscendingLeaves) {
  std::mt19937_64 rng(7);
  svo::LevelOrderTree tree;
  for (const auto& level : randomLevels(rng, 3, 1.0))
    tree.voxels.insert(tree.voxels.end(), level.begin(), level.end());
  tree.stubs = {0};  // the root has children
  EXPECT_NE(svotest::errorOf([&] { svo::layoutBlock(tree); }).find("stubs must be ascending"),
            std::string::npos);
  tree.stubs = {std::uint32_t(tree.voxels.size())};
  EXPECT_NE(svotest::errorOf([&] { svo::layoutBlock(tree); }).find("stubs must be ascending"),
            std::string::npos);
}

}  // namespace
