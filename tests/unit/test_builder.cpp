// The builder (builder/build.hpp) against independent references: the set of finest-level voxels equals the
// brute-force clipping reference (reference.hpp (b)); builds are deterministic across runs and thread counts;
// contours reduce the geometric error of ray hits against the true surface.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <random>
#include <sstream>
#include <string>

#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/raycast.hpp"

namespace {

// Boundary tolerance for the voxel sets, octree units. The builder works in double like the reference, but
// the two compute a triangle's octree coordinates and its clipped pieces along different paths, so a triangle
// that touches a cube face, edge or corner exactly (or within rounding) may count as overlapping in one and
// not in the other. 1e-9 is ~10^5 double ulps at [1,2] and 2^-7 / 1e-9 ~ 10^7 times below the finest voxel
// here.
constexpr double kEps = 1e-9;

std::string coordString(const glm::ivec3& c) {
  return "(" + std::to_string(c.x) + "," + std::to_string(c.y) + "," + std::to_string(c.z) + ")";
}

bool contains(const std::vector<glm::ivec3>& sorted, const glm::ivec3& c) {
  return std::binary_search(sorted.begin(), sorted.end(), c, [](const glm::ivec3& a, const glm::ivec3& b) {
    return svotest::packCoord(a) < svotest::packCoord(b);
  });
}

// Every point of every triangle must lie in some built voxel (closed cubes, up to kEps). Points are sampled
// on a barycentric grid fine enough for ~4 samples per voxel along each edge, plus vertices and edge
// midpoints.
std::string checkSurfaceCovered(const svo::Mesh& mesh, const svo::SceneTransform& transform, int levels,
                                const std::vector<glm::ivec3>& built) {
  const double cells = std::ldexp(1.0, levels);
  const int maxIndex = (1 << levels) - 1;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    glm::dvec3 g[3];
    for (int k = 0; k < 3; ++k)
      g[k] = (transform.toOctree(mesh.positions[mesh.triangles[t][k]]) - 1.0) * cells;
    const double longest =
        std::max({glm::length(g[1] - g[0]), glm::length(g[2] - g[1]), glm::length(g[0] - g[2])});
    const int n = std::clamp(int(std::ceil(longest * 4.0)), 2, 400);
    for (int i = 0; i <= n; ++i)
      for (int j = 0; i + j <= n; ++j) {
        const double a = double(i) / n, b = double(j) / n;
        const glm::dvec3 p = g[0] + a * (g[1] - g[0]) + b * (g[2] - g[0]);
        bool covered = false;
        const glm::ivec3 lo = glm::clamp(glm::ivec3(glm::floor(p - kEps * cells)), 0, maxIndex);
        const glm::ivec3 hi = glm::clamp(glm::ivec3(glm::floor(p + kEps * cells)), 0, maxIndex);
        for (int z = lo.z; z <= hi.z && !covered; ++z)
          for (int y = lo.y; y <= hi.y && !covered; ++y)
            for (int x = lo.x; x <= hi.x && !covered; ++x) covered = contains(built, {x, y, z});
        if (!covered) {
          std::ostringstream o;
          o << "triangle " << t << " point (" << p.x << "," << p.y << "," << p.z
            << ") [grid units] not covered";
          return o.str();
        }
      }
  }
  return "";
}

