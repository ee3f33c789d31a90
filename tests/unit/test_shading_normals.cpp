// Shading normals (builder/mesh.hpp): the crease rule on analytic meshes, and the voxel normals the builder
// makes from them against the true normal of the surface a coarse mesh approximates.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <random>

#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/mesh.hpp"
#include "svo/client/raycast.hpp"

namespace {

double degreesBetween(const glm::dvec3& a, const glm::dvec3& b) {
  return std::acos(std::clamp(glm::dot(glm::normalize(a), glm::normalize(b)), -1.0, 1.0)) * 180.0 /
         std::numbers::pi;
}

glm::dvec3 faceNormal(const svo::Mesh& m, const glm::uvec3& t) {
  return glm::normalize(glm::cross(m.positions[t.y] - m.positions[t.x], m.positions[t.z] - m.positions[t.x]));
}

// The same triangles with three vertices of their own each: no vertex is shared, so every corner's normal is
// its triangle's (what the builder made of every mesh before shading normals).
svo::Mesh unshared(const svo::Mesh& m) {
  svo::Mesh out;
  for (const glm::uvec3& t : m.triangles) {
    const std::uint32_t base = std::uint32_t(out.positions.size());
    for (int k = 0; k < 3; ++k) out.positions.push_back(m.positions[t[k]]);
    out.triangles.emplace_back(base, base + 1, base + 2);
  }
  return out;
}

struct AngleStats {
  double mean = 0.0, max = 0.0;
  std::size_t hits = 0;
};

// The hit voxels' normals against `truth(world hit point)` for rays from all around at the scene's
// middle: degrees. Hits where `use(world point)` is false are skipped.
template <class Truth, class Use>
AngleStats normalError(const svo::Octree& octree, int rays, Truth truth, Use use) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> g;
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const svo::BlockView view = octree.block.view();
  AngleStats s;
  for (int i = 0; i < rays; ++i) {
    const glm::dvec3 dir = glm::normalize(glm::dvec3(g(rng), g(rng), g(rng)));
    svo::OctreeRay ray;
    const glm::dvec3 origin = glm::dvec3(1.5) + 2.0 * dir;
    const glm::dvec3 target = 1.3 + 0.4 * glm::dvec3(uni(rng), uni(rng), uni(rng));
    ray.origin = glm::vec3(origin);
    ray.direction = glm::vec3(glm::normalize(target - origin));
    const svo::CastHit hit = svo::castRay(view, ray);
    if (!hit.hit) continue;
    const glm::dvec3 p =
        octree.transform.toWorld(glm::dvec3(ray.origin) + double(hit.t) * glm::dvec3(ray.direction));
    if (!use(p)) continue;
    // Unsigned: the renderer lights the side a ray sees, whichever way a mesh is wound.
    const double e = std::min(degreesBetween(glm::dvec3(svo::hitNormal(view, hit)), truth(p)),
                              degreesBetween(-glm::dvec3(svo::hitNormal(view, hit)), truth(p)));
    s.mean += e, s.max = std::max(s.max, e), ++s.hits;
  }
  if (s.hits) s.mean /= double(s.hits);
  return s;
}

// normalError's `use` that keeps every hit.
bool everywhere(const glm::dvec3&) {
  return true;
}

}  // namespace

