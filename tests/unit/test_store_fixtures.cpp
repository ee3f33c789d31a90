// Formats v4 and v5 pinned by fixture stores (tests/data/fixtures; README there). The fixtures are what
// writeStore makes (v5) or made (v4) of voxel trees defined below by integer rules (no mesh, no builder, so a
// builder change cannot move them): a cube's surface, a sphere's with contours and colors, and the cube again
// with 256-byte slices, whose level 3 packs the root cube's sub-cubes into runs. The tests check that
//  - the current reader decodes both versions exactly: header and directory fields read here by byte offset,
//    the first slice decompressed here with zstd and compared byte for byte with its layout worked out by
//    hand from the format (codec.hpp), the first slices' decoded masks, coordinates, normals, contours and
//    colors against hand-derived literals, and every voxel: the loaded store lays out to the block of its
//    tree;
//  - the current writer reproduces the v5 ones byte for byte from the same trees.
// So no change to writer and reader together can change a format unnoticed. A format change must bump
// kFileVersion (store_types.hpp) and add fixtures of the new version, checked by hand as these are.
// SVO_WRITE_FIXTURES=DIR makes StoreFixtures.WriterReproducesThemByteForByte write the newest version's
// fixtures into DIR instead (only for a new version).
#include <gtest/gtest.h>

#include <array>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <xxhash.h>
#include <zstd.h>

#include "reference.hpp"
#include "svo/store/byte_source.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_writer.hpp"

namespace fs = std::filesystem;