// Builds with and without contours and compares the finest-level voxel sets with the reference:
//   reference(shrunk by kEps) <= built <= reference(grown by kEps), every surface point covered,
// and the exact (unshrunk, ungrown) reference equal to the built set up to the boundary cases.
void expectCompleteVoxelSet(const std::string& name, const svo::Mesh& mesh, int levels) {
  SCOPED_TRACE(name);
  const svo::SceneTransform transform = svo::fitSceneCube(mesh);
  const auto grown = svotest::referenceLeafVoxels(mesh, transform, levels, kEps);
  const auto shrunk = svotest::referenceLeafVoxels(mesh, transform, levels, -kEps);
  const auto exact = svotest::referenceLeafVoxels(mesh, transform, levels, 0.0);
  std::vector<glm::ivec3> first;
  for (bool contours : {false, true}) {
    svo::BuildOptions options;
    options.levels = levels;
    options.contours = contours;
    const svo::VoxelTree tree = svo::voxelize(mesh, transform, options);
    const svo::Block block = svo::layoutBlock(tree);
    std::size_t otherLevels = 0, otherLevelsTree = 0;
    const auto built = svotest::leafCoords(svotest::walkLeaves(block.view()), levels, &otherLevels);
    const auto builtTree = svotest::leafCoords(svotest::walkLeaves(tree), levels, &otherLevelsTree);
    EXPECT_EQ(otherLevels, 0u) << "leaves above the finest level (contours " << contours << ")";
    EXPECT_EQ(otherLevelsTree, 0u);
    EXPECT_TRUE(built == builtTree) << "block and voxel tree disagree";
    std::size_t missing = 0, extra = 0;
    std::string firstMissing, firstExtra;
    for (const auto& c : shrunk)
      if (!contains(built, c) && missing++ == 0) firstMissing = coordString(c);
    for (const auto& c : built)
      if (!contains(grown, c) && extra++ == 0) firstExtra = coordString(c);
    EXPECT_EQ(missing, 0u) << "voxels the mesh overlaps but the builder left out (contours " << contours
                           << "), first " << firstMissing;
    EXPECT_EQ(extra, 0u) << "voxels the builder made that the mesh does not touch (contours " << contours
                         << "), first " << firstExtra;
    EXPECT_EQ(checkSurfaceCovered(mesh, transform, levels, built), "") << "contours " << contours;
    if (!contours)
      first = built;
    else
      EXPECT_TRUE(built == first) << "contours changed the voxel set: " << first.size() << " vs "
                                  << built.size();
    std::printf("[ VOXELS   ] %s L%d contours %d: built %zu, reference %zu (shrunk %zu, grown %zu)\n",
                name.c_str(), levels, int(contours), built.size(), exact.size(), shrunk.size(), grown.size());
  }
}

svo::Mesh offsetMesh(svo::Mesh m, const glm::dvec3& offset) {
  for (auto& p : m.positions) p += offset;
  return m;
}

}  // namespace

TEST(Builder, VoxelSetRandomTriangles) {
  expectCompleteVoxelSet("random triangles",
                         svotest::makeRandomTriangles(31, 200, {-1, -1, -1}, {1, 1, 1}, 0.3), 6);
}

TEST(Builder, VoxelSetSphere) {
  expectCompleteVoxelSet("sphere", svotest::makeSphere({0.1, 0.2, -0.3}, 2.0, 32, 32), 7);
}

TEST(Builder, VoxelSetAxisAlignedBox) {
  svo::Mesh m = svotest::makeBox({-1, -1, -1}, {1, 1, 1});
  svotest::appendMesh(m, svotest::makeBox({-0.5, -0.25, 0.0}, {0.25, 0.5, 0.75}));  // faces on grid planes
  expectCompleteVoxelSet("axis-aligned boxes", m, 6);
}

// One extent zero: the whole mesh lies in the plane z = const, which the scene cube puts on a grid plane.
TEST(Builder, VoxelSetFlatMesh) {
  svo::Mesh m = svotest::makeRandomTriangles(32, 100, {-1, -1, 0.5}, {1, 1, 0.5}, 0.5);
  expectCompleteVoxelSet("flat", m, 6);
}

// Triangles much smaller than a voxel (1e-4 voxels), some straddling voxel boundaries.
TEST(Builder, VoxelSetTinyTriangles) {
  const double voxel = 2.0 / 64.0;
  svo::Mesh m = svotest::makeRandomTriangles(33, 500, {-1, -1, -1}, {1, 1, 1}, 1e-4 * voxel);
  svotest::appendMesh(m, svotest::makeBox({-1, -1, -1}, {1, 1, 1}));  // fixes the scene cube
  expectCompleteVoxelSet("tiny triangles", m, 6);
}

