// The dimensional analysis (svo/store/dimensions.hpp, paper sec. 4) against independent references:
//  - a hand-counted store of three voxels: N, every D and the view data, exactly;
//  - analytic stores written from voxel sets made here (a tilted plane, a ball, axis-aligned lines), cut into
//    many small slices so that the walk crosses cube splits and runs: N measured through the slices equals a
//    brute-force count over the finest voxels; the plane's dimensions are 2, the ball's 3, the lines' local
//    one 1, within the bounds each test derives;
//  - a store the builder wrote (contours, colors, runs): N through its slices equals the count over its tree;
//  - a store with a bad slice fails with the slice named;
//  - `svo inspect --dimensions` and `svo bench dimensions`: tables, plots and JSON agreeing with the library;
//    bad input (missing or corrupt store, bad flags) gives one line on stderr, a non-zero exit and no report.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "command_helpers.hpp"
#include "reference.hpp"
#include "svo/store/dimensions.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_writer.hpp"

namespace {

// Slices small enough that every analytic store splits into hundreds of cubes and runs of sub-cubes.
constexpr std::uint32_t kSmallSlices = 512;

// The octree whose finest level (`levels`) holds exactly `finest`, every coarser voxel being the parent of
// some voxel below, written as a store without contours or attributes.
void writeVoxelStore(const std::filesystem::path& path, std::vector<glm::ivec3> finest, int levels) {
  const auto morton = [](const glm::ivec3& a, const glm::ivec3& b) { return svo::mortonLess(a, b); };
  svo::VoxelLevels tree(std::size_t(levels + 1));
  std::sort(finest.begin(), finest.end(), morton);
  finest.erase(std::unique(finest.begin(), finest.end()), finest.end());
  for (const glm::ivec3& c : finest) tree[std::size_t(levels)].push_back({c});
  for (int l = levels; l > 0; --l) {
    std::vector<svo::SliceVoxel>& parents = tree[std::size_t(l - 1)];
    for (const svo::SliceVoxel& v : tree[std::size_t(l)]) {
      const glm::ivec3 parent = v.coord >> 1;
      if (parents.empty() || parents.back().coord != parent) parents.push_back({parent});
      parents.back().childMask |= std::uint8_t(1u << svo::childSlot(v.coord));
    }
  }
  svo::BuildParameters parameters;
  parameters.levels = levels;
  parameters.contours = 0;
  svo::StoreWriteOptions options;
  options.sliceBytes = kSmallSlices;
  svo::writeStore(path, svo::treeOfLevels(tree, false, false), svo::SceneTransform{}, parameters, options);
}

// N(c, L) by brute force over the finest voxels: each point's level-c cube, the distinct level-L voxels of
// the points in that cube. Shares nothing with the walk over the slices.
double bruteForceCount(const std::vector<glm::ivec3>& finest, int levels, int c, int l) {
  std::vector<std::pair<std::uint64_t, std::uint64_t>> keys;  // (cube, voxel of level L) per point
  keys.reserve(finest.size());
  for (const glm::ivec3& p : finest)
    keys.push_back({svotest::packCoord(p >> (levels - c)), svotest::packCoord(p >> (levels - l))});
  std::sort(keys.begin(), keys.end());
  double sum = 0.0;
  for (std::size_t i = 0; i < keys.size();) {
    std::size_t j = i, voxels = 0;
    for (; j < keys.size() && keys[j].first == keys[i].first; ++j) voxels += j == i || keys[j] != keys[j - 1];
    sum += double(j - i) * double(voxels);  // the cube's points, each seeing its distinct voxels
    i = j;
  }
  return sum / double(finest.size());
}

std::vector<glm::ivec3> unique(std::vector<glm::ivec3> coords) {
  svotest::sortUnique(coords);
  return coords;
}

// The plane n.p = n.centre through the scene's centre, n = (kPlaneSlopeX, kPlaneSlopeY, 1): every voxel of
// level `levels` it passes through (conservative: its z span over the voxel's column, floor to floor).
// Slopes below 1 keep it inside the cube over every column.
constexpr double kPlaneSlopeX = 0.3, kPlaneSlopeY = 0.2;
std::vector<glm::ivec3> tiltedPlane(int levels) {
  const int n = 1 << levels;
  std::vector<glm::ivec3> voxels;
  const auto z = [&](double x, double y) {
    return 0.5 * n - kPlaneSlopeX * (x - 0.5 * n) - kPlaneSlopeY * (y - 0.5 * n);
  };
  for (int x = 0; x < n; ++x)
    for (int y = 0; y < n; ++y) {
      const double a = z(x, y), b = z(x + 1, y + 1);  // both slopes positive: the corners' extremes
      for (int k = int(std::floor(std::min(a, b))); k <= int(std::floor(std::max(a, b))); ++k)
        if (k >= 0 && k < n) voxels.push_back({x, y, k});
    }
  return unique(voxels);
}

// The voxels of level `levels` whose centre lies inside a ball of radius `radius` (a fraction of the scene)
// at the scene's centre.
std::vector<glm::ivec3> ball(int levels, double radius) {
  const int n = 1 << levels;
  const double r = radius * n, centre = 0.5 * n;
  std::vector<glm::ivec3> voxels;
  for (int x = 0; x < n; ++x)
    for (int y = 0; y < n; ++y)
      for (int z = 0; z < n; ++z) {
        const glm::dvec3 d = glm::dvec3(x, y, z) + 0.5 - centre;
        if (d.x * d.x + d.y * d.y + d.z * d.z <= r * r) voxels.push_back({x, y, z});
      }
  return voxels;
}

// `count` lines of voxels across the whole scene, each along a random axis at random coordinates on the
// other two.
std::vector<glm::ivec3> axisLines(int levels, int count, std::uint32_t seed) {
  const int n = 1 << levels;
  std::mt19937 random(seed);
  std::uniform_int_distribution<int> axisOf(0, 2), coordOf(0, n - 1);
  std::vector<glm::ivec3> voxels;
  for (int i = 0; i < count; ++i) {
    const int axis = axisOf(random);
    glm::ivec3 p(coordOf(random), coordOf(random), coordOf(random));
    for (int t = 0; t < n; ++t) {
      p[axis] = t;
      voxels.push_back(p);
    }
  }
  return unique(voxels);
}

// A store of the voxels, measured; N checked against the brute force at every cube and voxel level.
svo::VoxelDimensions measuredAndChecked(const std::vector<glm::ivec3>& finest, int levels) {
  svotest::TempFile file("svo_dimensions", ".svo");
  writeVoxelStore(file.path, finest, levels);
  const svo::StoreReader reader(file.path);
  EXPECT_GT(reader.slices().size(), 20u) << "the store should split into many slices";
  const svo::VoxelDimensions dims = svo::measureDimensions(reader);
  EXPECT_EQ(dims.finestLevel(), levels);
  EXPECT_EQ(dims.voxels(levels), finest.size());
  for (int c = 0; c <= levels; ++c)
    for (int l = c; l <= levels; ++l)
      EXPECT_NEAR(dims.count(c, l), bruteForceCount(finest, levels, c, l), 1e-9 * dims.count(c, l))
          << "N(" << c << ", " << l << ")";
  return dims;
}

TEST(Dimensions, HandCountedStore) {
  // Level 2: a = (0,0,0) and b = (1,0,0) share the level-1 cube (0,0,0); c = (3,3,3) is alone in (1,1,1).
  svotest::TempFile file("svo_dimensions_hand", ".svo");
  writeVoxelStore(file.path, {{0, 0, 0}, {1, 0, 0}, {3, 3, 3}}, 2);
  const svo::VoxelDimensions d = svo::measureDimensions(svo::StoreReader(file.path));
  ASSERT_EQ(d.finestLevel(), 2);
  EXPECT_EQ(d.voxels(0), 1u);
  EXPECT_EQ(d.voxels(1), 2u);
  EXPECT_EQ(d.voxels(2), 3u);
  // The scene cube holds 2 voxels of level 1 and 3 of level 2 around every point.
  EXPECT_DOUBLE_EQ(d.count(0, 0), 1.0);
  EXPECT_DOUBLE_EQ(d.count(0, 1), 2.0);
  EXPECT_DOUBLE_EQ(d.count(0, 2), 3.0);
  // Level-1 cubes: a and b see 2 level-2 voxels, c sees 1: (2 + 2 + 1) / 3.
  EXPECT_DOUBLE_EQ(d.count(1, 2), 5.0 / 3.0);
  EXPECT_DOUBLE_EQ(d.count(1, 1), 1.0);
  EXPECT_DOUBLE_EQ(d.count(2, 2), 1.0);
  EXPECT_DOUBLE_EQ(d.local(0, 1), 1.0);
  EXPECT_DOUBLE_EQ(d.local(0, 2), std::log2(3.0 / 2.0));
  EXPECT_DOUBLE_EQ(d.local(1, 2), std::log2(5.0 / 3.0));
  EXPECT_TRUE(std::isnan(d.local(2, 2)));  // the cube holds one voxel of either level
  EXPECT_DOUBLE_EQ(d.global(1, 1), 1.0);
  EXPECT_DOUBLE_EQ(d.global(1, 2), std::log2(9.0 / 5.0));
  EXPECT_DOUBLE_EQ(d.global(2, 2), std::log2(5.0 / 3.0));
  EXPECT_TRUE(std::isnan(d.global(0, 2)));  // no cube above the scene's
  EXPECT_DOUBLE_EQ(d.scale(1, 2), std::log2(6.0 / 5.0));
  EXPECT_DOUBLE_EQ(d.scale(1, 2), d.global(1, 2) - d.local(0, 2));
  EXPECT_DOUBLE_EQ(d.scale(2, 2), 0.0);
  // A view's data: every level down to the resolved one, in its cube; cubes beyond the scene hold it all.
  EXPECT_DOUBLE_EQ(d.viewData(0, 2), 1.0 + 2.0 + 3.0);
  EXPECT_DOUBLE_EQ(d.viewData(-3, 2), 6.0);
  EXPECT_DOUBLE_EQ(d.viewData(1, 2), 1.0 + 1.0 + 5.0 / 3.0);
  EXPECT_DOUBLE_EQ(d.viewData(0, 7), 6.0);  // nothing finer than the store's finest level
  EXPECT_NEAR(d.viewData(0, 1.5), std::sqrt(3.0 * 6.0), 1e-12);  // log-linear between levels 1 and 2
  const std::vector<double> weights{0.0, 10.0, 100.0};           // bytes per voxel of levels 0, 1, 2
  EXPECT_DOUBLE_EQ(d.viewData(0, 2, weights), 2.0 * 10.0 + 3.0 * 100.0);
  EXPECT_DOUBLE_EQ(d.viewData(0, 0, weights), 0.0);
  EXPECT_THROW(d.viewData(0, 2, std::vector<double>{1.0}), std::invalid_argument);
}

// A plane: local and global dimension 2. It crosses every column of the scene, so no cube sees its edge;
// within a cube, the voxels at the rim where the plane leaves through the cube's top or bottom face are cut
// by it, a share of about 2^-(L - c) of the count, so D_local moves towards 2 as the cube holds more voxels:
// within 0.05 from 16 voxels across (L - c >= 4). D_global also depends on how the plane cuts the few largest
// cubes of the grid (it passes through the scene's centre, a corner of every coarse cube): it is held to 2
// where the scene holds at least 8 cubes across (level 3 and finer), and so D_scale = D_global - D_local to 0
// within the sum of both bounds: data constant with distance.
TEST(Dimensions, PlaneIsTwoDimensional) {
  constexpr int kLevels = 8;
  const svo::VoxelDimensions dims = measuredAndChecked(tiltedPlane(kLevels), kLevels);
  for (int c = 0; c <= kLevels; ++c)
    for (int l = c + 4; l <= kLevels; ++l) {
      EXPECT_NEAR(dims.local(c, l), 2.0, 0.05) << "D_local(" << c << ", " << l << ")";
      if (c < 3) continue;
      EXPECT_NEAR(dims.global(c, l), 2.0, 0.05) << "D_global(" << c << ", " << l << ")";
      EXPECT_NEAR(dims.scale(c, l), 0.0, 0.1) << "D_scale(" << c << ", " << l << ")";
    }
}

// A ball: dimension 3. Each coarser level holds every voxel one of its children lies in, which wraps the
// ball in a shell of about half a coarse voxel: the count of level L - 1 exceeds 1/8 of level L's by about
// 3 (h / 2) / R = 1.5 h / R (surface over volume times the shell), h the voxel of level L - 1 and R the
// radius, so D_local lies within log2(1 + 1.5 h / R) below 3. The same holds for D_global with h the doubled
// cube, once its cubes are small against the ball (level 3, an eighth of the scene, against a radius of 0.4).
// The first order of that argument needs the ball many voxels wide: voxel levels 4 and finer (R >= 3.2
// voxels of level L - 1), cubes of level 2 and finer.
TEST(Dimensions, BallIsThreeDimensional) {
  constexpr int kLevels = 6;
  constexpr double kRadius = 0.4;  // of the scene
  const svo::VoxelDimensions dims = measuredAndChecked(ball(kLevels, kRadius), kLevels);
  const auto bound = [&](int level) { return std::log2(1.0 + 1.5 * std::ldexp(1.0, -level) / kRadius); };
  for (int c = 2; c <= kLevels; ++c)
    for (int l = std::max(c + 1, 4); l <= kLevels; ++l) {
      EXPECT_NEAR(dims.local(c, l), 3.0, bound(l - 1)) << "D_local(" << c << ", " << l << ")";
      if (c >= 4) EXPECT_NEAR(dims.global(c, l), 3.0, bound(c - 1)) << "D_global(" << c << ", " << l << ")";
    }
}

// Lines: local dimension 1. A line crosses every cube it enters from face to face, 2^(L - c) voxels of
// level L; what adds to that is voxels two lines share: each pair of lines along different axes meets in a
// voxel of level L - 1 with a chance of 2^-(L - 1), so 24 lines (about 190 such pairs) share about
// 190 / 2^(L - 1) of their 24 2^(L - 1) voxels, under 1% from voxel level 6 on (parallel lines share a row
// far less often): within 0.05 of 1. Spread over the scene, the lines fill it at large scales: doubling a
// cube larger than their spacing finds more lines, not only longer ones, so D_global exceeds the lines' own
// dimension there, as the paper's vegetation does.
TEST(Dimensions, LinesAreOneDimensional) {
  constexpr int kLevels = 8;
  const svo::VoxelDimensions dims = measuredAndChecked(axisLines(kLevels, 24, 7), kLevels);
  for (int c = 0; c <= kLevels; ++c)
    for (int l = std::max(c + 1, 6); l <= kLevels; ++l)
      EXPECT_NEAR(dims.local(c, l), 1.0, 0.05) << "D_local(" << c << ", " << l << ")";
  for (int c = 1; c <= 2; ++c) EXPECT_GT(dims.global(c, kLevels), 2.0) << c;
}

// A mesh store as the builder writes it (contours, colors, runs of sub-cubes): the walk through its slices
// counts what the whole tree holds.
TEST(Dimensions, BuiltStoreMatchesItsTree) {
  svotest::TempFile file("svo_dimensions_sphere", ".svo");
  svotest::writeSphereAndBoxStore(file.path, 4096);
  const svo::StoreReader reader(file.path);
  const svo::VoxelDimensions dims = svo::measureDimensions(reader);
  const svo::VoxelTree tree = reader.loadTree();
  // The finest voxels from the tree, breadth first from the root.
  std::vector<glm::ivec3> finest;
  std::vector<std::pair<std::uint32_t, std::pair<int, glm::ivec3>>> stack{{0u, {0, glm::ivec3(0)}}};
  while (!stack.empty()) {
    const auto [v, at] = stack.back();
    stack.pop_back();
    const svo::VoxelRecord& r = tree.voxels[v];
    if (at.first == dims.finestLevel()) finest.push_back(at.second);
    for (int slot = 0, k = 0; slot < 8; ++slot)
      if (r.childMask >> slot & 1)
        stack.push_back(
            {r.firstChild + std::uint32_t(k++), {at.first + 1, svo::childCoord(at.second, slot)}});
  }
  ASSERT_EQ(finest.size(), dims.voxels(dims.finestLevel()));
  for (int c = 0; c <= dims.finestLevel(); ++c)
    for (int l = c; l <= dims.finestLevel(); ++l)
      EXPECT_NEAR(dims.count(c, l), bruteForceCount(finest, dims.finestLevel(), c, l),
                  1e-9 * dims.count(c, l));
}

// `svo ARGS` through a shell: what it wrote to stdout and to stderr, and its exit status.
struct SvoRun {
  int exit = -1;
  std::string out, err;
};
SvoRun svo(const std::string& args, const std::filesystem::path& dir) {
  const std::filesystem::path out = dir / "stdout.txt";
  std::string err =
      svotest::runShell("{ " + std::string(SVO_BINARY) + " " + args + " >" + out.string() + "; }");
  SvoRun r;
  const std::size_t last = err.rfind("exit ");
  if (last != std::string::npos) r.exit = std::stoi(err.substr(last + 5)), err.resize(last);
  r.err = err;
  std::ifstream in(out);
  std::stringstream text;
  text << in.rdbuf();
  r.out = text.str();
  return r;
}

// Failed with one line on stderr that names `needle`, and left nothing at `target`.
void expectCleanFailure(const SvoRun& r, const std::string& needle, const std::filesystem::path& target) {
  EXPECT_NE(r.exit, 0) << r.err;
  EXPECT_LT(r.exit, 128) << "crashed: " << r.err;
  EXPECT_NE(r.err.find(needle), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_FALSE(std::filesystem::exists(target)) << target;
}

// The data rows (after the header panel,series,x,y) of a plot's CSV whose series is `name`.
std::size_t plottedPoints(const std::filesystem::path& png, const std::string& name) {
  EXPECT_TRUE(std::filesystem::is_regular_file(png)) << png;
  std::filesystem::path csv = png;
  std::ifstream in(csv.replace_extension(".csv"));
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "panel,series,x,y") << csv;
  std::size_t count = 0;
  while (std::getline(in, line)) count += line.find("," + name + ",") != std::string::npos;
  return count;
}

// A copy of the store with a bit flipped in its last slice.
std::filesystem::path corruptCopy(const std::filesystem::path& store, const std::filesystem::path& dir) {
  const std::filesystem::path bad = dir / "bad.svo";
  std::filesystem::copy_file(store, bad);
  const svo::SliceInfo slice = svo::StoreReader(bad).slices().back();
  std::fstream f(bad, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(std::streamoff(slice.offset + slice.compressedBytes / 2));
  const char byte = char(f.get());
  f.seekp(std::streamoff(slice.offset + slice.compressedBytes / 2));
  f.put(char(byte ^ 0x20));
  return bad;
}

TEST(Dimensions, BadSliceIsNamed) {
  const svotest::TempDir dir;
  writeVoxelStore(dir.path() / "plane.svo", tiltedPlane(5), 5);
  std::string error;
  try {
    svo::measureDimensions(svo::StoreReader(corruptCopy(dir.path() / "plane.svo", dir.path())));
  } catch (const svo::SliceError& e) {
    error = e.what();
  }
  EXPECT_NE(error.find("checksum"), std::string::npos) << error;
  EXPECT_NE(error.find("slice"), std::string::npos) << error;
}

TEST(DimensionsCli, Inspect) {
  const svotest::TempDir dir;
  const std::filesystem::path store = dir.path() / "plane.svo", out = dir.path() / "dims";
  writeVoxelStore(store, tiltedPlane(6), 6);
  const SvoRun r = svo("inspect --dimensions " + store.string() + " -o " + out.string(), dir.path());
  ASSERT_EQ(r.exit, 0) << r.err;
  EXPECT_NE(r.out.find("D_scale(c, L)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("prediction"), std::string::npos) << r.out;
  // Four panels; the scene cube has no global or scale dimension (nothing above it), so its line is in the
  // first two only, one point per voxel level 1 to 6.
  EXPECT_EQ(plottedPoints(out / "dimensions.png", "cube level 0"), 12u);
  // --json: every N(c, L) the library measures over the same store.
  const SvoRun json =
      svo("inspect --dimensions --json " + store.string() + " -o " + out.string(), dir.path());
  ASSERT_EQ(json.exit, 0) << json.err;
  const nlohmann::json j = nlohmann::json::parse(json.out);
  const svo::VoxelDimensions dims = svo::measureDimensions(svo::StoreReader(store));
  ASSERT_EQ(j.at("finestLevel").get<int>(), 6);
  ASSERT_EQ(j.at("cubes").size(), 21u);  // 0 <= c < L <= 6
  for (const auto& cube : j.at("cubes"))
    EXPECT_DOUBLE_EQ(cube.at("N").get<double>(),
                     dims.count(cube.at("cubeLevel").get<int>(), cube.at("voxelLevel").get<int>()));
  ASSERT_EQ(j.at("prediction").size(), 9u);  // the base view, 4 distances, 4 image sizes
  EXPECT_DOUBLE_EQ(j.at("prediction")[0].at("relativeData").get<double>(), 1.0);

  const std::filesystem::path none = dir.path() / "none";
  const std::string good = "inspect " + store.string() + " ";
  expectCleanFailure(
      svo("inspect --dimensions " + (dir.path() / "missing.svo").string() + " -o " + none.string(),
          dir.path()),
      "missing.svo", none);
  expectCleanFailure(
      svo("inspect --dimensions " + corruptCopy(store, dir.path()).string() + " -o " + none.string(),
          dir.path()),
      "checksum", none);
  expectCleanFailure(svo(good + "--dimensions --view-level 7 -o " + none.string(), dir.path()),
                     "--view-level", none);
  expectCleanFailure(svo(good + "--dimensions --view-level 0 -o " + none.string(), dir.path()),
                     "--view-level", none);
  expectCleanFailure(svo(good + "--dimensions --steps 0 -o " + none.string(), dir.path()), "--steps", none);
  expectCleanFailure(svo(good + "-o " + none.string(), dir.path()), "--dimensions", none);
  expectCleanFailure(svo(good + "--dimensions -o " + (store / "x").string(), dir.path()), "folder",
                     store / "x");
  const SvoRun onFile = svo(good + "--dimensions -o " + store.string(), dir.path());
  EXPECT_EQ(onFile.exit, 2) << onFile.err;
  EXPECT_NE(onFile.err.find("is not a folder"), std::string::npos) << onFile.err;
}

TEST(DimensionsCli, Bench) {
  const svotest::TempDir dir;
  const std::filesystem::path store = dir.path() / "plane.svo", out = dir.path() / "check";
  writeVoxelStore(store, tiltedPlane(6), 6);
  const SvoRun r =
      svo("bench dimensions " + store.string() + " --size 64 --steps 2 -o " + out.string(), dir.path());
  ASSERT_EQ(r.exit, 0) << r.err;
  EXPECT_NE(r.out.find("doubling the distance"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("doubling the image size"), std::string::npos) << r.out;
  // Two panels, each with the base view and two doublings per line.
  EXPECT_EQ(plottedPoints(out / "dimensions_check.png", "predicted"), 6u);
  EXPECT_EQ(plottedPoints(out / "dimensions_check.png", "loaded (view)"), 6u);

  const std::filesystem::path none = dir.path() / "none";
  expectCleanFailure(
      svo("bench dimensions " + store.string() + " --size 16 --steps 2 -o " + none.string(), dir.path()),
      "--size", none);
  expectCleanFailure(
      svo("bench dimensions " + (dir.path() / "missing.svo").string() + " -o " + none.string(), dir.path()),
      "missing.svo", none);
  expectCleanFailure(
      svo("bench dimensions " + corruptCopy(store, dir.path()).string() + " -o " + none.string(), dir.path()),
      "checksum", none);
}

}  // namespace