namespace {

// ---------------------------------------------------------------------------------------------------------
// The generator: a tree of the voxels a rule occupies, level by level in Morton order.

struct VoxelRule {
  std::function<bool(int level, glm::ivec3 coord)> occupied;  // closed under parents
  std::function<void(int level, glm::ivec3 coord, svo::VoxelRecord&)> attributes;
};

svo::VoxelTree treeOf(int levels, bool colors, bool normals, const VoxelRule& rule) {
  svo::VoxelTree tree;
  tree.hasColors = colors, tree.hasNormals = normals;
  struct Place {
    int level;
    glm::ivec3 coord;
  };
  std::vector<Place> places{{0, glm::ivec3(0)}};
  tree.voxels.emplace_back();
  rule.attributes(0, glm::ivec3(0), tree.voxels[0]);
  for (std::size_t i = 0; i < tree.voxels.size(); ++i) {  // breadth first: children contiguous, slot order
    const Place at = places[i];
    if (at.level == levels) continue;
    std::uint8_t mask = 0;
    for (int slot = 0; slot < 8; ++slot)
      if (rule.occupied(at.level + 1, svo::childCoord(at.coord, slot))) mask |= std::uint8_t(1u << slot);
    if (mask == 0) continue;
    tree.voxels[i].childMask = mask;
    tree.voxels[i].firstChild = std::uint32_t(tree.voxels.size());
    for (int slot = 0; slot < 8; ++slot) {
      if (!(mask >> slot & 1u)) continue;
      places.push_back({at.level + 1, svo::childCoord(at.coord, slot)});
      svo::VoxelRecord r;
      rule.attributes(places.back().level, places.back().coord, r);
      tree.voxels.push_back(r);
    }
  }
  return tree;
}

// Voxels the rule occupies at `level`, by brute force over the level's grid.
std::uint32_t occupiedAt(const VoxelRule& rule, int level) {
  std::uint32_t count = 0;
  const int n = 1 << level;
  for (int z = 0; z < n; ++z)
    for (int y = 0; y < n; ++y)
      for (int x = 0; x < n; ++x) count += rule.occupied(level, {x, y, z});
  return count;
}

// The surface of the scene cube: voxels with a coordinate 0 or 2^level - 1. A voxel's normal is the sum of
// the outward normals of the faces it touches (corner voxels diagonal); the root's is +z.
VoxelRule cubeRule() {
  const auto faces = [](int level, glm::ivec3 c) {
    const int last = (1 << level) - 1;
    glm::ivec3 n(0);
    for (int k = 0; k < 3; ++k) n[k] = (c[k] == last) - (c[k] == 0);
    return level == 0 ? glm::ivec3(0, 0, 1) : n;
  };
  return {[=](int level, glm::ivec3 c) { return level == 0 || faces(level, c) != glm::ivec3(0); },
          [=](int level, glm::ivec3 c, svo::VoxelRecord& r) {
            r.normal = svo::latticeNormal(glm::vec3(faces(level, c)));
          }};
}

// The sphere of radius 3/8 about the scene's centre: voxels whose closed cube its surface meets. Lengths in
// eighths of a voxel of the level, where everything is an integer: a voxel spans [8x, 8x + 8], the centre is
// at 4 * 2^level, the radius is 3 * 2^level.
bool sphereMeets(int level, glm::ivec3 c) {
  const std::int64_t centre = 4ll << level, radius = 3ll << level;
  std::int64_t nearest = 0, farthest = 0;
  for (int k = 0; k < 3; ++k) {
    const std::int64_t lo = 8ll * c[k] - centre, hi = lo + 8;
    const std::int64_t near = lo > 0 ? lo : hi < 0 ? -hi : 0, far = std::max(-lo, hi);
    nearest += near * near, farthest += far * far;
  }
  return nearest <= radius * radius && radius * radius <= farthest;
}
// From the sphere's centre to a voxel's centre, in half voxels of its level.
glm::ivec3 sphereOffset(int level, glm::ivec3 c) {
  return 2 * c + 1 - (1 << level);
}
// The sphere's voxels: normals point from its centre (the root's +z). Contours where the surface passes
// within half a voxel of the voxel's centre: the slab of its tangent plane there, 1/8 voxel thick, along the
// quantized normal. Colors from the voxel's ancestor at level 2 (red, green, blue: its centre's x, y, z
// scaled to 0-255), so levels 3 and 4 inherit them, but for a white band at the finest level's
// y = 2^levels / 2.
VoxelRule sphereRule(int levels) {
  return {sphereMeets, [=](int level, glm::ivec3 c, svo::VoxelRecord& r) {
            const glm::ivec3 d = sphereOffset(level, c);
            r.normal = svo::latticeNormal(level == 0 ? glm::vec3(0, 0, 1) : glm::vec3(d));
            if (level == 0) {
              r.color = svo::packABGR(128, 128, 128);
              return;
            }
            const int colorLevel = std::min(level, 2);
            const glm::ivec3 a = c >> (level - colorLevel);
            const auto channel = [&](int k) {
              return std::uint8_t((2 * a[k] + 1) * 255 / (2 << colorLevel));
            };
            r.color = svo::packABGR(channel(0), channel(1), channel(2));
            if (level == levels && c.y == (1 << levels) / 2) r.color = svo::packABGR(255, 255, 255);
            const double centreDistance = 0.5 * std::sqrt(double(d.x * d.x + d.y * d.y + d.z * d.z));
            const double toSurface = 0.375 * double(1 << level) - centreDistance;  // voxels, outwards
            if (std::abs(toSurface) > 0.5) return;
            const glm::ivec3 q = svo::quantizeContourNormal(glm::dvec3(d));
            const double scale = std::sqrt(double(q.x * q.x + q.y * q.y + q.z * q.z)) / 31.0;  // |q / 31|
            const double plane = scale * toSurface, half = scale / 16.0;
            r.hasContour = svo::encodeContour(q, plane - half, plane + half, r.contour);
          }};
}

// The sphere again with every normal +z: its voxels' normals say nothing of its contours, so format v5 codes
// those of the levels below the first against their parents' contours (kParentContourPrediction).
VoxelRule flatShadedSphereRule(int levels) {
  VoxelRule rule = sphereRule(levels);
  rule.attributes = [sphere = rule.attributes](int level, glm::ivec3 c, svo::VoxelRecord& r) {
    sphere(level, c, r);
    r.normal = svo::latticeNormal(glm::vec3(0, 0, 1));
  };
  return rule;
}

struct Fixture {
  std::string file;
  std::uint32_t version;
  VoxelRule rule;
  svo::VoxelTree tree;
  svo::BuildParameters parameters;
  std::uint32_t sliceBytes;
};

// The scene: [-1, 1]^3.
const svo::SceneTransform kScene{glm::dvec3(-1.0), 2.0};

std::string fileOf(const std::string& name, std::uint32_t version) {
  return name + "-v" + std::to_string(version) + ".svo";
}
Fixture cubeFixture(const std::string& name, std::uint32_t version, int levels, std::uint32_t sliceBytes) {
  const VoxelRule rule = cubeRule();
  return {fileOf(name, version), version,   rule, treeOf(levels, false, true, rule),
          {levels, 0, 0, 0, 0},  sliceBytes};
}
Fixture fixture(const std::string& name, std::uint32_t version) {
  if (name == "cube") return cubeFixture(name, version, 4, svo::kDefaultSliceBytes);
  if (name == "runs") return cubeFixture(name, version, 3, 256);
  const VoxelRule rule = name == "shaded" ? flatShadedSphereRule(4) : sphereRule(4);
  return {fileOf(name, version),       version,         rule,
          treeOf(4, true, true, rule), {4, 0, 0, 0, 1}, svo::kDefaultSliceBytes};
}
// Every version readers decode has fixtures; the writer makes the last. The shaded sphere pins what only
// format v5 has (kParentContourPrediction).
constexpr std::uint32_t kVersions[] = {4, 5};
static_assert(kVersions[0] == svo::kOldestReadVersion && kVersions[1] == svo::kFileVersion);
struct FixtureFile {
  const char* name;
  std::uint32_t version;
};
constexpr FixtureFile kFixtureFiles[] = {{"cube", 4},   {"sphere", 4}, {"runs", 4},  {"cube", 5},
                                         {"sphere", 5}, {"runs", 5},   {"shaded", 5}};

fs::path fixturePath(const Fixture& f) {
  return fs::path(SVO_TEST_DATA) / "fixtures" / f.file;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// ---------------------------------------------------------------------------------------------------------
// Reading the file by byte offset (store_types.hpp and the writer's header and directory records).

template <class T>
T at(const std::string& bytes, std::size_t offset) {
  T v;
  std::memcpy(&v, bytes.data() + offset, sizeof v);
  return v;
}

constexpr std::size_t kHeaderBytes = 256, kEntryBytes = 64;

struct Entry {  // a directory entry's fields
  std::uint64_t offset, checksum;
  std::uint32_t compressed, raw;
  glm::ivec3 cube;
  int cubeLevel, voxelLevel, firstSlot, lastSlot;
  std::uint32_t parents, voxels, contours, colors, normals, parentSlice;
};
Entry entry(const std::string& bytes, std::size_t i) {
  const std::size_t e = at<std::uint64_t>(bytes, 88) + i * kEntryBytes;
  return {at<std::uint64_t>(bytes, e),
          at<std::uint64_t>(bytes, e + 8),
          at<std::uint32_t>(bytes, e + 16),
          at<std::uint32_t>(bytes, e + 20),
          {at<std::int32_t>(bytes, e + 24), at<std::int32_t>(bytes, e + 28), at<std::int32_t>(bytes, e + 32)},
          at<std::uint8_t>(bytes, e + 36),
          at<std::uint8_t>(bytes, e + 37),
          at<std::uint8_t>(bytes, e + 38),
          at<std::uint8_t>(bytes, e + 39),
          at<std::uint32_t>(bytes, e + 40),
          at<std::uint32_t>(bytes, e + 44),
          at<std::uint32_t>(bytes, e + 48),
          at<std::uint32_t>(bytes, e + 52),
          at<std::uint32_t>(bytes, e + 56),
          at<std::uint32_t>(bytes, e + 60)};
}

// The header's fields, and the directory tiling the file, checked against the fixture's input.
void checkHeader(const std::string& bytes, const Fixture& f, bool colors, std::uint32_t sliceCount) {
  ASSERT_GE(bytes.size(), kHeaderBytes);
  EXPECT_EQ(bytes.substr(0, 8), std::string("SVOSTRM\0", 8));
  EXPECT_EQ(at<std::uint32_t>(bytes, 8), f.version);                           // version
  EXPECT_EQ(at<std::uint32_t>(bytes, 12), kHeaderBytes);                       // header bytes
  for (int k = 0; k < 3; ++k) EXPECT_EQ(at<double>(bytes, 16 + 8 * k), -1.0);  // origin
  EXPECT_EQ(at<double>(bytes, 40), 2.0);                                       // size
  EXPECT_EQ(at<std::int32_t>(bytes, 48), f.parameters.levels);
  for (int k = 0; k < 3; ++k) EXPECT_EQ(at<float>(bytes, 52 + 4 * k), 0.0f);  // error bounds
  EXPECT_EQ(at<std::uint32_t>(bytes, 64), f.parameters.contours);
  EXPECT_EQ(at<std::uint32_t>(bytes, 68), colors ? 3u : 2u);  // attachment types: bit 0 colors, 1 normals
  EXPECT_EQ(at<std::uint32_t>(bytes, 72), colors ? svo::packABGR(128, 128, 128) : 0u);  // root color
  EXPECT_EQ(at<std::uint32_t>(bytes, 76), svo::latticeNormalBits(0));  // root normal: +z, octahedral code 0
  EXPECT_EQ(at<std::uint32_t>(bytes, 80), f.sliceBytes);
  EXPECT_EQ(at<std::uint32_t>(bytes, 84), sliceCount);
  const auto directory = at<std::uint64_t>(bytes, 88);
  EXPECT_EQ(at<std::uint64_t>(bytes, 96), sliceCount * kEntryBytes);
  EXPECT_EQ(directory + sliceCount * kEntryBytes, bytes.size());
  EXPECT_EQ(at<std::uint64_t>(bytes, 104), XXH3_64bits(bytes.data() + directory, sliceCount * kEntryBytes));
  for (std::size_t i = 112; i < 248; ++i) EXPECT_EQ(bytes[i], 0) << "reserved header byte " << i;
  EXPECT_EQ(at<std::uint64_t>(bytes, 248), XXH3_64bits(bytes.data(), 248));
  // The slices follow the header in directory order, each under its checksum.
  std::uint64_t offset = kHeaderBytes;
  for (std::uint32_t i = 0; i < sliceCount; ++i) {
    const Entry e = entry(bytes, i);
    EXPECT_EQ(e.offset, offset) << "slice " << i;
    EXPECT_EQ(e.checksum, XXH3_64bits(bytes.data() + e.offset, e.compressed)) << "slice " << i;
    offset += e.compressed;
  }
  EXPECT_EQ(offset, directory);
}

struct ExpectedEntry {
  int voxelLevel, firstSlot, lastSlot;
  std::uint32_t parents, voxels, contours, colors, normals, raw, parentSlice;
};
void checkEntry(const std::string& bytes, std::uint32_t i, const ExpectedEntry& x) {
  SCOPED_TRACE("directory entry " + std::to_string(i));
  const Entry e = entry(bytes, i);
  EXPECT_EQ(e.cube, glm::ivec3(0));  // every fixture slice lies in the root cube
  EXPECT_EQ(e.cubeLevel, 0);
  EXPECT_EQ(e.voxelLevel, x.voxelLevel);
  EXPECT_EQ(e.firstSlot, x.firstSlot);
  EXPECT_EQ(e.lastSlot, x.lastSlot);
  EXPECT_EQ(e.parents, x.parents);
  EXPECT_EQ(e.voxels, x.voxels);
  EXPECT_EQ(e.contours, x.contours);
  EXPECT_EQ(e.colors, x.colors);
  EXPECT_EQ(e.normals, x.normals);
  EXPECT_EQ(e.raw, x.raw);
  EXPECT_EQ(e.parentSlice, x.parentSlice);
}

// Slice i's decoded bytes, decompressed here (not by the reader).
std::vector<std::uint8_t> rawSlice(const std::string& bytes, std::uint32_t i) {
  const Entry e = entry(bytes, i);
  std::vector<std::uint8_t> raw(e.raw);
  const std::size_t got = ZSTD_decompress(raw.data(), raw.size(), bytes.data() + e.offset, e.compressed);
  EXPECT_EQ(got, e.raw) << "slice " << i << " does not decompress to its size";
  return raw;
}

// A slice head, as bytes: magic "SLCE", the counts, the attachment bits.
std::vector<std::uint8_t> head(std::uint32_t parents, std::uint32_t splits, std::uint32_t voxels,
                               std::uint32_t contours, std::uint32_t colors, std::uint32_t normals,
                               std::uint32_t attachments) {
  std::vector<std::uint8_t> out{'S', 'L', 'C', 'E'};
  for (const std::uint32_t v : {parents, splits, voxels, contours, colors, normals, attachments})
    for (int b = 0; b < 32; b += 8) out.push_back(std::uint8_t(v >> b));
  return out;
}
void append(std::vector<std::uint8_t>& to, std::initializer_list<std::uint8_t> bytes) {
  to.insert(to.end(), bytes);
}

// ---------------------------------------------------------------------------------------------------------
// Decoding through the reader.

svo::StoreReader readerOf(const Fixture& f) {
  const std::string bytes = slurp(fixturePath(f));
  const auto* b = reinterpret_cast<const std::byte*>(bytes.data());
  return svo::StoreReader(
      std::make_shared<const svo::MemorySource>(f.file, std::vector<std::byte>(b, b + bytes.size())));
}

// The root and the voxels of the first `slices` slices (one level each), decoded in turn.
svo::VoxelLevels decodeChain(const svo::StoreReader& reader, std::uint32_t slices) {
  const svo::StoreHeader& h = reader.header();
  svo::VoxelLevels levels(1);
  levels[0].push_back({.color = h.rootColor, .normal = h.rootNormal});
  for (std::uint32_t i = 0; i < slices; ++i) {
    std::vector<svo::SliceVoxel> added;
    reader.decodeSlice(i, reader.readSlice(i), levels.back(), added);
    levels.push_back(std::move(added));
  }
  return levels;
}

std::uint16_t code(const svo::SliceVoxel& v) {
  return svo::octNormalCodeOf(v.normal);
}

bool sameBlock(const svo::Block& a, const svo::Block& b) {
  return a.bytes().size() == b.bytes().size() &&
         std::memcmp(a.bytes().data(), b.bytes().data(), a.bytes().size()) == 0;
}

// ---------------------------------------------------------------------------------------------------------
// Octahedral codes (format.hpp) of the fixtures' first normals, worked out by hand: a direction scaled to
// |x| + |y| + |z| = 1; the upper half (z >= 0) keeps (x, y), the lower folds to ((1 - |y|) sign x,
// (1 - |x|) sign y); each rounded to 127ths (halves away from zero), as int8, x in the high byte.
// Corners (+-1, +-1, +-1): (+-1/3, +-1/3) -> +-42 (0x2A, 0xD6) above, (+-2/3, +-2/3) -> +-85 (0x55, 0xAB)
// below. Edges and faces of the lower half: (0, -1, -1) -> (1/2, -1) -> 0x4081, (-1, 0, -1) -> 0x8140,
// (0, 0, -1) -> (1, 1) -> 0x7F7F; of the upper half: (-1, -1, 0) -> (-1/2, -1/2) -> 0xC0C0, (0, -1, 0) ->
// 0x0081, (-1, 0, 0) -> 0x8100.
constexpr std::uint16_t kCornerCodes[8] = {0xABAB, 0x55AB, 0xAB55, 0x5555, 0xD6D6, 0x2AD6, 0xD62A, 0x2A2A};

// Slice 0 of both cubes: level 1 of the root cube, all 8 octants, each with its corner's normal.
std::vector<std::uint8_t> cubeSlice0() {
  std::vector<std::uint8_t> raw = head(1, 1, 8, 0, 0, 8, 2);
  append(raw, {0x01, 0xFF});  // the root splits into all 8 slots
  append(raw, {0x00});        // no contours
  // Normals: all 8 stored; residuals against the root's code 0 are the codes, x bytes then y bytes.
  append(raw, {0xFF, 0xAB, 0x55, 0xAB, 0x55, 0xD6, 0x2A, 0xD6, 0x2A, 0xAB, 0xAB, 0x55, 0x55, 0xD6, 0xD6, 0x2A,
               0x2A});
  return raw;
}

// Levels 1 and 2 of the cube's surface, the same in both cube stores: 8 corner voxels at level 1, and below
// them 8 corners, 24 edge and 24 face voxels (see CubeDecodesAsWorkedOutByHand).
void checkCubeTop(const std::string& bytes) {
  checkEntry(bytes, 0, {1, 0, 7, 1, 8, 0, 0, 8, 52, svo::SliceInfo::kNoSlice});
  checkEntry(bytes, 1, {2, 0, 7, 8, 56, 0, 0, 48, 151, 0});
  EXPECT_EQ(rawSlice(bytes, 0), cubeSlice0());
}

void checkCube(const Fixture& f) {
  const std::string bytes = slurp(fixturePath(f));
  checkHeader(bytes, f, false, 4);
  // Level L has n^3 - (n - 2)^3 voxels, n = 2^L; a corner voxel has 7 children (6 store a normal: the one
  // in the corner inherits), an edge voxel 6 (4), a face voxel 4 (0). Level 1: 8 corners; level 2: 8
  // corners, 24 edge, 24 face voxels; level 3: 8, 72, 216.
  checkCubeTop(bytes);
  checkEntry(bytes, 2, {3, 0, 7, 56, 296, 0, 0, 144, 457, 1});
  checkEntry(bytes, 3, {4, 0, 7, 296, 1352, 0, 0, 336, 1375, 2});
  // Slice 1 by hand up to its normals: octant s misses its child 7 - s (the cube's inside); its child s
  // (in the cube's corner, index s or s - 1 among its 7) inherits the octant's normal.
  std::vector<std::uint8_t> slice1 = head(8, 8, 56, 0, 0, 48, 2);
  append(slice1, {0xFF, 0x7F, 0xBF, 0xDF, 0xEF, 0xF7, 0xFB, 0xFD, 0xFE});
  append(slice1, {0, 0, 0, 0, 0, 0, 0});                       // no contours
  append(slice1, {0xFE, 0xFE, 0xFE, 0x7E, 0x7F, 0x7F, 0x7F});  // all but voxels 0, 8, 16, 24, 31, 39, 47, 55
  // Octant 0's (code 0xABAB) children 1-6: (1,0,0) faces -y -z, (0,1,0) -x -z, (1,1,0) -z, (0,0,1) -x -y,
  // (1,0,1) -y, (0,1,1) -x; residuals are their codes minus 0xAB per byte.
  const std::uint8_t x0[] = {0x95, 0xD6, 0xD4, 0x15, 0x55, 0xD6}, y0[] = {0xD6, 0x95, 0xD4, 0x15, 0xD6, 0x55};
  const std::vector<std::uint8_t> raw1 = rawSlice(bytes, 1);
  ASSERT_EQ(raw1.size(), 151u);
  EXPECT_EQ(std::vector<std::uint8_t>(raw1.begin(), raw1.begin() + 55), slice1);
  EXPECT_EQ(std::vector<std::uint8_t>(raw1.begin() + 55, raw1.begin() + 61), std::vector(x0, x0 + 6));
  EXPECT_EQ(std::vector<std::uint8_t>(raw1.begin() + 103, raw1.begin() + 109), std::vector(y0, y0 + 6));

  const svo::StoreReader reader = readerOf(f);
  EXPECT_EQ(reader.index().trunkLevels(), 4) << "one slice per level, all of the root cube";
  const svo::VoxelLevels levels = decodeChain(reader, 2);
  EXPECT_EQ(levels[0][0].childMask, 0xFF);
  ASSERT_EQ(levels[1].size(), 8u);
  for (int s = 0; s < 8; ++s) {
    EXPECT_EQ(levels[1][s].coord, svo::childCoord(glm::ivec3(0), s));
    EXPECT_EQ(code(levels[1][s]), kCornerCodes[s]) << "octant " << s;
    EXPECT_EQ(levels[1][s].childMask, 0xFF & ~(1 << (7 - s))) << "octant " << s;
    EXPECT_FALSE(levels[1][s].hasContour);
  }
  ASSERT_EQ(levels[2].size(), 56u);
  const glm::ivec3 coords[7] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0, 0, 1}, {1, 0, 1}, {0, 1, 1}};
  const std::uint16_t codes[7] = {0xABAB, 0x4081, 0x8140, 0x7F7F, 0xC0C0, 0x0081, 0x8100};
  for (int k = 0; k < 7; ++k) {
    EXPECT_EQ(levels[2][k].coord, coords[k]);
    EXPECT_EQ(code(levels[2][k]), codes[k]) << "voxel " << k;
  }
}