// Huge triangles spanning the scene.
TEST(Builder, VoxelSetHugeTriangles) {
  svo::Mesh m;
  m.positions = {{-1, -1, -1}, {1, 1, -1}, {1, -1, 1}, {-1, 1, 1}, {1, 1, 1}, {-1, -0.9, 0.8}};
  m.triangles = {{0, 1, 2}, {0, 3, 4}, {1, 3, 5}, {2, 4, 5}};
  expectCompleteVoxelSet("huge triangles", m, 6);
}

// Far from the origin: the same sphere offset by 1e6, in double world coordinates.
TEST(Builder, VoxelSetFarFromOrigin) {
  const svo::Mesh sphere = svotest::makeSphere({0.0, 0.0, 0.0}, 1.0, 16, 24);
  const svo::Mesh far = offsetMesh(sphere, {1e6, -1e6, 3e6});
  expectCompleteVoxelSet("far sphere", far, 6);
  // The same voxels as the sphere at the origin, up to rounding: the scene cube is placed relative to the
  // bounds, and 1e6 has a double ulp of ~1e-10, well inside kEps.
  svo::BuildOptions options;
  options.levels = 6;
  const auto farSet = svotest::leafCoords(
      svotest::walkLeaves(svo::voxelize(far, svo::fitSceneCube(far), options)), 6, nullptr);
  const svo::SceneTransform nearTransform = svo::fitSceneCube(sphere);
  const auto nearGrown = svotest::referenceLeafVoxels(sphere, nearTransform, 6, kEps);
  const auto nearShrunk = svotest::referenceLeafVoxels(sphere, nearTransform, 6, -kEps);
  std::size_t missing = 0, extra = 0;
  for (const auto& c : nearShrunk) missing += !contains(farSet, c);
  for (const auto& c : farSet) extra += !contains(nearGrown, c);
  EXPECT_EQ(missing, 0u);
  EXPECT_EQ(extra, 0u);
}

TEST(Builder, ReferenceSelfCheck) {
  // The clipping reference on hand-made cases: touching faces, edges and corners count (closed boxes).
  const glm::dvec3 lo(0.0), hi(1.0);
  EXPECT_TRUE(svotest::triangleBoxOverlap({0.5, 0.5, 0.5}, {5, 0.5, 0.5}, {0.5, 5, 0.5}, lo, hi));
  EXPECT_TRUE(svotest::triangleBoxOverlap({1, 0.2, 0.2}, {2, 0.2, 0.2}, {1, 0.8, 0.9}, lo, hi));  // on a face
  EXPECT_TRUE(svotest::triangleBoxOverlap({1, 1, 1}, {2, 1, 1}, {2, 2, 1}, lo, hi));  // at a corner
  EXPECT_FALSE(svotest::triangleBoxOverlap({1.001, 0, 0}, {2, 0, 0}, {2, 1, 1}, lo, hi));
  // Separated only along a cross-product axis: the bounding boxes overlap, the triangle misses the corner.
  EXPECT_FALSE(
      svotest::triangleBoxOverlap({1.6, 0, 0.5}, {0, 1.6, 0.5}, {1.6, 1.6, 0.5}, {0, 0, 0}, {0.75, 0.75, 1}));
  EXPECT_TRUE(
      svotest::triangleBoxOverlap({1.4, 0, 0.5}, {0, 1.4, 0.5}, {1.4, 1.4, 0.5}, {0, 0, 0}, {0.75, 0.75, 1}));
  // A segment (degenerate triangle) through the box.
  EXPECT_TRUE(svotest::triangleBoxOverlap({-1, 0.5, 0.5}, {2, 0.5, 0.5}, {2, 0.5, 0.5}, lo, hi));
}

// ---------------------------------------------------------------------------------------------------------
// Determinism: the same input gives the same bytes, whatever the thread count.

