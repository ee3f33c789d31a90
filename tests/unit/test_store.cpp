// The slice store (store/store_writer.hpp, store_reader.hpp) against independent references:
//  - round trip: the store loaded whole and laid out gives the in-core builder's block byte for byte, for
//    slice sizes from the smallest to one that never splits, with and without colors;
//  - the slice hierarchy: voxel counts per level equal a breadth-first count of the source tree, slices of a
//    level cover disjoint cubes that together hold every parent, and no slice exceeds the slice size unless
//    its cube is one voxel of the level above (it cannot split further);
//  - bad files: every single-byte corruption of a small store and every truncation is reported (header,
//    directory or slice named), never decoded; wrong magic, version, a directory past the end, zero length.
#include <gtest/gtest.h>
#include <glm/geometric.hpp>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include <tbb/global_control.h>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/store/codec.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_writer.hpp"

namespace fs = std::filesystem;

namespace {

fs::path tempPath(const std::string& name) {
  return fs::temp_directory_path() / ("svo_store_" + std::to_string(::getpid()) + "_" + name);
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void spit(const fs::path& p, const std::string& bytes) {
  std::ofstream(p, std::ios::binary | std::ios::trunc) << bytes;
}

svo::Octree coloredSphere(int levels) {
  svo::Mesh m = svotest::makeSphere({0.1, 0.2, -0.3}, 1.0, 20, 20);
  for (const glm::dvec3& p : m.positions)
    m.colors.emplace_back(float(0.5 + 0.5 * p.x), float(0.5 + 0.5 * p.y), 0.3f, 1.0f);
  svo::BuildOptions options;
  options.levels = levels;
  return svo::buildOctree(m, options);
}

svo::Octree plainTriangles(int levels) {
  svo::BuildOptions options;
  options.levels = levels;
  return svo::buildOctree(svotest::makeRandomTriangles(3, 60, {-1, -1, -1}, {1, 1, 1}, 0.5), options);
}

// Voxels per level of a tree, breadth first from the root (level 0 = the root).
std::vector<std::uint64_t> voxelsPerLevel(const svo::VoxelTree& tree) {
  std::vector<std::uint64_t> counts;
  std::vector<std::pair<std::uint32_t, int>> stack{{0u, 0}};
  while (!stack.empty()) {
    const auto [v, level] = stack.back();
    stack.pop_back();
    if (counts.size() <= std::size_t(level)) counts.resize(level + 1);
    ++counts[level];
    const svo::VoxelRecord& r = tree.voxels[v];
    for (int c = 0; c < std::popcount(unsigned(r.childMask)); ++c)
      stack.push_back({r.firstChild + c, level + 1});
  }
  return counts;
}

bool sameBlock(const svo::Octree& a, const svo::Octree& b) {
  const auto& x = a.block.bytes();
  const auto& y = b.block.bytes();
  return x.size() == y.size() && std::memcmp(x.data(), y.data(), x.size()) == 0;
}

TEST(Store, RoundTripGivesTheInCoreBlockByteForByte) {
  for (const bool colors : {true, false}) {
    const svo::Octree octree = colors ? coloredSphere(7) : plainTriangles(6);
    for (const std::uint32_t sliceBytes : {256u, 1024u, 16384u, 1u << 30}) {
      const fs::path path = tempPath("roundtrip.svo");
      svo::StoreWriteOptions options;
      options.sliceBytes = sliceBytes;
      svo::writeOctree(path, octree, options);
      const svo::Octree back = svo::readOctree(path);
      EXPECT_TRUE(sameBlock(octree, back))
          << (colors ? "colored sphere" : "triangles") << ", slice size " << sliceBytes;
      EXPECT_EQ(back.transform.origin, octree.transform.origin);
      EXPECT_EQ(back.transform.size, octree.transform.size);
      EXPECT_EQ(back.parameters.levels, octree.parameters.levels);
      EXPECT_EQ(svo::StoreReader(path).header().hasColors, colors);
      fs::remove(path);
    }
  }
}

// Decoding calls its pause hook (a pager worker leaving the cores to a frame) after every
// kParentsBetweenPauses parents of a slice, and decodes the same voxels as without it (walk's decoding).
TEST(Store, DecodingPausesAfterEveryFewThousandParentsAndDecodesTheSame) {
  const fs::path path = tempPath("pauses.svo");
  svo::writeOctree(path, coloredSphere(9), {});
  const svo::StoreReader reader(path);
  std::size_t slicesPaused = 0;
  const auto enter = [&](std::uint32_t slice, std::span<const svo::SliceVoxel> parents,
                         std::span<const svo::SliceVoxel> voxels) {
    SCOPED_TRACE("slice " + std::to_string(slice));
    std::vector<svo::SliceVoxel> paused(parents.begin(), parents.end()), children;
    for (svo::SliceVoxel& p : paused) p.childMask = 0;
    std::size_t pauses = 0;
    svo::decodeSlice(reader.index(), slice, reader.readSlice(slice), paused, children, [&] { ++pauses; });
    EXPECT_EQ(pauses, parents.size() / svo::kParentsBetweenPauses);
    slicesPaused += pauses > 0;
    for (std::size_t i = 0; i < parents.size(); ++i) ASSERT_EQ(paused[i].childMask, parents[i].childMask);
    ASSERT_EQ(children.size(), voxels.size());
    for (std::size_t i = 0; i < voxels.size(); ++i) {
      const svo::SliceVoxel &a = children[i], &b = voxels[i];
      ASSERT_TRUE(a.coord == b.coord && a.hasContour == b.hasContour && a.contour == b.contour &&
                  a.color == b.color && a.normal == b.normal)
          << "voxel " << i;
    }
  };
  reader.walk(enter, [](auto, auto, auto) {});
  EXPECT_GT(slicesPaused, 0u) << "no slice has enough parents to pause";
  fs::remove(path);
}

// The writer compresses slices in parallel batches and writes them in the order they came: one thread and
// every thread write the same file, here of far more slices than one batch.
TEST(Store, TheFileIsTheSameOnAnyThreadCount) {
  const svo::Octree octree = coloredSphere(7);
  svo::StoreWriteOptions options;
  options.sliceBytes = 256;
  std::string written[2];
  for (const std::size_t threads : {std::size_t(1), std::size_t(0)}) {
    const fs::path path = tempPath("threads.svo");
    {
      std::optional<tbb::global_control> limit;
      if (threads) limit.emplace(tbb::global_control::max_allowed_parallelism, threads);
      svo::writeOctree(path, octree, options);
    }
    written[threads == 0] = slurp(path);
    ASSERT_GT(svo::StoreReader(path).slices().size(), 100u);
    EXPECT_TRUE(sameBlock(octree, svo::readOctree(path)));
    fs::remove(path);
  }
  EXPECT_TRUE(written[0] == written[1]);
}

TEST(Store, WritingTheBuilderTreeDirectlyGivesTheSameOctree) {
  // svo build writes the voxelizer's tree (raw attribute values) without laying it out first: inheritance is
  // decided by the same rule, so the loaded store lays out to the in-core block.
  svo::Mesh m = svotest::makeSphere({0.0, 0.0, 0.0}, 1.0, 16, 16);
  for (const glm::dvec3& p : m.positions)
    m.colors.emplace_back(float(0.5 + 0.4 * p.z), 0.2f, float(0.5 + 0.4 * p.x), 1.0f);
  svo::BuildOptions options;
  options.levels = 6;
  const svo::Octree inCore = svo::buildOctree(m, options);
  const svo::VoxelTree tree = svo::voxelize(m, inCore.transform, options);
  const fs::path path = tempPath("direct.svo");
  svo::StoreWriteOptions store;
  store.sliceBytes = 1024;
  svo::writeStore(path, tree, inCore.transform, inCore.parameters, store);
  EXPECT_TRUE(sameBlock(inCore, svo::readOctree(path)));
  // svo verify's depth-first walk counts what the builder made: every voxel, and the leaves.
  std::uint64_t leaves = 0;
  const svo::StoreReader reader(path);
  // The directory holds every level's voxels, some of them in cubes below the root's (so the walk crosses
  // from slice to child slice).
  std::vector<std::uint64_t> directoryVoxels(1, 1);
  bool belowRoot = false;
  for (const svo::SliceInfo& s : reader.slices()) {
    if (directoryVoxels.size() <= std::size_t(s.voxelLevel)) directoryVoxels.resize(s.voxelLevel + 1);
    directoryVoxels[s.voxelLevel] += s.voxelCount;
    belowRoot = belowRoot || s.cubeLevel > 0;
  }
  EXPECT_EQ(directoryVoxels, voxelsPerLevel(tree));
  EXPECT_TRUE(belowRoot);
  EXPECT_EQ(reader.verify(nullptr, &leaves), tree.voxels.size());
  EXPECT_EQ(leaves, std::uint64_t(std::count_if(tree.voxels.begin(), tree.voxels.end(),
                                                [](const svo::VoxelRecord& v) { return v.childMask == 0; })));
  fs::remove(path);
}

TEST(Store, SlicesTileEachLevelWithinTheSliceSize) {
  const svo::Octree octree = coloredSphere(8);
  const svo::VoxelTree tree = svo::readBlock(octree.block.view());
  const std::vector<std::uint64_t> expected = voxelsPerLevel(tree);
  for (const std::uint32_t sliceBytes : {256u, 2048u, 65536u}) {
    const fs::path path = tempPath("tile.svo");
    svo::StoreWriteOptions options;
    options.sliceBytes = sliceBytes;
    svo::writeOctree(path, octree, options);
    const svo::StoreReader reader(path);
    std::map<int, std::uint64_t> voxels, parents;
    // What each slice covers, as cubes: its cube, or each sub-cube of its run. (voxel level, cube level,
    // cube)
    std::set<std::tuple<int, int, int, int, int>> cubes;
    std::size_t split = 0, runs = 0;
    std::vector<std::uint32_t> splittable;  // sizes of the slices that could have split further
    for (std::size_t i = 0; i < reader.slices().size(); ++i) {
      const svo::SliceInfo& s = reader.slices()[i];
      voxels[s.voxelLevel] += s.voxelCount;
      parents[s.voxelLevel] += s.parentCount;
      EXPECT_EQ(reader.readSlice(std::uint32_t(i)).size(), s.rawBytes);
      const bool whole = s.firstSlot == 0 && s.lastSlot == 7;
      if (!whole || s.cubeLevel < s.voxelLevel - 1) {
        EXPECT_LE(s.rawBytes, sliceBytes) << "slice " << i;
        splittable.push_back(s.rawBytes);
      }
      split += s.cubeLevel > 0 || !whole;
      runs += !whole;
      std::vector<std::pair<int, glm::ivec3>> covered;
      if (whole) covered.push_back({s.cubeLevel, s.cubeCoord});
      for (int slot = s.firstSlot; !whole && slot <= s.lastSlot; ++slot)
        covered.push_back({s.cubeLevel + 1, svo::childCoord(s.cubeCoord, slot)});
      for (const auto& [cubeLevel, cube] : covered) {
        // Disjoint: no slice of the same level covers this cube or one containing it.
        for (int up = 0; up <= cubeLevel; ++up) {
          const glm::ivec3 c = cube >> (cubeLevel - up);
          EXPECT_EQ(cubes.count({s.voxelLevel, up, c.x, c.y, c.z}), 0u) << "slice " << i << " overlaps";
        }
        cubes.insert({s.voxelLevel, cubeLevel, cube.x, cube.y, cube.z});
      }
    }
    for (std::size_t level = 1; level < expected.size(); ++level) {
      EXPECT_EQ(voxels[int(level)], expected[level]) << "level " << level << ", slice size " << sliceBytes;
      // Every voxel of the level above is some slice's parent (leaves included: their split bit is 0).
      EXPECT_EQ(parents[int(level)], expected[level - 1]) << "level " << level;
    }
    if (sliceBytes <= 2048u) {
      EXPECT_GT(split, 0u) << "small slices must split cubes";
      EXPECT_GT(runs, 0u) << "split cubes pack their sub-cubes into runs";
      // Packing keeps the slices that could split near the slice size: their median is at least half of it.
      std::sort(splittable.begin(), splittable.end());
      EXPECT_GE(2 * splittable[splittable.size() / 2], sliceBytes) << "median of " << splittable.size();
    }
    fs::remove(path);
  }
}

// A small store whose every byte is under some checksum.
std::string smallStore(const fs::path& path) {
  svo::StoreWriteOptions options;
  options.sliceBytes = 512;
  svo::writeOctree(path, coloredSphere(3), options);
  return slurp(path);
}

// What is wrong with the file, as `svo verify` (StoreReader::verify, depth first) finds it; loading it whole
// (loadTree, then the block validator) must find it too, or the message says they disagree.
std::string loadError(const fs::path& path) {
  std::string verified, loaded;
  try {
    svo::StoreReader(path).verify();
  } catch (const std::exception& e) {
    verified = e.what();
  }
  try {
    (void)svo::layoutBlock(svo::StoreReader(path).loadTree());
  } catch (const std::exception& e) {
    loaded = e.what();
  }
  if (verified.empty() != loaded.empty())
    return "verify says '" + verified + "', loadTree says '" + loaded + "'";
  return verified;
}

TEST(Store, EverySingleByteCorruptionIsDetected) {
  const fs::path path = tempPath("corrupt.svo");
  const std::string bytes = smallStore(path);
  ASSERT_EQ(loadError(path), "");
  // Split cubes included: some slice covers a run of the root's sub-cubes, or a cube below it.
  const std::vector<svo::SliceInfo> slices = svo::StoreReader(path).slices();
  ASSERT_TRUE(std::any_of(slices.begin(), slices.end(),
                          [](const svo::SliceInfo& s) { return s.cubeLevel > 0 || !s.wholeCube(); }));
  std::size_t header = 0, directory = 0, slice = 0;
  const svo::StoreHeader h = svo::StoreReader(path).header();
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    for (const unsigned char flip : {0x01, 0x80, 0xFF}) {
      std::string bad = bytes;
      bad[i] = char(bad[i] ^ flip);
      spit(path, bad);
      const std::string error = loadError(path);
      ASSERT_NE(error, "") << "byte " << i << " xor " << int(flip) << " went unnoticed";
      ASSERT_NE(error.find(path.string()), std::string::npos) << error;
    }
    if (i < 256)
      ++header;
    else if (i >= h.directoryOffset)
      ++directory;
    else
      ++slice;
  }
  std::printf("[ STORE    ] %zu bytes x 3 flips detected: %zu header, %zu slice, %zu directory bytes\n",
              bytes.size(), header, slice, directory);
  fs::remove(path);
}

TEST(Store, TruncationsAndForeignFilesGiveClearErrors) {
  const fs::path path = tempPath("trunc.svo");
  const std::string bytes = smallStore(path);
  // Every length through the header and the first slices, then every 7th.
  for (std::size_t length = 0; length < bytes.size(); length += length < 512 ? 1 : 7) {
    spit(path, bytes.substr(0, length));
    const std::string error = loadError(path);
    ASSERT_NE(error, "") << "truncated to " << length << " bytes";
    if (length == 0) EXPECT_NE(error.find("empty file"), std::string::npos) << error;
    if (length > 256) EXPECT_NE(error.find("truncated"), std::string::npos) << error;
  }
  spit(path, "\x89PNG\r\n\x1a\n and more bytes than a header would need to hold, surely");
  EXPECT_NE(loadError(path).find("not an svostream file"), std::string::npos);
  std::string version = bytes;
  version[8] = 1;  // a version-1 (single block) file
  spit(path, version);
  EXPECT_NE(loadError(path).find("unsupported file version 1"), std::string::npos) << loadError(path);
  for (const std::uint32_t unread : {svo::kOldestReadVersion - 1, svo::kFileVersion + 1}) {
    version[8] = char(unread);
    spit(path, version);
    const std::string expected = "unsupported file version " + std::to_string(unread) +
                                 " (this build reads " + std::to_string(svo::kOldestReadVersion) + " to " +
                                 std::to_string(svo::kFileVersion) + ")";
    EXPECT_NE(loadError(path).find(expected), std::string::npos) << loadError(path);
  }
  spit(path, bytes + "trailing");
  EXPECT_NE(loadError(path).find("unexpected bytes after the directory"), std::string::npos);
  EXPECT_NE(loadError(tempPath("missing.svo")).find("no such file"), std::string::npos);
  fs::remove(path);
}

// The store keeps normals as 16-bit lattice codes: a normal off the lattice (not from latticeNormal, as the
// builder's are) is refused rather than silently rounded, and no file is left behind.
TEST(Store, RefusesNormalsOffTheLattice) {
  svo::VoxelTree tree = svo::readBlock(plainTriangles(3).block.view());
  ASSERT_TRUE(tree.hasNormals);
  std::size_t leaf = 1;
  while (tree.voxels[leaf].childMask != 0) ++leaf;
  tree.voxels[leaf].normal = svo::encodeNormal(glm::normalize(glm::vec3(0.3f, 0.2f, 0.9f)));
  ASSERT_NE(svo::latticeNormalBits(svo::octNormalCodeOf(tree.voxels[leaf].normal)), tree.voxels[leaf].normal);
  const fs::path path = tempPath("off-lattice.svo");
  try {
    svo::writeStore(path, tree, {}, {}, {});
    ADD_FAILURE() << "a normal off the lattice was written";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("lattice"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(path));
}

TEST(Store, RejectsBadWriteOptions) {
  svo::StoreWriteOptions options;
  options.sliceBytes = 16;
  EXPECT_THROW(svo::writeOctree(tempPath("bad.svo"), plainTriangles(3), options), std::invalid_argument);
  EXPECT_FALSE(fs::exists(tempPath("bad.svo")));
}

}  // namespace

namespace {

// A store's bytes in memory, counting reads and failing those that reach `failFrom` or beyond.
class CountingSource final : public svo::ByteSource {
 public:
  explicit CountingSource(const fs::path& path) : memory_("counted", bytesOf(path)) {}
  const std::string& name() const override { return memory_.name(); }
  std::uint64_t size() const override { return memory_.size(); }
  std::size_t read(std::uint64_t offset, std::span<std::byte> out) const override {
    ++reads;
    if (offset + out.size() > failFrom) throw svo::TransientSourceError("refused");
    return memory_.read(offset, out);
  }
  mutable int reads = 0;
  std::uint64_t failFrom = ~std::uint64_t(0);

