// Point clouds: the readers (PLY ASCII and binary, Draco, .xyz) against each other and the points written,
// normal estimation against analytic normals (sphere, plane) and a real scan's own normals, voxelization
// against the brute-force set of voxels holding a point, contours against the points they must hold, and the
// command's bad-input errors (under AddressSanitizer when SVO_ASAN_BINARY is set).
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <numbers>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include <draco/compression/encode.h>
#include <draco/point_cloud/point_cloud_builder.h>
#include <glm/geometric.hpp>
#include <glm/trigonometric.hpp>

#include "command_helpers.hpp"
#include "points_helpers.hpp"
#include "reference.hpp"
#include "svo/builder/points.hpp"
#include "svo/store/format.hpp"
#include "svo/store/store_reader.hpp"

using namespace pointtest;

namespace {

// Points on the unit sphere (a Fibonacci spiral: nearly even spacing), scaled by `radius`.
PointCloud sphere(int n, double radius) {
  PointCloud c;
  const double golden = std::numbers::pi * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < n; ++i) {
    const double z = 1.0 - 2.0 * (i + 0.5) / n, r = std::sqrt(1.0 - z * z), a = golden * i;
    c.positions.emplace_back(radius * r * std::cos(a), radius * r * std::sin(a), radius * z);
  }
  return c;
}

std::string drc(const PointCloud& c) {
  draco::PointCloudBuilder builder;
  builder.Start(std::uint32_t(c.positions.size()));
  const int pos = builder.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  const int nor = builder.AddAttribute(draco::GeometryAttribute::NORMAL, 3, draco::DT_FLOAT32);
  const int col = builder.AddAttribute(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT8);
  for (std::size_t i = 0; i < c.positions.size(); ++i) {
    const float p[3] = {float(c.positions[i].x), float(c.positions[i].y), float(c.positions[i].z)};
    const std::uint8_t rgb[3] = {std::uint8_t(c.colors[i].r), std::uint8_t(c.colors[i].g),
                                 std::uint8_t(c.colors[i].b)};
    builder.SetAttributeValueForPoint(pos, draco::PointIndex(std::uint32_t(i)), p);
    builder.SetAttributeValueForPoint(nor, draco::PointIndex(std::uint32_t(i)), &c.normals[i].x);
    builder.SetAttributeValueForPoint(col, draco::PointIndex(std::uint32_t(i)), rgb);
  }
  const std::unique_ptr<draco::PointCloud> pc = builder.Finalize(false);
  draco::Encoder encoder;  // no quantization: values stay exact
  encoder.SetEncodingMethod(draco::POINT_CLOUD_SEQUENTIAL_ENCODING);
  draco::EncoderBuffer buffer;
  EXPECT_TRUE(encoder.EncodePointCloudToBuffer(*pc, &buffer).ok());
  return std::string(buffer.data(), buffer.size());
}

using Key = std::tuple<int, int, int>;
Key keyOf(glm::ivec3 c) {
  return {c.x, c.y, c.z};
}

// The voxel of `level` holding each point, found point by point from the octree frame.
std::map<Key, std::vector<glm::dvec3>> voxelsOfPoints(const PointCloud& c, const svo::SceneTransform& t,
                                                      int level) {
  std::map<Key, std::vector<glm::dvec3>> out;
  for (const glm::dvec3& p : c.positions) {
    const glm::dvec3 u = (t.toOctree(p) - 1.0) * std::ldexp(1.0, level);
    out[keyOf(glm::ivec3(glm::floor(u)))].push_back(p);
  }
  return out;
}