TEST(Builder, DeterministicAcrossRunsAndThreads) {
  svo::Mesh m = svotest::makeSphere({0, 0, 0}, 1.0, 24, 24);
  svotest::appendMesh(m, svotest::makeRandomTriangles(34, 300, {-1, -1, -1}, {1, 1, 1}, 0.3));
  m.colors.resize(m.positions.size());
  std::mt19937 rng(35);
  for (auto& c : m.colors) c = glm::vec4(float(rng() % 256) / 255.0f, 0.5f, float(rng() % 7) / 7.0f, 1.0f);
  svo::BuildOptions options;
  options.levels = 7;
  options.contours = true;
  std::vector<std::vector<std::byte>> results;
  for (int threads : {0, 1, 2, 3, 0}) {
    std::unique_ptr<tbb::global_control> limit;
    if (threads > 0)
      limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism, threads);
    const svo::Octree o = svo::buildOctree(m, options);
    const auto* p = o.block.bytes().data();
    results.emplace_back(p, p + o.block.bytes().size());
  }
  for (std::size_t i = 1; i < results.size(); ++i) {
    ASSERT_EQ(results[i].size(), results[0].size()) << "run " << i;
    EXPECT_EQ(std::memcmp(results[i].data(), results[0].data(), results[0].size()), 0) << "run " << i;
  }
}

// ---------------------------------------------------------------------------------------------------------
// Contours reduce the geometric error of ray hits (sec. 5.2).

namespace {

struct ErrorStats {
  double mean = 0.0, max = 0.0;
  std::size_t hits = 0;
};

// Casts rays from outside towards the scene and measures the distance from each hit point (the ray point at
// the hit t) to the true surface, in finest-voxel units.
template <class Distance>
ErrorStats surfaceError(const svo::Octree& octree, bool contours, int rays, std::uint64_t seed,
                        Distance distance) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> g;
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::vector<svo::OctreeRay> all(rays);
  for (auto& r : all) {
    glm::dvec3 dir(g(rng), g(rng), g(rng));
    dir = glm::normalize(dir);
    const glm::dvec3 o = glm::dvec3(1.5) + 2.0 * dir;
    const glm::dvec3 target = 1.25 + 0.5 * glm::dvec3(uni(rng), uni(rng), uni(rng));
    r.origin = glm::vec3(o);
    r.direction = glm::vec3(glm::normalize(target - o));
  }
  std::vector<double> err(rays, -1.0);
  const svo::BlockView view = octree.block.view();
  const double voxel = std::ldexp(1.0, -octree.parameters.levels);
  tbb::parallel_for(0, rays, [&](int i) {
    svo::CastOptions options;
    options.contours = contours;
    const svo::CastHit hit = svo::castRay(view, all[i], options);
    if (!hit.hit) return;
    const glm::dvec3 p = glm::dvec3(all[i].origin) + double(hit.t) * glm::dvec3(all[i].direction);
    err[i] = distance(octree.transform.toWorld(p)) / octree.transform.size / voxel;
  });
  ErrorStats s;
  for (double e : err) {
    if (e < 0.0) continue;
    ++s.hits;
    s.mean += e;
    s.max = std::max(s.max, e);
  }
  if (s.hits) s.mean /= double(s.hits);
  return s;
}

std::filesystem::path bunnyPath() {
  if (const char* env = std::getenv("SVO_BUNNY")) return env;
  // Where tools/scripts/fetch-data.sh puts it by default: <binary dir>/data/bunny.ply.
  const std::filesystem::path binaryDir = std::filesystem::path(SVO_BINARY).parent_path().parent_path();
  for (const auto& p : {binaryDir / "data" / "bunny.ply",
                        std::filesystem::path(SVO_SOURCE_DIR) / "build" / "data" / "bunny.ply"})
    if (std::filesystem::exists(p)) return p;
  return {};
}

}  // namespace