 private:
  static std::vector<std::byte> bytesOf(const fs::path& path) {
    const std::string s = slurp(path);
    std::vector<std::byte> out(s.size());
    std::memcpy(out.data(), s.data(), s.size());
    return out;
  }
  svo::MemorySource memory_;
};

}  // namespace

// fetchSlices reads a run of slices that lie back to back in the file at once, and gives each slice the bytes
// fetchSlice gives it; a failed read keeps the slices before it and names the first slice it was for.
TEST(Store, FetchSlicesReadsRunsAtOnceAndEachSliceAsAlone) {
  const fs::path path = tempPath("fetch_slices.svo");
  svo::StoreWriteOptions options;
  options.sliceBytes = 32768;  // the root cube's first levels fit: a trunk of several slices
  svo::writeOctree(path, coloredSphere(7), options);
  CountingSource source(path);
  const svo::StoreIndex index = svo::readStoreIndex(source);
  const auto& slices = index.slices();
  // The trunk's chain lies back to back (the writer writes a cube's levels in turn); so may others.
  std::vector<std::uint32_t> trunk{index.rootSlices()[0]};
  while (index.childSlices(trunk.back()).size() == 1 &&
         slices[index.childSlices(trunk.back())[0]].wholeCube())
    trunk.push_back(index.childSlices(trunk.back())[0]);
  ASSERT_GE(trunk.size(), 4u);
  for (std::size_t k = 1; k < trunk.size(); ++k)
    ASSERT_EQ(slices[trunk[k]].offset, slices[trunk[k - 1]].offset + slices[trunk[k - 1]].compressedBytes);
  const auto expectEach = [&](std::span<const std::uint32_t> ids, const std::vector<svo::SliceBytes>& got) {
    ASSERT_EQ(got.size(), ids.size());
    for (std::size_t k = 0; k < ids.size(); ++k) {
      svo::SliceBytes alone;
      svo::fetchSlice(source, index, ids[k], alone);
      EXPECT_TRUE(got[k] == alone) << "slice " << ids[k];
    }
  };
  std::vector<svo::SliceBytes> got;
  source.reads = 0;
  svo::fetchSlices(source, index, trunk, got);
  EXPECT_EQ(source.reads, 1);
  expectEach(trunk, got);

  // Apart in the file: one read each.
  const std::vector<std::uint32_t> apart{trunk.back(), trunk.front()};
  got.clear();
  source.reads = 0;
  svo::fetchSlices(source, index, apart, got);
  EXPECT_EQ(source.reads, 2);
  expectEach(apart, got);

  // The second run's read fails: the first run's slices stay, the error names the failed run's first slice
  // and may pass.
  const std::vector<std::uint32_t> broken{trunk[0], trunk[1], trunk[3]};
  source.failFrom = slices[trunk[2]].offset;
  got.clear();
  try {
    svo::fetchSlices(source, index, broken, got);
    ADD_FAILURE() << "a failed read went unreported";
  } catch (const svo::SliceError& e) {
    EXPECT_EQ(e.slice, trunk[3]);
    EXPECT_TRUE(e.transient);
    EXPECT_NE(std::string(e.what()).find("refused"), std::string::npos) << e.what();
  }
  source.failFrom = ~std::uint64_t(0);
  expectEach(std::span(broken).first(2), got);
  fs::remove(path);
}
