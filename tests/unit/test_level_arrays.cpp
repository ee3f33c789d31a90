// Level arrays (level_arrays.hpp) against decodeSlice's voxel records: every fixture store and a store of
// many small slices decode to the same hierarchy, contours and shown values; bad slices throw.
#include <gtest/gtest.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <filesystem>
#include <vector>

#include "reference.hpp"
#include "svo/store/codec.hpp"
#include "svo/store/format.hpp"
#include "svo/store/level_arrays.hpp"
#include "svo/store/store_reader.hpp"

namespace {

namespace fs = std::filesystem;

// A store decoded both ways, slice by slice in each level's Morton order.
struct Decoded {
  svo::LevelOrderTree tree;
  std::vector<std::size_t> levelStart{0, 1};  // in tree.voxels
  std::vector<svo::OctreeLevel> levels;
};

Decoded decodeBoth(const svo::StoreReader& reader) {
  const svo::StoreIndex& index = reader.index();
  const svo::StoreHeader& header = reader.header();
  Decoded d;
  d.tree.hasColors = header.hasColors, d.tree.hasNormals = header.hasNormals;
  d.tree.voxels.push_back({.color = header.rootColor, .normal = header.rootNormal});
  d.levels.push_back(svo::rootLevel(header));
  for (int level = 1; level <= header.parameters.levels && !index.slicesOfLevel(level).empty(); ++level) {
    const std::size_t begin = d.levelStart[std::size_t(level) - 1], end = d.tree.voxels.size();
    std::vector<std::pair<std::size_t, std::uint32_t>> order;  // first parent in the level, slice
    for (const std::uint32_t id : index.slicesOfLevel(level)) {
      const std::span<svo::SliceVoxel> level(d.tree.voxels.data() + begin, end - begin);
      order.push_back({std::size_t(svo::sliceParents(index, id, level).data() - level.data()), id});
    }
    std::sort(order.begin(), order.end());
    d.levels.emplace_back();
    for (const auto& [first, id] : order) {
      const svo::SliceBytes raw = reader.readSlice(id);
      svo::decodeSlice(index, id, raw, d.tree, begin + first, begin + first + index.slices()[id].parentCount);
      svo::decodeSliceLevel(raw, index.slices()[id], header, d.levels[std::size_t(level) - 1], first,
                            d.levels.back());
    }
    d.levelStart.push_back(d.tree.voxels.size());
  }
  return d;
}

// Every voxel's child mask, contour and shown values as the level arrays give them, against its record.
void expectSameVoxels(const Decoded& d) {
  for (std::size_t l = 1; l < d.levels.size(); ++l) {
    const svo::OctreeLevel& level = d.levels[l];
    ASSERT_EQ(level.voxels, d.levelStart[l + 1] - d.levelStart[l]) << "level " << l;
    ASSERT_EQ(level.contourBits.size(), level.voxels);
    std::size_t parent = d.levelStart[l - 1], siblingsLeft = 0, contour = 0, color = 0, normal = 0;
    for (std::size_t i = 0; i < level.voxels; ++i) {
      while (siblingsLeft == 0) siblingsLeft = std::size_t(std::popcount(d.tree.voxels[parent++].childMask));
      --siblingsLeft;
      const svo::SliceVoxel& v = d.tree.voxels[d.levelStart[l] + i];
      const svo::SliceVoxel& p = d.tree.voxels[parent - 1];
      SCOPED_TRACE("level " + std::to_string(l) + ", voxel " + std::to_string(i));
      EXPECT_EQ(level.childMasks[i], v.childMask);
      ASSERT_EQ(level.contourBits[i], v.hasContour);
      if (v.hasContour) EXPECT_EQ(level.contours[contour++], v.contour);
      if (d.tree.hasColors) EXPECT_EQ(level.colorBits[i] ? level.colors[color++] : p.color, v.color);
      if (d.tree.hasNormals) {
        const std::uint16_t code = level.shownNormalCodes[i];
        EXPECT_EQ(svo::latticeNormalBits(code), v.normal);
        if (level.normalBits[i]) EXPECT_EQ(level.normalCodes[normal++], code);
      }
    }
    EXPECT_EQ(contour, level.contours.size());
    EXPECT_EQ(color, level.colors.size());
    EXPECT_EQ(normal, level.normalCodes.size());
  }
}

TEST(LevelArrays, FixturesDecodeAsTheirVoxelRecords) {
  for (const char* file : {"cube-v4.svo", "sphere-v4.svo", "runs-v4.svo", "cube-v5.svo", "sphere-v5.svo",
                           "runs-v5.svo", "shaded-v5.svo"}) {
    SCOPED_TRACE(file);
    const svo::StoreReader reader(fs::path(SVO_TEST_DATA) / "fixtures" / file);
    const Decoded d = decodeBoth(reader);
    ASSERT_GT(d.levels.size(), 2u);
    expectSameVoxels(d);
  }
}

TEST(LevelArrays, ManySlicesPerLevelDecodeAsTheirVoxelRecords) {
  const svotest::TempFile store("svo_level_arrays", ".svo");
  svotest::writeSphereAndBoxStore(store.path, 4096);
  const svo::StoreReader reader(store.path);
  const Decoded d = decodeBoth(reader);
  const std::size_t slicesOfDeepest = reader.index().slicesOfLevel(int(d.levels.size()) - 1).size();
  ASSERT_GT(slicesOfDeepest, 4u) << "the store should split its levels into many slices";
  expectSameVoxels(d);
  // Bytes as bytesOf counts them: the deepest level has no child masks, each part presence bits and values.
  const svo::LevelArrayBytes b = svo::bytesOf(d.levels, reader.header());
  std::size_t masks = 0, contours = 0;
  for (std::size_t l = 0; l < d.levels.size(); ++l) {
    if (l + 1 < d.levels.size()) masks += d.levels[l].voxels;
    contours += d.levels[l].contours.size();
  }
  EXPECT_GT(b.hierarchy, masks);
  EXPECT_LT(b.hierarchy, masks + 4 * (masks / svo::kChildCountGroup + d.levels.size()));
  EXPECT_GT(b.contours, 4 * contours);
}

TEST(LevelArrays, BadSlicesThrow) {
  const svo::StoreReader reader(fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v5.svo");
  const svo::StoreHeader& header = reader.header();
  const std::uint32_t id = reader.index().slicesOfLevel(2).front();
  const svo::SliceInfo& slice = reader.index().slices()[id];
  // Level 1 as its own slice gives it, to decode level 2 on.
  svo::OctreeLevel root = svo::rootLevel(header), level1, level2;
  const std::uint32_t first = reader.index().slicesOfLevel(1).front();
  svo::decodeSliceLevel(reader.readSlice(first), reader.index().slices()[first], header, root, 0, level1);
  ASSERT_EQ(level1.voxels, slice.parentCount);
  const svo::SliceBytes good = reader.readSlice(id);
  const auto decode = [&](std::vector<std::byte> bytes, std::size_t firstParent = 0) {
    svo::OctreeLevel parents = level1, children;
    svo::decodeSliceLevel(bytes, slice, header, parents, firstParent, children);
  };
  const std::vector<std::byte> bytes(good.begin(), good.end());
  EXPECT_NO_THROW(decode(bytes));
  EXPECT_THROW(decode(bytes, 1), svo::SliceDecodeError);  // its parents run past their level
  EXPECT_THROW(decode(std::vector<std::byte>(bytes.begin(), bytes.end() - 1)), svo::SliceDecodeError);
  svo::SliceHead head;
  std::memcpy(&head, bytes.data(), sizeof head);
  const std::size_t masks = sizeof head + (head.parentCount + 7) / 8;
  std::vector<std::byte> zeroMask = bytes;
  zeroMask[masks] = std::byte{0};
  EXPECT_THROW(decode(zeroMask), svo::SliceDecodeError);
  std::vector<std::byte> moreChildren = bytes;  // a mask with a child more than the voxel count
  moreChildren[masks] = std::byte(std::to_integer<unsigned>(bytes[masks]) == 0xFF ? 0x7F : 0xFF);
  EXPECT_THROW(decode(moreChildren), svo::SliceDecodeError);
  std::vector<std::byte> noSplit = bytes;  // a split bit cleared: the masks outnumber the split parents
  for (std::size_t k = sizeof head; k < masks; ++k)
    if (noSplit[k] != std::byte{0}) {
      noSplit[k] &= std::byte(std::to_integer<unsigned>(noSplit[k]) - 1);
      break;
    }
  EXPECT_THROW(decode(noSplit), svo::SliceDecodeError);
  std::vector<std::byte> extraContour = bytes;  // a contour presence bit more than the contour count
  const std::size_t contourBits = masks + head.splitCount;
  for (std::size_t i = 0; i < head.voxelCount; ++i)
    if (!((std::to_integer<unsigned>(extraContour[contourBits + i / 8]) >> (i % 8)) & 1u)) {
      extraContour[contourBits + i / 8] |= std::byte(1u << (i % 8));
      break;
    }
  EXPECT_THROW(decode(extraContour), svo::SliceDecodeError);
}

}  // namespace