// Checks every level's voxels against the brute-force set of voxels holding a point, every contour against
// the points in its voxel, and returns the leaves' largest angle to `expected`, the analytic normal at each
// leaf's points' mean.
double checkVoxels(const PointCloud& cloud, int levels,
                   const std::function<glm::dvec3(glm::dvec3)>& expected) {
  svo::BuildOptions options;
  options.levels = levels;
  const svo::SceneTransform transform = svo::fitSceneCube(cloud);
  const svo::VoxelTree tree = svo::voxelizePoints(cloud, transform, options);
  std::vector<Voxel> found;
  walk(tree, 0, glm::ivec3(0), 0, found);
  std::vector<std::map<Key, std::vector<glm::dvec3>>> truth;
  std::size_t voxels = 0;
  for (int level = 0; level <= levels; ++level)
    truth.push_back(voxelsOfPoints(cloud, transform, level)), voxels += truth.back().size();
  EXPECT_EQ(found.size(), voxels);
  double worst = 0.0;
  std::size_t contours = 0;
  for (const Voxel& v : found) {
    EXPECT_EQ(v.record.childMask == 0, v.level == levels) << "leaves are the finest voxels";
    const auto it = truth[std::size_t(v.level)].find(keyOf(v.coord));
    if (it == truth[std::size_t(v.level)].end()) {
      ADD_FAILURE() << "a voxel holds no point";
      continue;
    }
    if (v.level == levels) {
      glm::dvec3 mean(0.0);
      for (const glm::dvec3& p : it->second) mean += p;
      mean /= double(it->second.size());
      worst = std::max(worst, degreesBetween(glm::dvec3(svo::decodeNormal(v.record.normal)), expected(mean)));
    }
    if (!v.record.hasContour) continue;
    ++contours;
    const svo::Contour c = svo::decodeContour(v.record.contour);
    const double size = std::ldexp(1.0, -v.level);
    const glm::dvec3 centre = 1.0 + (glm::dvec3(v.coord) + 0.5) * size;
    for (const glm::dvec3& p : it->second) {
      const double d = glm::dot(glm::dvec3(c.normal), (transform.toOctree(p) - centre) / size);
      EXPECT_LE(std::abs(d - c.position), 0.5 * c.thickness + 1e-5) << "a point outside its voxel's contour";
    }
  }
  std::printf("%zu voxels, %zu contours\n", found.size(), contours);
  EXPECT_GT(contours, std::size_t(levels)) << "a smooth surface's voxels keep contours";
  return worst;
}

// Whether the finest voxels seal a closed surface: no 6-connected path of empty finest voxels leads from the
// scene cube's corner to the voxel at `inside`.
bool sealsInside(const svo::VoxelTree& tree, int levels, glm::ivec3 inside) {
  std::vector<Voxel> all;
  walk(tree, 0, glm::ivec3(0), 0, all);
  const int side = 1 << levels;
  std::vector<char> state(std::size_t(side) * side * side, 0);  // 1 full, 2 reached
  const auto at = [&](glm::ivec3 c) -> char& { return state[(std::size_t(c.z) * side + c.y) * side + c.x]; };
  for (const Voxel& v : all)
    if (v.level == levels) at(v.coord) = 1;
  std::vector<glm::ivec3> stack{glm::ivec3(0)};
  at(glm::ivec3(0)) = 2;
  while (!stack.empty()) {
    const glm::ivec3 c = stack.back();
    stack.pop_back();
    for (int axis = 0; axis < 3; ++axis)
      for (int d : {-1, 1}) {
        glm::ivec3 n = c;
        n[axis] += d;
        if (n[axis] < 0 || n[axis] >= side || at(n) != 0) continue;
        at(n) = 2;
        stack.push_back(n);
      }
  }
  return at(inside) == 0;
}

// The sphere at 5 levels with a finest voxel of 4.5 spacings (between kVoxelsPerSpacing and twice it).
constexpr int kFitLevels = 5;
constexpr double kSphereCube = 2.0 * 1.03125;  // fitSceneCube's margin of 1/64 a side around [-1, 1]
constexpr double kSphereSpacing = kSphereCube / 32.0 / 4.5;
const int kSpherePoints = int(4.0 * std::numbers::pi / (kSphereSpacing * kSphereSpacing));

}  // namespace

TEST_F(Points, PlyAsciiAndBinaryReadTheSamePoints) {
  const PointCloud c = exactCloud(50);
  const PointCloud a = svo::loadPointCloud(write("a.ply", ply(c, false)));
  const PointCloud b = svo::loadPointCloud(write("b.ply", ply(c, true)));
  ASSERT_EQ(a.positions.size(), c.positions.size());
  EXPECT_EQ(a.positions, c.positions);
  EXPECT_EQ(b.positions, c.positions);
  EXPECT_EQ(a.normals, b.normals);
  EXPECT_EQ(a.colors, b.colors);
  EXPECT_TRUE(svo::isPointCloudFile(dir_ / "a.ply"));
  EXPECT_TRUE(svo::isPointCloudFile(dir_ / "b.ply"));
  // assimp's ASCII sample: colors before normals, white at (0, 0, 0) with normal +y.
  const PointCloud s = svo::loadPointCloud(kPoints);
  ASSERT_EQ(s.positions.size(), 4u);
  EXPECT_EQ(s.normals[0], glm::vec3(0, 1, 0));
  EXPECT_EQ(s.colors[0], glm::vec4(1.0f));
  EXPECT_FALSE(svo::isPointCloudFile("/usr/share/assimp/models/PLY/cube.ply"));  // a mesh
}