TEST(Builder, ContoursReduceErrorSphere) {
  const glm::dvec3 centre(0.2, -0.1, 0.3);
  const double radius = 1.0;
  // Fine tessellation: chord error r (1 - cos(pi / 128)) ~ 3e-4 r, ~0.02 finest voxels at level 7.
  const svo::Mesh m = svotest::makeSphere(centre, radius, 128, 256);
  svo::BuildOptions options;
  options.levels = 7;
  options.contours = true;
  const svo::Octree o = svo::buildOctree(m, options);
  const auto distance = [&](const glm::dvec3& p) { return std::abs(glm::length(p - centre) - radius); };
  const ErrorStats cubes = surfaceError(o, false, 20000, 41, distance);
  const ErrorStats cont = surfaceError(o, true, 20000, 41, distance);
  std::printf(
      "[ ERROR    ] sphere L7: cubes mean %.3f max %.3f vx; contours mean %.3f max %.3f vx (%zu / %zu "
      "hits)\n",
      cubes.mean, cubes.max, cont.mean, cont.max, cubes.hits, cont.hits);
  ASSERT_GT(cubes.hits, 5000u);
  ASSERT_GT(cont.hits, 5000u);
  // Cube voxels: a hit is within the voxel's diagonal of the surface (sqrt(3) voxels, plus chord error).
  EXPECT_LE(cubes.max, std::sqrt(3.0) + 0.05);
  // measured (20000 rays, L7, RelWithDebInfo): cubes mean 0.752 vx, max 1.650 vx; contours mean 0.016 vx,
  // max 0.119 vx. Asserted with margin: contours at least 4x better on average, mean within 0.1 voxel and
  // max within half a voxel of the sphere.
  EXPECT_LT(cont.mean, 0.25 * cubes.mean);
  EXPECT_LT(cont.mean, 0.1);
  EXPECT_LT(cont.max, 0.5);
}

TEST(Builder, ContoursReduceErrorBunny) {
  const std::filesystem::path path = bunnyPath();
  if (path.empty() || !std::filesystem::exists(path))
    GTEST_SKIP() << "bunny not found: set SVO_BUNNY or run tools/scripts/fetch-data.sh";
  const svo::Mesh m = svo::loadMesh(path);
  ASSERT_GT(m.triangles.size(), 1000u);
  svo::BuildOptions options;
  options.levels = 7;
  options.contours = true;
  const svo::Octree o = svo::buildOctree(m, options);
  // Brute-force point-to-mesh distance, with a bounding-sphere cull per triangle that keeps it exact.
  struct Tri {
    glm::dvec3 a, b, c, centre;
    double radius;
  };
  std::vector<Tri> tris;
  for (const auto& t : m.triangles) {
    Tri r{m.positions[t[0]], m.positions[t[1]], m.positions[t[2]], {}, 0.0};
    r.centre = (r.a + r.b + r.c) / 3.0;
    r.radius =
        std::max({glm::length(r.a - r.centre), glm::length(r.b - r.centre), glm::length(r.c - r.centre)});
    tris.push_back(r);
  }
  const auto distance = [&](const glm::dvec3& p) {
    double best = svotest::kInf;
    for (const Tri& t : tris) {
      if (glm::length(p - t.centre) - t.radius >= best) continue;
      best = std::min(best, svotest::pointTriangleDistance(p, t.a, t.b, t.c));
    }
    return best;
  };
  const ErrorStats cubes = surfaceError(o, false, 3000, 42, distance);
  const ErrorStats cont = surfaceError(o, true, 3000, 42, distance);
  std::printf(
      "[ ERROR    ] bunny L7: cubes mean %.3f max %.3f vx; contours mean %.3f max %.3f vx (%zu / %zu hits)\n",
      cubes.mean, cubes.max, cont.mean, cont.max, cubes.hits, cont.hits);
  ASSERT_GT(cubes.hits, 500u);
  // Cube voxels: within the voxel diagonal of the mesh (the mesh is the true surface here).
  EXPECT_LE(cubes.max, std::sqrt(3.0) + 1e-3);
  // measured (3000 rays, npm bunny, L7): cubes mean 0.756 vx, max 1.578 vx; contours mean 0.032 vx, max
  // 0.334 vx. Asserted with margin: contours at least 3x better on average, mean within 0.15 voxel, max
  // within the cube bound.
  EXPECT_LT(cont.mean, cubes.mean / 3.0);
  EXPECT_LT(cont.mean, 0.15);
  EXPECT_LE(cont.max, std::sqrt(3.0) + 1e-3);
}