// A box's corners are 54.7 degrees off each of its faces: every corner keeps its face's normal (a crease).
// An icosahedron's vertices are 37.4 degrees off its faces: every corner takes its vertex's normal, which by
// symmetry points from the centre through the vertex.
TEST(ShadingNormals, CornersCreaseABoxAndSmoothAnIcosahedron) {
  const svo::Mesh box = svotest::makeBox({-1, -2, -3}, {2, 1, 0.5});
  const auto boxCorners = svo::cornerNormals(box);
  ASSERT_EQ(boxCorners.size(), box.triangles.size());
  for (std::size_t t = 0; t < box.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k)
      EXPECT_LT(degreesBetween(glm::dvec3(boxCorners[t][k]), faceNormal(box, box.triangles[t])), 1e-4)
          << "triangle " << t << " corner " << k;

  svo::Mesh ico;
  const double phi = (1.0 + std::sqrt(5.0)) / 2.0;
  for (const double a : {-1.0, 1.0})
    for (const double b : {-phi, phi}) {
      ico.positions.emplace_back(0.0, a, b);
      ico.positions.emplace_back(a, b, 0.0);
      ico.positions.emplace_back(b, 0.0, a);
    }
  // Faces: the triples of mutually adjacent vertices (edge length 2), wound outwards.
  const std::size_t n = ico.positions.size();
  for (std::uint32_t i = 0; i < n; ++i)
    for (std::uint32_t j = i + 1; j < n; ++j)
      for (std::uint32_t k = j + 1; k < n; ++k) {
        const auto adjacent = [&](std::uint32_t a, std::uint32_t b) {
          return std::abs(glm::length(ico.positions[a] - ico.positions[b]) - 2.0) < 1e-9;
        };
        if (!adjacent(i, j) || !adjacent(j, k) || !adjacent(i, k)) continue;
        const glm::dvec3 n0 =
            glm::cross(ico.positions[j] - ico.positions[i], ico.positions[k] - ico.positions[i]);
        ico.triangles.push_back(glm::dot(n0, ico.positions[i]) > 0.0 ? glm::uvec3(i, j, k)
                                                                     : glm::uvec3(i, k, j));
      }
  ASSERT_EQ(ico.triangles.size(), 20u);
  const auto icoCorners = svo::cornerNormals(ico);
  for (std::size_t t = 0; t < ico.triangles.size(); ++t)
    for (int k = 0; k < 3; ++k)
      EXPECT_LT(degreesBetween(glm::dvec3(icoCorners[t][k]), ico.positions[ico.triangles[t][k]]), 1e-4)
          << "triangle " << t << " corner " << k;

  // Normals given with the mesh are taken as they are.
  ico.normals.assign(ico.positions.size(), glm::vec3(0.0f, 0.0f, 1.0f));
  for (const auto& corners : svo::cornerNormals(ico))
    for (const glm::vec3& c : corners) EXPECT_EQ(c, glm::vec3(0.0f, 0.0f, 1.0f));
}

// A coarse sphere (8 stacks, 12 slices: facets 22.5 and 30 degrees wide) built at 6 levels: the voxels'
// normals follow the sphere, not the facets, as a renderer interpolating the mesh's normals shades it.
TEST(ShadingNormals, VoxelNormalsFollowTheSurfaceACoarseMeshApproximates) {
  const glm::dvec3 centre(0.1, -0.2, 0.05);
  const svo::Mesh sphere = svotest::makeSphere(centre, 1.0, 8, 12);
  svo::BuildOptions options;
  options.levels = 6;
  const auto radial = [&](const glm::dvec3& p) { return p - centre; };
  const AngleStats smooth = normalError(svo::buildOctree(sphere, options), 4000, radial, everywhere);
  const AngleStats faceted =
      normalError(svo::buildOctree(unshared(sphere), options), 4000, radial, everywhere);
  std::printf(
      "[ NORMALS  ] coarse sphere L6: shading normals mean %.2f max %.2f deg; face normals mean %.2f "
      "max %.2f deg (%zu / %zu hits)\n",
      smooth.mean, smooth.max, faceted.mean, faceted.max, smooth.hits, faceted.hits);
  ASSERT_GT(smooth.hits, 2000u);
  ASSERT_GT(faceted.hits, 2000u);
  // A facet's normal is up to half its width (15 degrees) off the sphere's; the interpolated normals are off
  // by the chord's bulge only. Measured (4000 rays, L6): shading normals mean 1.13, max 3.35 degrees; face
  // normals mean 8.49, max 17.73. Asserted with margin.
  EXPECT_LT(smooth.mean, 0.35 * faceted.mean);
  EXPECT_LT(smooth.mean, 2.0);
  EXPECT_LT(smooth.max, 6.0);
}