TEST_F(Points, BigEndianPlyReadsAsLittleEndian) {
  const PointCloud c = exactCloud(20);
  std::string little = ply(c, true), big = little;
  big.replace(big.find("binary_little_endian"), 20, "binary_big_endian");
  const std::size_t start = big.find("end_header\n") + 11;
  for (std::size_t r = 0; r < c.positions.size(); ++r)
    for (int f = 0; f < 6; ++f) {  // the six floats of each 27-byte record, byte-swapped
      char* at = big.data() + start + r * 27 + 4 * std::size_t(f);
      std::reverse(at, at + 4);
    }
  const PointCloud a = svo::loadPointCloud(write("le.ply", little));
  const PointCloud b = svo::loadPointCloud(write("be.ply", big));
  EXPECT_EQ(a.positions, b.positions);
  EXPECT_EQ(a.normals, b.normals);
  EXPECT_EQ(a.colors, b.colors);
}

TEST_F(Points, XyzColumnLayouts) {
  const PointCloud xyz3 = svo::loadPointCloud(write("a.xyz", "0 0 0\n1\t2\t3 # a comment\n\n"));
  EXPECT_EQ(xyz3.positions.size(), 2u);
  EXPECT_TRUE(xyz3.normals.empty() && xyz3.colors.empty());
  const PointCloud rgb = svo::loadPointCloud(write("b.xyz", "0 0 0 255 0 0\n1,2,3,0,255,1\n"));
  EXPECT_TRUE(rgb.normals.empty());
  ASSERT_EQ(rgb.colors.size(), 2u);
  EXPECT_EQ(rgb.colors[0], glm::vec4(1, 0, 0, 1));
  const PointCloud normals = svo::loadPointCloud(write("c.xyz", "0 0 0 0 0 1\n1 2 3 0 1 0\n"));
  EXPECT_TRUE(normals.colors.empty());
  ASSERT_EQ(normals.normals.size(), 2u);
  EXPECT_EQ(normals.normals[1], glm::vec3(0, 1, 0));
  const PointCloud both = svo::loadPointCloud(write("d.xyz", "0 0 0 0 0 255 0.6 0 0.8\n1 1 1 0 0 0 0 0 0\n"));
  ASSERT_EQ(both.colors.size(), 2u);
  EXPECT_EQ(both.colors[0], glm::vec4(0, 0, 1, 1));
  EXPECT_EQ(both.normals[0], glm::vec3(0.6f, 0.0f, 0.8f));
  EXPECT_EQ(both.normals[1], glm::vec3(0.0f));  // unknown: estimated later
}

TEST_F(Points, PlyXyzAndDracoGiveTheSameTree) {
  const PointCloud c = exactCloud(3000);
  std::vector<svo::VoxelTree> trees;
  for (const auto& [name, bytes] : {std::pair{"p.ply", ply(c, true)}, std::pair{"a.ply", ply(c, false)},
                                    std::pair{"p.xyz", xyz(c)}, std::pair{"p.drc", drc(c)}}) {
    const fs::path path = write(name, bytes);
    ASSERT_TRUE(svo::isPointCloudFile(path)) << name;
    PointCloud read = svo::loadPointCloud(path);
    EXPECT_EQ(read.positions, c.positions) << name;
    svo::estimateNormals(read);
    svo::BuildOptions options;
    options.levels = 7;
    trees.push_back(svo::voxelizePoints(read, svo::fitSceneCube(read), options));
  }
  for (std::size_t i = 1; i < trees.size(); ++i) {
    ASSERT_EQ(trees[i].voxels.size(), trees[0].voxels.size()) << i;
    for (std::size_t v = 0; v < trees[0].voxels.size(); ++v) {
      const svo::VoxelRecord &a = trees[0].voxels[v], &b = trees[i].voxels[v];
      ASSERT_EQ(std::tie(a.firstChild, a.childMask, a.hasContour, a.contour, a.color, a.normal),
                std::tie(b.firstChild, b.childMask, b.hasContour, b.contour, b.color, b.normal))
          << "file " << i << " voxel " << v;
    }
  }
}