void checkSphere(const Fixture& f) {
  const std::string bytes = slurp(fixturePath(f));
  checkHeader(bytes, f, true, 4);
  // Levels 1 and 2 by hand: every octant meets the sphere; of its children at level 2 all but the outer
  // corner (child s of octant s). Contours at level 1: all 8; at level 2, 3 per octant (the ones with two
  // faces on the octant's inner sides). Colors: all stored at levels 1 and 2. Normals: octants all; their
  // inner corner child inherits.
  checkEntry(bytes, 0, {1, 0, 7, 1, 8, 8, 8, 8, 125, svo::SliceInfo::kNoSlice});
  checkEntry(bytes, 1, {2, 0, 7, 8, 56, 24, 56, 48, 502, 0});
  // Levels 3 and 4: the voxel counts of a brute-force count over the grid.
  for (std::uint32_t i = 2; i < 4; ++i) {
    const Entry e = entry(bytes, i);
    EXPECT_EQ(e.voxelLevel, int(i + 1));
    EXPECT_EQ(e.parents, occupiedAt(f.rule, int(i)));
    EXPECT_EQ(e.voxels, occupiedAt(f.rule, int(i + 1)));
    EXPECT_EQ(e.parentSlice, i - 1);
  }
  // Slice 0: octant s at offset (+-1, +-1, +-1) half voxels. Contour: normal (+-31, +-31, +-31); the tangent
  // plane lies 0.75 - sqrt(3)/2 = -0.116 voxels out, so along the normal (|n| = sqrt 3) at -0.2010 +- 0.1083
  // (1/16 voxel x |n|): position round(-0.2010 / (1.5/63)) = -8, thickness ceil(2 x 0.1187 / (3/127)) = 11.
  // Residuals: the normal's code (kCornerCodes) predicts (+-30, +-30, +-31), so +-1 (63 for -1) in x and y;
  // the root has no contour, so the position is its own (-8 = 0x78 mod 128).
  std::vector<std::uint8_t> slice0 = head(1, 1, 8, 8, 8, 8, 3);
  append(slice0, {0x01, 0xFF, 0xFF});
  append(slice0, {0x3F, 0x01, 0x3F, 0x01, 0x3F, 0x01, 0x3F, 0x01});  // normal x residuals
  append(slice0, {0x3F, 0x3F, 0x01, 0x01, 0x3F, 0x3F, 0x01, 0x01});  // normal y residuals
  append(slice0, {0, 0, 0, 0, 0, 0, 0, 0});                          // normal z residuals
  append(slice0, {0x78, 0x78, 0x78, 0x78, 0x78, 0x78, 0x78, 0x78});  // positions
  append(slice0, {0x0B, 0x0B, 0x0B, 0x0B, 0x0B, 0x0B, 0x0B, 0x0B});  // thicknesses
  append(slice0, {0xFF});  // colors: channels 63 or 191 by octant (x red, y green, z blue), alpha 255
  for (int s = 0; s < 8; ++s) {
    const auto channel = [&](int bit) { return std::uint8_t(s & bit ? 0xBF : 0x3F); };
    append(slice0, {channel(1), channel(2), channel(4), 0xFF});
  }
  append(slice0, {0xFF, 0xAB, 0x55, 0xAB, 0x55, 0xD6, 0x2A, 0xD6, 0x2A, 0xAB, 0xAB, 0x55, 0x55, 0xD6, 0xD6,
                  0x2A, 0x2A});
  EXPECT_EQ(rawSlice(bytes, 0), slice0);

  const svo::StoreReader reader = readerOf(f);
  const svo::VoxelLevels levels = decodeChain(reader, 2);
  ASSERT_EQ(levels[1].size(), 8u);
  for (int s = 0; s < 8; ++s) {
    const svo::SliceVoxel& v = levels[1][s];
    const int sx = s & 1 ? 31 : -31, sy = s & 2 ? 31 : -31, sz = s & 4 ? 31 : -31;
    EXPECT_EQ(v.childMask, 0xFF & ~(1 << s)) << "octant " << s;
    EXPECT_TRUE(v.hasContour);
    EXPECT_EQ(v.contour, svo::packContourBits(sx, sy, sz, -8, 11)) << "octant " << s;
    EXPECT_EQ(code(v), kCornerCodes[s]);
    EXPECT_EQ(v.color, svo::packABGR(s & 1 ? 191 : 63, s & 2 ? 191 : 63, s & 4 ? 191 : 63));
  }
  // Octant 0's children: slots 1-7; contours on (1,1,0), (1,0,1), (0,1,1). For (1,1,0), offset (-1, -1, -3):
  // normal round((-1, -1, -3) x 31/3) = (-10, -10, -31); the surface 1.5 - sqrt(11)/2 = -0.1583 out, along
  // |n| = sqrt(1161)/31 = 1.0991 at -0.1740 +- 0.0687: position round(-7.31) = -7, thickness
  // ceil(6.44) = 7. Colors channels 31 or 95 at level 2.
  const glm::ivec3 coords[7] = {{1, 0, 0}, {0, 1, 0}, {1, 1, 0}, {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}};
  for (int k = 0; k < 7; ++k) {
    const svo::SliceVoxel& v = levels[2][k];
    EXPECT_EQ(v.coord, coords[k]);
    EXPECT_EQ(v.hasContour, k == 2 || k == 4 || k == 5) << "voxel " << k;
    EXPECT_EQ(v.color, svo::packABGR(coords[k].x ? 95 : 31, coords[k].y ? 95 : 31, coords[k].z ? 95 : 31));
  }
  EXPECT_EQ(levels[2][2].contour, svo::packContourBits(-10, -10, -31, -7, 7));
  EXPECT_EQ(code(levels[2][6]), kCornerCodes[0]);  // (1,1,1) lies on octant 0's diagonal: inherits
  // Its residual bytes: the code (-102, -102) of (-1, -1, -3) predicts the normal exactly (so format v5 keeps
  // that prediction: the head's bit 2 is clear); octant 0's contour predicts position
  // round((62 x -8 + 21 x 31) / 31) = 5 for slot 3, so -7 - 5 = -12 (0x74).
  // Contour presence: octant s lists its children c != s in slot order; those on two of its inner sides
  // (c and s differ in two bits) have contours.
  std::vector<std::uint8_t> contourBits(7, 0);
  std::size_t voxel = 0;
  for (int s = 0; s < 8; ++s)
    for (int c = 0; c < 8; ++c) {
      if (c == s) continue;
      if (std::popcount(unsigned(c ^ s)) == 2) contourBits[voxel / 8] |= std::uint8_t(1u << (voxel % 8));
      ++voxel;
    }
  const std::vector<std::uint8_t> raw1 = rawSlice(bytes, 1);
  ASSERT_EQ(raw1.size(), 502u);
  EXPECT_EQ(std::vector<std::uint8_t>(raw1.begin() + 41, raw1.begin() + 48), contourBits);
  const std::size_t contours = 48;  // head 32, split bits 1, masks 8, contour presence bits 7
  EXPECT_EQ(raw1[28], 3) << "attachment bits: colors, normals";
  for (std::size_t plane = 0; plane < 5; ++plane)
    EXPECT_EQ(raw1[contours + 24 * plane], (std::array<std::uint8_t, 5>{0, 0, 0, 0x74, 7}[plane])) << plane;
  EXPECT_EQ(code(levels[2][2]), 0x9A9A);
}

