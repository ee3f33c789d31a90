// The streaming triangle source: binary PLY read batch by batch from the file, compared with what loadMesh
// loads from the same file and with PLY bytes the test wrote itself.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/gen.hpp"
#include "svo/builder/mesh.hpp"

namespace fs = std::filesystem;
using svotest::srgbToLinearRef;
using svotest::TempDir;

namespace {

// Little-endian bytes of a binary PLY, appended field by field.
struct PlyBytes {
  std::string bytes;
  template <class T>
  PlyBytes& put(T value) {
    bytes.append(reinterpret_cast<const char*>(&value), sizeof value);
    return *this;
  }
};

std::vector<svo::SourceTriangle> readAll(const svo::TriangleSource& source) {
  std::vector<svo::SourceTriangle> all;
  source.read(
      [&](std::span<const svo::SourceTriangle> batch) { all.insert(all.end(), batch.begin(), batch.end()); });
  return all;
}

std::string errorOfSource(const fs::path& path) {
  try {
    svo::openTriangleSource(path);
  } catch (const std::runtime_error& e) {
    return e.what();
  }
  return "no error";
}

}  // namespace

TEST(TriangleSource, BinaryPlyStreamsExactlyWhatLoadMeshLoads) {
  TempDir dir;
  svo::GenOptions gen;
  gen.kind = svo::SceneKind::Terrain;
  gen.triangles = 5000;
  svo::Mesh generated = svo::generateScene(gen);
  generated.triangles.push_back({0, 0, 1});  // degenerate: both readers drop it
  const fs::path ply = dir.path() / "terrain.ply";
  svo::writePly(ply, generated);

  svo::MeshLoadReport report;
  const svo::Mesh loaded = svo::loadMesh(ply, &report);  // assimp: the independent reader
  const auto streamed = svo::openTriangleSource(ply);
  EXPECT_NE(streamed->format().find("streamed"), std::string::npos) << streamed->format();
  EXPECT_EQ(streamed->droppedDegenerate(), report.droppedDegenerate);
  EXPECT_EQ(streamed->droppedDegenerate(), 1u);
  EXPECT_TRUE(streamed->hasColor());
  EXPECT_TRUE(streamed->hasVertexColors());
  const auto reference = svo::meshTriangleSource(loaded);
  EXPECT_EQ(streamed->lower(), reference->lower());
  EXPECT_EQ(streamed->upper(), reference->upper());
  const std::vector<svo::SourceTriangle> got = readAll(*streamed), want = readAll(*reference);
  ASSERT_EQ(got.size(), want.size());
  ASSERT_EQ(streamed->triangleCount(), want.size());
  std::size_t differing = 0;
  for (std::size_t t = 0; t < got.size(); ++t)
    differing += got[t].positions != want[t].positions || got[t].colors != want[t].colors ||
                 got[t].normals != want[t].normals;
  EXPECT_EQ(differing, 0u) << "of " << got.size() << " triangles";
  // A terrain is smooth: its corners take their vertices' normals, not their triangles'.
  std::size_t smoothCorners = 0;
  for (const svo::SourceTriangle& t : got) {
    const glm::dvec3 face =
        glm::normalize(glm::cross(t.positions[1] - t.positions[0], t.positions[2] - t.positions[0]));
    for (const glm::vec3& n : t.normals) smoothCorners += glm::dot(glm::dvec3(n), face) < 1.0 - 1e-6;
  }
  EXPECT_GT(smoothCorners, got.size());
  // Two passes give the same triangles (the out-of-core build reads twice).
  EXPECT_EQ(readAll(*streamed).size(), got.size());

  // The fingerprint is the content's: the same for the same bytes, another for one changed byte.
  EXPECT_EQ(svo::openTriangleSource(ply)->fingerprint(), streamed->fingerprint());
  std::string bytes;
  {
    std::ifstream in(ply, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), {});
  }
  bytes[bytes.size() - 4] ^= 0x01;  // the last face's last index, 1 -> 0: still a valid (degenerate) face
  EXPECT_NE(svo::openTriangleSource(dir.file("changed.ply", bytes))->fingerprint(), streamed->fingerprint());
}