TEST_F(Points, SphereNormalsVoxelsAndContours) {
  PointCloud c = sphere(40000, 3.0);
  const svo::NormalEstimate e = svo::estimateNormals(c);
  EXPECT_EQ(e.estimated, c.positions.size());
  EXPECT_EQ(e.components, 1u);
  double worst = 0.0;
  for (std::size_t i = 0; i < c.positions.size(); ++i) {
    EXPECT_GT(glm::dot(glm::dvec3(c.normals[i]), c.positions[i]), 0.0) << "inward normal at point " << i;
    worst = std::max(worst, degreesBetween(glm::dvec3(c.normals[i]), c.positions[i]));
  }
  EXPECT_LT(worst, 2.0) << "PCA normal against the sphere's";
  EXPECT_LT(checkVoxels(c, 7, [](glm::dvec3 p) { return p; }), 3.0) << "leaf normal against the sphere's";
}

TEST_F(Points, PlaneNormalsVoxelsAndContours) {
  const glm::dvec3 normal = glm::normalize(glm::dvec3(-0.3, -0.1, 1.0));  // z = 0.3 x + 0.1 y
  PointCloud c;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  for (int i = 0; i < 20000; ++i) {
    const double x = u(rng), y = u(rng);
    c.positions.emplace_back(x, y, 0.3 * x + 0.1 * y);
  }
  svo::estimateNormals(c);
  for (std::size_t i = 0; i < c.positions.size(); ++i)
    ASSERT_LT(degreesBetween(glm::dvec3(c.normals[i]), normal), 0.5) << "point " << i;  // +z side
  EXPECT_LT(checkVoxels(c, 8, [&](glm::dvec3) { return normal; }), 1.0);
}

// The scan's own normals against PCA's over the same points: the file's normals come from the scanner's
// software, so agreement is measured with a tolerance, not exact: most points (three in four) within 30
// degrees as lines, half within 20, and one orientation for 90% of them up to a global sign.
TEST_F(Points, PondScanNormalsAgreeWithTheFile) {
  if (!fs::exists(kPond)) GTEST_SKIP() << kPond << " is missing (assimp-testmodels)";
  EXPECT_THROW(svo::loadPointCloud(kPond), std::runtime_error);  // as packaged: non-finite positions
  const PointCloud file = svo::loadPointCloud(write("pond.ply", repairedPond().first));
  std::printf("pond.0.ply: %zu of its 70051 points read after the repair\n", file.positions.size());
  ASSERT_GT(file.positions.size(), 30000u);
  ASSERT_EQ(file.normals.size(), file.positions.size());
  ASSERT_EQ(file.colors.size(), file.positions.size());
  PointCloud c = file;
  c.normals.clear();
  svo::estimateNormals(c);
  std::vector<double> angles;  // as lines: the PCA normal against the file's, sign aside
  std::size_t sameSide = 0;
  for (std::size_t i = 0; i < c.positions.size(); ++i) {
    const double d = glm::dot(c.normals[i], file.normals[i]);
    angles.push_back(glm::degrees(std::acos(std::min(1.0, std::abs(d)))));
    sameSide += d > 0.0;
  }
  std::sort(angles.begin(), angles.end());
  const auto quantile = [&](double q) { return angles[std::size_t(q * double(angles.size() - 1))]; };
  // Orientation is consistent when the sides agree for nearly all points, up to one global sign: Hoppe's
  // seed faces +z, where the scanner's normals face -y on the whole.
  const double side = double(sameSide) / double(c.positions.size()), consistent = std::max(side, 1.0 - side);
  std::printf(
      "pond.0.ply: PCA against the file's normals: median %.1f, p75 %.1f, p90 %.1f degrees; %.1f%% "
      "oriented alike up to one sign\n",
      quantile(0.5), quantile(0.75), quantile(0.9), 100.0 * consistent);
  // Measured with k = 16: median 14.7, p75 26.4, p90 39.7 degrees, 92.8% alike (the file's normals are
  // smoother than 16-neighbour planes on this noisy scan).
  EXPECT_LT(quantile(0.5), 20.0);
  EXPECT_LT(quantile(0.75), 30.0);
  EXPECT_GT(consistent, 0.9);
}