// Format v5 only: the sphere with every normal +z (flatShadedSphereRule). Its first slice codes the octants'
// contours as the sphere's does, against the root's +z: the store predicts (0, 0, 31) from it, so residuals
// (+-31 - 0, +-31 - 0, +-31 - 31) = (31 or 33, 31 or 33, 0 or 2); the root has no contour, so both
// predictions agree and the head's bit 2 stays clear. Its second slice's contours are far from (0, 0, 31)
// but near their parents' (+-31, +-31, +-31): the writer sets bit 2, and the first, child (1,1,0) of octant
// 0 with normal (-10, -10, -31), has residuals (21, 21, 0).
void checkShaded(const Fixture& f) {
  const std::string bytes = slurp(fixturePath(f));
  checkHeader(bytes, f, true, 4);
  checkEntry(bytes, 0, {1, 0, 7, 1, 8, 8, 8, 0, 109, svo::SliceInfo::kNoSlice});
  std::vector<std::uint8_t> slice0 = head(1, 1, 8, 8, 8, 0, 3);
  append(slice0, {0x01, 0xFF, 0xFF});
  for (const int bit : {1, 2})
    for (int s = 0; s < 8; ++s) slice0.push_back(s & bit ? 0x1F : 0x21);  // x, y residuals
  for (int s = 0; s < 8; ++s) slice0.push_back(s & 4 ? 0x00 : 0x02);      // z residuals
  append(slice0, {0x78, 0x78, 0x78, 0x78, 0x78, 0x78, 0x78, 0x78});       // positions, as the sphere's
  append(slice0, {0x0B, 0x0B, 0x0B, 0x0B, 0x0B, 0x0B, 0x0B, 0x0B});       // thicknesses
  append(slice0, {0xFF});
  for (int s = 0; s < 8; ++s) {
    const auto channel = [&](int bit) { return std::uint8_t(s & bit ? 0xBF : 0x3F); };
    append(slice0, {channel(1), channel(2), channel(4), 0xFF});
  }
  append(slice0, {0x00});  // every normal +z: all inherit the root's
  EXPECT_EQ(rawSlice(bytes, 0), slice0);

  const std::vector<std::uint8_t> raw1 = rawSlice(bytes, 1);
  ASSERT_GT(raw1.size(), 48u + 5 * 24u);
  EXPECT_EQ(raw1[28], 7) << "attachment bits: colors, normals, kParentContourPrediction";
  for (std::size_t plane = 0; plane < 5; ++plane)
    EXPECT_EQ(raw1[48 + 24 * plane], (std::array<std::uint8_t, 5>{21, 21, 0, 0x74, 7}[plane])) << plane;

  const svo::VoxelLevels levels = decodeChain(readerOf(f), 2);
  ASSERT_EQ(levels[2].size(), 56u);
  EXPECT_EQ(levels[2][2].contour, svo::packContourBits(-10, -10, -31, -7, 7));
  for (const svo::SliceVoxel& v : levels[2]) EXPECT_EQ(v.normal, svo::latticeNormal(glm::vec3(0, 0, 1)));
}