// A box shares its eight corners between faces, and its faces stay flat: away from the edges, the voxels'
// normals are the faces' axes.
TEST(ShadingNormals, ABoxKeepsFlatFaces) {
  const glm::dvec3 lo(-1.0, -0.5, -0.75), hi(1.0, 0.5, 0.75);
  svo::BuildOptions options;
  options.levels = 6;
  const svo::Octree octree = svo::buildOctree(svotest::makeBox(lo, hi), options);
  // Two finest voxels (the scene cube is 2 wide: 2 / 64 each) from every edge.
  const double margin = 2.0 * 2.0 / 64.0;
  const auto axisOf = [&](const glm::dvec3& p) {
    const glm::dvec3 below = glm::abs(p - lo), above = glm::abs(hi - p);
    glm::dvec3 n(0.0);
    double nearest = 1e30;
    for (int i = 0; i < 3; ++i) {
      if (below[i] < nearest) nearest = below[i], n = glm::dvec3(0.0), n[i] = -1.0;
      if (above[i] < nearest) nearest = above[i], n = glm::dvec3(0.0), n[i] = 1.0;
    }
    return n;
  };
  const auto awayFromEdges = [&](const glm::dvec3& p) {
    int near = 0;
    for (int i = 0; i < 3; ++i) near += std::min(std::abs(p[i] - lo[i]), std::abs(hi[i] - p[i])) < margin;
    return near == 1;
  };
  const AngleStats s = normalError(octree, 4000, axisOf, awayFromEdges);
  std::printf("[ NORMALS  ] box L6 away from edges: mean %.3f max %.3f deg (%zu hits)\n", s.mean, s.max,
              s.hits);
  ASSERT_GT(s.hits, 1000u);
  EXPECT_LT(s.max, 0.5);  // the normal encoding's rounding
}

// A file's own normals are what the voxels show: a flat square whose OBJ normals lean 36.9 degrees off its
// plane builds to voxels with those normals; the same square without normals shows its plane's.
TEST(ShadingNormals, AFilesOwnNormalsAreKept) {
  svotest::TempDir dir;
  const std::string square = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n";
  const svo::Mesh leaning =
      svo::loadMesh(dir.file("leaning.obj", square + "vn 0 0.6 0.8\nf 1//1 2//1 3//1\nf 1//1 3//1 4//1\n"));
  const svo::Mesh plain = svo::loadMesh(dir.file("plain.obj", square + "f 1 2 3\nf 1 3 4\n"));
  ASSERT_EQ(leaning.normals.size(), leaning.positions.size());
  EXPECT_TRUE(plain.normals.empty());
  svo::BuildOptions options;
  options.levels = 5;
  const auto isLeaning = [](const glm::dvec3&) { return glm::dvec3(0.0, 0.6, 0.8); };
  const auto isPlane = [](const glm::dvec3&) { return glm::dvec3(0.0, 0.0, 1.0); };
  const AngleStats kept = normalError(svo::buildOctree(leaning, options), 2000, isLeaning, everywhere);
  const AngleStats derived = normalError(svo::buildOctree(plain, options), 2000, isPlane, everywhere);
  std::printf(
      "[ NORMALS  ] square with the file's normals: mean %.3f max %.3f deg; without: mean %.3f max %.3f "
      "deg (%zu / %zu hits)\n",
      kept.mean, kept.max, derived.mean, derived.max, kept.hits, derived.hits);
  ASSERT_GT(kept.hits, 500u);
  ASSERT_GT(derived.hits, 500u);
  // Within the stored normal's rounding (8 bits per octahedral coordinate; measured 0.378 and 0.004 degrees).
  EXPECT_LT(kept.max, 1.0);
  EXPECT_LT(derived.max, 1.0);
}