// ----- the command --------------------------------------------------------------------------------------

TEST_F(PointsCli, BadPointCloudsGiveOneClearError) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nend_header\n";
  expectCleanFailure(write("nan.xyz", "0 0 0\nnan 0 0\n1 1 1\n"), "non-finite position");
  expectCleanFailure(write("inf.ply", header + "0 0 0\n1 inf 0\n1 1 1\n"), "non-finite position");
  expectCleanFailure(write("empty.xyz", "# no points\n"), "no points");
  expectCleanFailure(write("none.ply",
                           "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty "
                           "float y\nproperty float z\nend_header\n"),
                     "no points");
  expectCleanFailure(
      write("type.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty flot x\nend_header\n"),
      "malformed PLY header");
  expectCleanFailure(write("open.ply", "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"),
                     "no end_header");
  expectCleanFailure(write("short.ply", header + "0 0"), "ends before its first vertex");
  const PointCloud c = exactCloud(200);
  expectCleanFailure(write("short.xyz", "0 0 0\n1 1 1\n2 2\n"), "line 3 has 2 numbers");
  expectCleanFailure(write("word.xyz", "0 0 0\n1 x 1\n"), "'x' is not a number");
  const std::string draco = drc(c);
  expectCleanFailure(write("short.drc", draco.substr(0, draco.size() / 2)), "Draco");
  expectCleanFailure(write("same.xyz", "1 2 3\n1 2 3\n"), "no extent");
  if (fs::exists(kPond))
    expectCleanFailure(kPond, "point 714 has a non-finite position");  // see repairedPond
  // Out of core: the same errors from the streaming passes, and a bound too small for the scan.
  expectCleanFailure(write("nan2.xyz", "0 0 0\nnan 0 0\n1 1 1\n"), "non-finite position", "--memory 1G");
  expectCleanFailure(write("short2.ply", header + "0 0"), "ends before its first vertex", "--memory 1G");
  expectCleanFailure(write("same2.xyz", "1 2 3\n1 2 3\n"), "no extent", "--memory 1G");
  expectCleanFailure(write("bound.xyz", xyz(c)), "too small", "--memory 1M");
}

// A PLY cut inside its vertex records builds from the complete ones, with a warning.
TEST_F(PointsCli, TruncatedPlyBuildsFromTheCompletePoints) {
  const PointCloud c = exactCloud(200);
  const std::string binary = ply(c, true);
  const fs::path cut = write("cut.ply", binary.substr(0, binary.size() - 30));  // 27-byte records: 2 cut
  EXPECT_EQ(svo::loadPointCloud(cut).positions.size(), 198u);
  const auto [code, err] = build(cut, dir_ / "cut.svo", "--levels 6");
  EXPECT_EQ(code, 0) << err;
  const std::string said = err + slurp(dir_ / "stdout.txt");
  EXPECT_NE(said.find("ends inside point 198 of the 200"), std::string::npos) << said;
}

TEST_F(PointsCli, BuildsAScanIntoAStore) {
  if (!fs::exists(kPond)) GTEST_SKIP() << kPond << " is missing (assimp-testmodels)";
  const fs::path out = dir_ / "pond.svo";
  const auto [code, err] = build(write("pond.ply", repairedPond().first), out, "--levels 9");
  ASSERT_EQ(code, 0) << err;
  const svo::StoreReader store(out);
  EXPECT_EQ(store.header().parameters.levels, 9);
  const svo::VoxelTree tree = store.loadTree();
  EXPECT_TRUE(tree.hasColors);
  EXPECT_GT(tree.voxels.size(), 10000u);
  // The store keeps the voxelizer's structure and contours exactly (record order aside).
  PointCloud cloud = svo::loadPointCloud(dir_ / "pond.ply");
  svo::estimateNormals(cloud);
  svo::BuildOptions options;
  options.levels = 9;
  const svo::VoxelTree built = svo::voxelizePoints(cloud, svo::fitSceneCube(cloud), options);
  const auto shape = [](const svo::VoxelTree& t) {
    std::multiset<std::tuple<int, bool, std::uint32_t>> out;
    for (const svo::VoxelRecord& r : t.voxels)
      out.emplace(r.childMask, r.hasContour, r.hasContour ? r.contour : 0);
    return out;
  };
  EXPECT_EQ(shape(tree), shape(built));
}