void checkRuns(const Fixture& f) {
  const std::string bytes = slurp(fixturePath(f));
  checkHeader(bytes, f, false, 4);
  // Level 3 of the whole cube takes 457 bytes > 256: its 8 octants (each 7 parents, 37 voxels, 18 normals)
  // pack into runs. k octants take 32 + ceil(7k/8) + 7k + 2 ceil(37k/8) + 36k bytes: 86, 140, 192, 246, 300,
  // ...; the share is 457 / 2 = 228.5, so each run grows while it fits and nears the share: 0-3 and 4-7.
  checkCubeTop(bytes);
  checkEntry(bytes, 2, {3, 0, 3, 28, 148, 0, 0, 72, 246, 1});
  checkEntry(bytes, 3, {3, 4, 7, 28, 148, 0, 0, 72, 246, 1});

  const svo::StoreReader reader = readerOf(f);
  EXPECT_FALSE(reader.slices()[2].wholeCube());
  EXPECT_EQ(reader.index().trunkLevels(), 2) << "level 3 is in the octants' runs";
  svo::VoxelLevels levels = decodeChain(reader, 2);
  // The run's parents: octants 0-3's level-2 voxels, the first 28 in Morton order. Octant 0's, in order:
  // (0,0,0) a corner: all children but (1,1,1); (1,0,0) on -y and -z: children with y or z 0; (0,1,0) on -x,
  // -z; (1,1,0) on -z; (0,0,1) on -x, -y; (1,0,1) on -y; (0,1,1) on -x.
  std::vector<svo::SliceVoxel> added;
  reader.decodeSlice(2, reader.readSlice(2), std::span(levels[2]).first(28), added);
  EXPECT_EQ(added.size(), 148u);
  const std::uint8_t masks[7] = {0x7F, 0x3F, 0x5F, 0x0F, 0x77, 0x33, 0x55};
  for (int k = 0; k < 7; ++k) EXPECT_EQ(levels[2][k].childMask, masks[k]) << "parent " << k;
  EXPECT_EQ(levels[2][28].childMask, 0) << "a parent of the other run";
  EXPECT_EQ(added[0].coord, glm::ivec3(0));
  EXPECT_EQ(code(added[0]), kCornerCodes[0]);  // inherits the corner's normal
  EXPECT_EQ(added[1].coord, glm::ivec3(1, 0, 0));
  EXPECT_EQ(code(added[1]), 0x4081);
}

}  // namespace