TEST(TriangleSource, BinaryPlyFansPolygonsSkipsUnknownPropertiesAndDecodesColors) {
  TempDir dir;
  // Vertices with an extra double property between position and color; faces with a ushort count, a quad,
  // a degenerate triangle and a scalar after the index list; elements before the vertices and between the
  // vertices and the faces.
  const std::string header =
      "ply\nformat binary_little_endian 1.0\ncomment hand-made\nelement extra 3\nproperty short s\n"
      "element vertex 5\nproperty float x\n"
      "property float y\nproperty float z\nproperty double quality\nproperty uchar red\nproperty uchar "
      "green\n"
      "property uchar blue\nproperty uchar alpha\nelement material 2\nproperty int id\n"
      "element face 3\nproperty list ushort uint vertex_indices\nproperty uchar flags\nend_header\n";
  PlyBytes b;
  b.put(std::int16_t(-1)).put(std::int16_t(2)).put(std::int16_t(3));
  const float xyz[5][3] = {{0, 0, 0}, {2, 0, 0}, {2, 3, 0}, {0, 3, 0}, {1, 1, 5}};
  const std::uint8_t rgba[5][4] = {
      {255, 0, 0, 255}, {0, 128, 0, 255}, {0, 0, 64, 128}, {10, 20, 30, 40}, {1, 2, 3, 4}};
  for (int v = 0; v < 5; ++v) {
    b.put(xyz[v][0]).put(xyz[v][1]).put(xyz[v][2]).put(0.5);
    for (int k = 0; k < 4; ++k) b.put(rgba[v][k]);
  }
  b.put(std::int32_t(7)).put(std::int32_t(8));
  b.put(std::uint16_t(4)).put(0u).put(1u).put(2u).put(3u).put(std::uint8_t(9));  // quad: 2 triangles
  b.put(std::uint16_t(3)).put(0u).put(0u).put(4u).put(std::uint8_t(9));          // degenerate
  b.put(std::uint16_t(3)).put(0u).put(1u).put(4u).put(std::uint8_t(9));
  const auto source = svo::openTriangleSource(dir.file("hand.ply", header + b.bytes));
  EXPECT_EQ(source->triangleCount(), 3u);
  EXPECT_EQ(source->droppedDegenerate(), 1u);
  EXPECT_EQ(source->lower(), glm::dvec3(0, 0, 0));
  EXPECT_EQ(source->upper(), glm::dvec3(2, 3, 5));
  const std::vector<svo::SourceTriangle> all = readAll(*source);
  ASSERT_EQ(all.size(), 3u);
  double area = 0.0;
  for (int t = 0; t < 2; ++t)
    area += 0.5 * glm::length(glm::cross(all[t].positions[1] - all[t].positions[0],
                                         all[t].positions[2] - all[t].positions[0]));
  EXPECT_DOUBLE_EQ(area, 6.0);  // the 2 x 3 quad
  EXPECT_EQ(all[2].positions[2], glm::dvec3(1, 1, 5));
  // Vertex 2's color, decoded by the sRGB formula; alpha is linear.
  const glm::vec4 c = all[0].colors[2];
  EXPECT_NEAR(c.r, 0.0, 1e-6);
  EXPECT_NEAR(c.b, srgbToLinearRef(64 / 255.0), 1e-5);
  EXPECT_NEAR(c.a, 128 / 255.0, 1e-6);
}