TEST_F(PointsCli, PlyAndXyzOfTheSamePointsBuildTheSameStore) {
  const PointCloud c = exactCloud(2000);
  const auto [plyCode, plyErr] = build(write("p.ply", ply(c, true)), dir_ / "ply.svo", "--levels 8");
  ASSERT_EQ(plyCode, 0) << plyErr;
  const auto [xyzCode, xyzErr] = build(write("p.xyz", xyz(c)), dir_ / "xyz.svo", "--levels 8");
  ASSERT_EQ(xyzCode, 0) << xyzErr;
  EXPECT_EQ(slurp(dir_ / "ply.svo"), slurp(dir_ / "xyz.svo"));
}

// The spacing estimate against the analytic spacing of a random sphere sample; the level it picks against
// the one the analytic spacing gives; that level's surface sealed (no path of empty voxels from outside to
// the centre) with at least 85% of the leaves the same sphere as a mesh makes (points cover less of each
// voxel a surface merely grazes: 0.88-0.92 measured at 3.5-8 spacings a voxel), the level below it not.
TEST_F(Points, LevelsFitThePointSpacing) {
  const PointCloud c = randomSphere(kSpherePoints, 11);
  const double spacing = svo::estimatePointSpacing(c);
  EXPECT_NEAR(spacing / kSphereSpacing, 1.0, 0.03);
  const svo::SceneTransform transform = svo::fitSceneCube(c);
  EXPECT_NEAR(transform.size, kSphereCube, 1e-3);
  const int fits = svo::levelsForSpacing(spacing, transform);
  EXPECT_EQ(fits, kFitLevels);
  EXPECT_EQ(fits, int(std::floor(std::log2(kSphereCube / (svo::kVoxelsPerSpacing * kSphereSpacing)))));
  const svo::Mesh mesh = svotest::makeSphere(glm::dvec3(0.0), 1.0, 100, 200);
  for (int levels : {fits, fits + 1}) {
    svo::BuildOptions options;
    options.levels = levels;
    svo::BuildStats points, triangles;
    const svo::VoxelTree tree = svo::voxelizePoints(c, transform, options, &points);
    svo::voxelize(mesh, transform, options, &triangles);
    const glm::ivec3 centre(
        glm::floor((transform.toOctree(glm::dvec3(0.0)) - 1.0) * std::ldexp(1.0, levels)));
    std::printf("%d levels: %llu leaves from points, %llu from the mesh\n", levels,
                (unsigned long long)points.leafVoxels, (unsigned long long)triangles.leafVoxels);
    if (levels == fits) {
      EXPECT_TRUE(sealsInside(tree, levels, centre)) << "holes at the level the spacing fits";
      EXPECT_GT(double(points.leafVoxels), 0.85 * double(triangles.leafVoxels));
    } else {
      EXPECT_FALSE(sealsInside(tree, levels, centre)) << "a level deeper than fits is expected to leak";
    }
  }
}

// Without --levels a scan builds at the level its spacing fits; with --levels deeper than that, one warning.
TEST_F(PointsCli, LevelsFromThePointSpacing) {
  const PointCloud c = randomSphere(kSpherePoints, 12);
  std::string text;
  for (std::size_t i = 0; i < c.positions.size(); ++i)
    text += number(c.positions[i].x) + " " + number(c.positions[i].y) + " " + number(c.positions[i].z) + " " +
            number(c.normals[i].x) + " " + number(c.normals[i].y) + " " + number(c.normals[i].z) + "\n";
  const fs::path input = write("sphere.xyz", text);
  const auto [code, err] = build(input, dir_ / "fit.svo");
  ASSERT_EQ(code, 0) << err;
  EXPECT_EQ(svo::StoreReader(dir_ / "fit.svo").header().parameters.levels, kFitLevels);
  EXPECT_EQ(err.find("holes"), std::string::npos) << err;
  const auto [deepCode, deepErr] =
      build(input, dir_ / "deep.svo", "--levels " + std::to_string(kFitLevels + 2));
  ASSERT_EQ(deepCode, 0) << deepErr;
  const std::string said = deepErr + slurp(dir_ / "stdout.txt");
  EXPECT_NE(said.find("the surface will have holes; --levels " + std::to_string(kFitLevels) + " fits"),
            std::string::npos)
      << said;
}
