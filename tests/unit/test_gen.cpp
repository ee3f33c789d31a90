// `svo gen` scenes: deterministic from the seed, within the promised triangle tolerance and bounds, no
// degenerate or non-finite triangles, and a binary PLY that loadMesh decodes back to the same triangles.
#include <gtest/gtest.h>

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <glm/geometric.hpp>

#include "svo/builder/gen.hpp"
#include "svo/builder/mesh.hpp"

namespace fs = std::filesystem;

namespace {

constexpr svo::SceneKind kKinds[] = {svo::SceneKind::Terrain, svo::SceneKind::City, svo::SceneKind::Hairball,
                                     svo::SceneKind::Sphere};

svo::Mesh generate(svo::SceneKind kind, std::uint64_t triangles, std::uint64_t seed) {
  svo::GenOptions options;
  options.kind = kind;
  options.triangles = triangles;
  options.seed = seed;
  return svo::generateScene(options);
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class Gen : public ::testing::TestWithParam<svo::SceneKind> {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           ("svo_gen_" + std::to_string(::getpid()) + "_" + std::string(svo::sceneKindName(GetParam())));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

std::string kindName(const ::testing::TestParamInfo<svo::SceneKind>& info) {
  return std::string(svo::sceneKindName(info.param));
}

TEST_P(Gen, SameSeedSameBytesOtherSeedOtherBytes) {
  const auto write = [&](std::uint64_t seed, const std::string& name) {
    svo::writePly(dir_ / name, generate(GetParam(), 20000, seed), "test");
    return slurp(dir_ / name);
  };
  const std::string a = write(7, "a.ply"), b = write(7, "b.ply"), c = write(8, "c.ply");
  ASSERT_GT(a.size(), 20000u * 13u);  // at least the face records
  EXPECT_EQ(a, b);
  EXPECT_EQ(a.size(), c.size());  // same topology, different shape
  EXPECT_NE(a, c);
  for (const auto& e : fs::directory_iterator(dir_))
    EXPECT_EQ(e.path().string().find(".tmp"), std::string::npos) << "left behind: " << e.path();
}

TEST_P(Gen, TriangleCountWithinTolerance) {
  for (const std::uint64_t target :
       {std::uint64_t(100), std::uint64_t(777), std::uint64_t(12345), std::uint64_t(100000)}) {
    const svo::Mesh mesh = generate(GetParam(), target, 3);
    const double ratio = double(mesh.triangles.size()) / double(target);
    EXPECT_LE(std::abs(ratio - 1.0), svo::kGenTolerance) << target << " -> " << mesh.triangles.size();
  }
}

TEST_P(Gen, NoDegenerateOrNonFiniteTriangles) {
  const svo::Mesh mesh = generate(GetParam(), 50000, 11);
  ASSERT_EQ(mesh.colors.size(), mesh.positions.size());
  for (const glm::dvec3& p : mesh.positions)
    ASSERT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
  for (const glm::vec4& c : mesh.colors) {
    ASSERT_TRUE(glm::all(glm::greaterThanEqual(c, glm::vec4(0.0f))) &&
                glm::all(glm::lessThanEqual(c, glm::vec4(1.0f))));
    ASSERT_EQ(c.a, 1.0f);
  }
  for (const glm::uvec3& t : mesh.triangles) {
    ASSERT_TRUE(t.x < mesh.positions.size() && t.y < mesh.positions.size() && t.z < mesh.positions.size());
    ASSERT_TRUE(t.x != t.y && t.y != t.z && t.x != t.z);
    const glm::dvec3 a = mesh.positions[t.x], b = mesh.positions[t.y], c = mesh.positions[t.z];
    ASSERT_GT(glm::length(glm::cross(b - a, c - a)), 0.0);
  }
  svo::Mesh copy = mesh;
  EXPECT_EQ(svo::validateMesh(copy, "generated"), 0u);  // the loader's own degenerate test drops nothing
}

void checkBounds(svo::SceneKind kind, const svo::Mesh& mesh);

TEST_P(Gen, StaysInsideThePromisedBounds) {
  const svo::SceneKind kind = GetParam();
  // Few triangles make the largest parts (the city's towers reach their height cap).
  ASSERT_NO_FATAL_FAILURE(checkBounds(kind, generate(kind, 100, 5)));
  checkBounds(kind, generate(kind, 30000, 5));
}

void checkBounds(svo::SceneKind kind, const svo::Mesh& mesh) {
  const svo::GenBounds box = svo::sceneBounds(kind);
  glm::dvec3 lo(1e300), hi(-1e300);
  double rMin = 1e300, rMax = 0.0;
  for (const glm::dvec3& p : mesh.positions) {
    ASSERT_TRUE(glm::all(glm::greaterThanEqual(p, box.min)) && glm::all(glm::lessThanEqual(p, box.max)))
        << p.x << " " << p.y << " " << p.z;
    lo = glm::min(lo, p), hi = glm::max(hi, p);
    rMin = std::min(rMin, glm::length(p)), rMax = std::max(rMax, glm::length(p));
  }
  switch (kind) {
    case svo::SceneKind::Terrain:  // the full grid, lowest point at 0, highest at the promised height
      EXPECT_EQ(lo, box.min);
      EXPECT_EQ(hi, box.max);
      break;
    case svo::SceneKind::City:  // the full ground plane, towers up to the promised height
      EXPECT_EQ(lo, box.min);
      EXPECT_EQ(hi.x, 1.0);
      EXPECT_EQ(hi.z, 1.0);
      EXPECT_GT(hi.y, 0.0);
      break;
    case svo::SceneKind::Hairball:
      EXPECT_LE(rMax, 1.0);
      EXPECT_GT(rMax, 0.3);  // the tubes fill the ball, not just its centre
      break;
    case svo::SceneKind::Sphere:
      EXPECT_LE(rMax, 1.0);
      EXPECT_GE(rMin, svo::kSphereMinRadius);
      EXPECT_GT(rMax - rMin, 0.5 * (1.0 - svo::kSphereMinRadius));  // bumpy, not a plain sphere
      break;
  }
}

// Writes the mesh with `write`, loads it back with loadMesh and compares triangle by triangle; colors may
// differ by `colorTolerance` (linear units).
void expectRoundTrip(const svo::Mesh& mesh, const fs::path& path, float colorTolerance) {
  svo::MeshLoadReport report;
  const svo::Mesh loaded = svo::loadMesh(path, &report);
  EXPECT_EQ(report.droppedDegenerate, 0u);
  ASSERT_EQ(loaded.triangles.size(), mesh.triangles.size());
  ASSERT_EQ(loaded.colors.size(), loaded.positions.size());
  // The loader may merge or reorder vertices; triangle order and corner order are kept.
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t a = mesh.triangles[t][k], b = loaded.triangles[t][k];
      ASSERT_EQ(loaded.positions[b], mesh.positions[a]) << "triangle " << t << " corner " << k;
      const glm::vec4 d = glm::abs(loaded.colors[b] - mesh.colors[a]);
      ASSERT_LE(std::max({d.r, d.g, d.b, d.a}), colorTolerance) << "triangle " << t << " corner " << k;
    }
}

TEST_P(Gen, PlyDecodesToTheSameTriangles) {
  const svo::Mesh mesh = generate(GetParam(), 20000, 21);
  svo::writePly(dir_ / "scene.ply", mesh, "round trip");
  // 8-bit sRGB in the file: within half a step after decoding, which is at most 2.27 / 510 in linear units
  // (the steepest slope of the sRGB decoding curve, at 1, is 2.27).
  expectRoundTrip(mesh, dir_ / "scene.ply", 2.28f / 510.0f);
}

TEST_P(Gen, GlbDecodesToTheSameTriangles) {
  const svo::Mesh mesh = generate(GetParam(), 20000, 21);
  svo::writeGlb(dir_ / "scene.glb", mesh, "round \"trip\"");
  svo::writeGlb(dir_ / "again.glb", mesh, "round \"trip\"");
  EXPECT_EQ(slurp(dir_ / "scene.glb"), slurp(dir_ / "again.glb"));
  // Linear 8-bit colors in the file: within half a step, plus float rounding.
  expectRoundTrip(mesh, dir_ / "scene.glb", 0.5f / 255.0f + 1e-6f);
}

INSTANTIATE_TEST_SUITE_P(Kinds, Gen, ::testing::ValuesIn(kKinds), kindName);

TEST(GenOptions, RejectsBadParameters) {
  EXPECT_FALSE(svo::parseSceneKind("castle"));
  for (const svo::SceneKind kind : kKinds) EXPECT_EQ(svo::parseSceneKind(svo::sceneKindName(kind)), kind);
  EXPECT_THROW(generate(svo::SceneKind::Terrain, 0, 1), std::invalid_argument);
  EXPECT_THROW(generate(svo::SceneKind::City, svo::kMinGenTriangles - 1, 1), std::invalid_argument);
  EXPECT_THROW(generate(svo::SceneKind::Sphere, svo::kMaxGenTriangles + 1, 1), std::invalid_argument);
}

TEST(GenOutput, UnwritablePathThrowsAndLeavesNothing) {
  const svo::Mesh mesh = generate(svo::SceneKind::Sphere, 100, 1);
  const fs::path missing = fs::temp_directory_path() / ("svo_gen_missing_" + std::to_string(::getpid()));
  EXPECT_THROW(svo::writePly(missing / "scene.ply", mesh), std::runtime_error);
  EXPECT_FALSE(fs::exists(missing));
}

}  // namespace