// A PLY with nx, ny, nz (floats here, doubles for ny) streams them as its corners' normals, as they are and
// as loadMesh (assimp) reads them.
TEST(TriangleSource, BinaryPlyStreamsTheFilesNormals) {
  TempDir dir;
  const std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
      "property float z\nproperty float nx\nproperty double ny\nproperty float nz\nelement face 2\n"
      "property list uchar int vertex_indices\nend_header\n";
  const float xyz[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0.5f}, {0, 1, 0}};
  const float n[4][3] = {{0, 0, 1}, {0.6f, 0, 0.8f}, {0, 0.28f, 0.96f}, {0, 0, 2}};  // the last not unit
  PlyBytes b;
  for (int v = 0; v < 4; ++v)
    b.put(xyz[v][0]).put(xyz[v][1]).put(xyz[v][2]).put(n[v][0]).put(double(n[v][1])).put(n[v][2]);
  b.put(std::uint8_t(3)).put(0).put(1).put(2);
  b.put(std::uint8_t(3)).put(0).put(2).put(3);
  const fs::path ply = dir.file("normals.ply", header + b.bytes);
  const std::vector<svo::SourceTriangle> got = readAll(*svo::openTriangleSource(ply));
  const svo::Mesh loaded = svo::loadMesh(ply);
  ASSERT_EQ(loaded.normals.size(), loaded.positions.size());
  const std::vector<svo::SourceTriangle> want = readAll(*svo::meshTriangleSource(loaded));
  ASSERT_EQ(got.size(), 2u);
  ASSERT_EQ(want.size(), 2u);
  const int corners[2][3] = {{0, 1, 2}, {0, 2, 3}};
  for (int t = 0; t < 2; ++t) {
    EXPECT_EQ(got[t].normals, want[t].normals) << "triangle " << t;
    for (int k = 0; k < 3; ++k)
      EXPECT_EQ(got[t].normals[k], glm::vec3(n[corners[t][k]][0], n[corners[t][k]][1], n[corners[t][k]][2]));
  }
}

// A range of a streamed PLY starts at the face noted nearest before it (every 2^16 triangles) and must give
// exactly that stretch of the whole read: polygons fanned across the noted faces, degenerate faces dropped.
TEST(TriangleSource, ARangeIsThatStretchOfTheWholeRead) {
  TempDir dir;
  constexpr int kSide = 300;  // a height field's grid of vertices
  constexpr std::uint32_t kFaces = 80000;
  const std::string header =
      "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(kSide * kSide) +
      "\nproperty float x\nproperty float y\nproperty float z\nelement face " + std::to_string(kFaces) +
      "\nproperty list uchar int vertex_indices\nend_header\n";
  PlyBytes b;
  for (int y = 0; y < kSide; ++y)
    for (int x = 0; x < kSide; ++x) b.put(float(x)).put(float(y)).put(float((x * 7 + y * 13) % 5));
  const auto at = [](int x, int y) { return std::int32_t(y * kSide + x); };
  std::uint64_t expected = 0;
  for (std::uint32_t f = 0; f < kFaces; ++f) {
    const int x = int(f % (kSide - 2)), y = int(f / (kSide - 2) % (kSide - 2));
    if (f % 1000 == 999) {  // degenerate
      b.put(std::uint8_t(3)).put(at(x, y)).put(at(x, y)).put(at(x + 1, y));
    } else if (f % 3 == 0) {  // a pentagon: 3 triangles
      b.put(std::uint8_t(5)).put(at(x, y)).put(at(x + 1, y)).put(at(x + 2, y + 1)).put(at(x + 1, y + 2));
      b.put(at(x, y + 1));
      expected += 3;
    } else if (f % 3 == 1) {  // a quad: 2 triangles
      b.put(std::uint8_t(4)).put(at(x, y)).put(at(x + 1, y)).put(at(x + 1, y + 1)).put(at(x, y + 1));
      expected += 2;
    } else {
      b.put(std::uint8_t(3)).put(at(x, y)).put(at(x + 1, y)).put(at(x, y + 1));
      expected += 1;
    }
  }
  const auto source = svo::openTriangleSource(dir.file("polygons.ply", header + b.bytes));
  const std::vector<svo::SourceTriangle> all = readAll(*source);
  ASSERT_EQ(all.size(), expected);
  ASSERT_EQ(source->triangleCount(), expected);
  ASSERT_GT(expected, 2u << 16);  // three stretches between noted faces at least
  const std::uint64_t n = expected, kNoted = 1u << 16;
  const std::vector<std::pair<std::uint64_t, std::uint64_t>> ranges = {{0, 1},
                                                                       {5, 5},
                                                                       {kNoted - 1, kNoted + 2},
                                                                       {kNoted + 1, 2 * kNoted + 7},
                                                                       {100, n - 100},
                                                                       {n / 3, 2 * n / 3},
                                                                       {n - 1, n},
                                                                       {n - 3, n + 50},
                                                                       {0, n}};
  for (const auto& [first, last] : ranges) {
    std::vector<svo::SourceTriangle> got;
    source->readRange(first, last, [&](std::span<const svo::SourceTriangle> batch) {
      got.insert(got.end(), batch.begin(), batch.end());
    });
    const std::uint64_t end = std::min(last, n);
    ASSERT_EQ(got.size(), end - std::min(first, end)) << first << ".." << last;
    std::size_t differing = 0;
    for (std::size_t k = 0; k < got.size(); ++k)
      differing += got[k].positions != all[std::size_t(first) + k].positions;
    EXPECT_EQ(differing, 0u) << first << ".." << last;
  }
  // A mesh in memory gives the same stretches.
  const svo::Mesh mesh = svo::loadMesh(dir.path() / "polygons.ply");
  const auto inMemory = svo::meshTriangleSource(mesh);
  std::vector<svo::SourceTriangle> stretch;
  inMemory->readRange(kNoted - 1, kNoted + 2, [&](std::span<const svo::SourceTriangle> batch) {
    stretch.insert(stretch.end(), batch.begin(), batch.end());
  });
  const std::vector<svo::SourceTriangle> whole = readAll(*inMemory);
  ASSERT_EQ(stretch.size(), 3u);
  for (std::size_t k = 0; k < stretch.size(); ++k)
    EXPECT_EQ(stretch[k].positions, whole[std::size_t(kNoted) - 1 + k].positions);
}