// Both versions: the cube has no contours, so only the header's version differs.
TEST(StoreFixtures, CubeDecodesAsWorkedOutByHand) {
  for (const std::uint32_t version : kVersions) {
    SCOPED_TRACE("format v" + std::to_string(version));
    checkCube(fixture("cube", version));
  }
}

TEST(StoreFixtures, SphereDecodesAsWorkedOutByHand) {
  for (const std::uint32_t version : kVersions) {
    SCOPED_TRACE("format v" + std::to_string(version));
    checkSphere(fixture("sphere", version));
  }
}

TEST(StoreFixtures, ShadedSphereDecodesAsWorkedOutByHand) {
  checkShaded(fixture("shaded", 5));
}

// Bit 2 of a slice head means nothing in format v4: the same slice under a v4 header is refused.
TEST(StoreFixtures, AVersion4HeaderRefusesParentContourPrediction) {
  const svo::StoreReader reader = readerOf(fixture("shaded", 5));
  svo::VoxelLevels levels = decodeChain(reader, 1);
  svo::StoreHeader v4 = reader.header();
  v4.version = 4;
  std::vector<svo::SliceVoxel> added;
  const svo::SliceBytes raw = reader.readSlice(1);
  EXPECT_THROW(svo::decodeSlice(std::span(raw.data(), raw.size()), reader.slices()[1], v4, levels[1], added),
               svo::SliceDecodeError);
  EXPECT_NO_THROW(svo::decodeSlice(std::span(raw.data(), raw.size()), reader.slices()[1], reader.header(),
                                   levels[1], added));
}