TEST(TriangleSource, BadBinaryPlyGivesOneLineErrors) {
  TempDir dir;
  const auto file = [&](const std::string& name, std::uint32_t faces, const std::vector<float>& xyz,
                        const std::vector<std::int32_t>& indices) {
    std::string h = "ply\nformat binary_little_endian 1.0\nelement vertex " + std::to_string(xyz.size() / 3) +
                    "\nproperty float x\nproperty float y\nproperty float z\nelement face " +
                    std::to_string(faces) + "\nproperty list uchar int vertex_indices\nend_header\n";
    PlyBytes b;
    for (const float f : xyz) b.put(f);
    for (std::size_t i = 0; i < indices.size(); i += 3)
      b.put(std::uint8_t(3)).put(indices[i]).put(indices[i + 1]).put(indices[i + 2]);
    return dir.file(name, h + b.bytes);
  };
  const std::vector<float> square = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
  const fs::path truncated = file("truncated.ply", 3, square, {0, 1, 2, 0, 2, 3});
  EXPECT_EQ(errorOfSource(truncated), truncated.string() + ": truncated: face 2 of 3 is missing");
  const fs::path range = file("range.ply", 2, square, {0, 1, 2, 0, 2, 7});
  EXPECT_EQ(errorOfSource(range), range.string() + ": face 1 uses vertex 7, but there are only 4");
  const fs::path negative = file("negative.ply", 1, square, {0, -1, 2});
  EXPECT_EQ(errorOfSource(negative), negative.string() + ": face 0 uses vertex -1, but there are only 4");
  std::vector<float> nan = square;
  nan[4] = std::nanf("");
  const fs::path notFinite = file("nan.ply", 1, nan, {0, 1, 2});
  EXPECT_EQ(errorOfSource(notFinite), notFinite.string() + ": vertex 1 has a non-finite coordinate");
  const fs::path flat = file("degenerate.ply", 1, square, {0, 1, 1});
  EXPECT_EQ(errorOfSource(flat), flat.string() + ": mesh has no triangles (all 1 are degenerate)");
  const fs::path shortVertices =
      dir.file("vertices.ply",
               "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
               "property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n" +
                   std::string(12, '\0'));
  EXPECT_EQ(errorOfSource(shortVertices), shortVertices.string() + ": truncated: vertex 1 of 2 is missing");
  // ASCII PLY is not streamed: loadMesh reads it whole, with the same result.
  const fs::path ascii =
      dir.file("ascii.ply",
               "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
               "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
               "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  const auto fallback = svo::openTriangleSource(ascii);
  EXPECT_EQ(fallback->format().find("streamed"), std::string::npos);
  EXPECT_EQ(fallback->triangleCount(), 1u);
}