TEST(StoreFixtures, RunsDecodeAsWorkedOutByHand) {
  for (const std::uint32_t version : kVersions) {
    SCOPED_TRACE("format v" + std::to_string(version));
    checkRuns(fixture("runs", version));
  }
}

// Every voxel, every slice: the store loaded whole lays out to the block of the tree it was written from,
// and svo verify's walk counts that tree's voxels.
TEST(StoreFixtures, ReaderDecodesEveryVoxel) {
  for (const auto& [name, version] : kFixtureFiles) {
    const Fixture f = fixture(name, version);
    SCOPED_TRACE(f.file);
    const svo::StoreReader reader = readerOf(f);
    EXPECT_TRUE(sameBlock(svo::layoutBlock(reader.loadTree()), svo::layoutBlock(f.tree)));
    EXPECT_EQ(reader.verify(), f.tree.voxels.size());
    EXPECT_EQ(reader.header().transform.origin, kScene.origin);
    EXPECT_EQ(reader.header().transform.size, kScene.size);
  }
}

TEST(StoreFixtures, WriterReproducesThemByteForByte) {
  const char* regenerate = std::getenv("SVO_WRITE_FIXTURES");
  for (const auto& [name, version] : kFixtureFiles) {
    if (version != svo::kFileVersion) continue;
    const Fixture f = fixture(name, version);
    svo::StoreWriteOptions options;
    options.sliceBytes = f.sliceBytes;
    if (regenerate && *regenerate) {
      svo::writeStore(fs::path(regenerate) / f.file, f.tree, kScene, f.parameters, options);
      continue;
    }
    const svotest::TempFile written("svo_fixture", ".svo");
    svo::writeStore(written.path, f.tree, kScene, f.parameters, options);
    EXPECT_TRUE(slurp(written.path) == slurp(fixturePath(f))) << f.file << " is not what the writer makes";
  }
  if (regenerate && *regenerate) GTEST_SKIP() << "wrote the fixtures into " << regenerate;
}
