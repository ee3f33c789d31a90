// The voxelizer's geometric kernels (builder/src/geometry.hpp) against independent brute-force references:
//  - hullVertices: every triple of the 6 cube planes and 4 slab planes solved as a 3x3 system, the points
//    inside everything kept; the two vertex sets must give the same extent along any direction;
//  - triangleOverlapsCube: the reference separating-axis test of reference.hpp (a), on random triangles and
//    on triangles that touch the cube exactly along a face, an edge or at a corner;
//  - clipTriangleToCube: every clipped vertex lies in the cube and on the triangle's plane, and the clipped
//    area matches a Monte Carlo estimate of the triangle's area inside the cube.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <random>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/mat3x3.hpp>

#include "geometry.hpp"
#include "reference.hpp"

namespace {

using glm::dvec3;
using svo::geom::Cube;
using svo::geom::Slab;

dvec3 randomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> g;
  dvec3 v;
  do v = dvec3(g(rng), g(rng), g(rng));
  while (glm::length(v) < 1e-6);
  return glm::normalize(v);
}

// Brute force: all 3-plane intersections of the cube's faces and the slabs' planes, kept when inside all.
std::vector<dvec3> referenceHull(const Cube& cube, const std::vector<Slab>& slabs) {
  struct Plane {
    dvec3 n;
    double d;
  };
  std::vector<Plane> planes;
  for (int a = 0; a < 3; ++a) {
    dvec3 n(0.0);
    n[a] = 1.0;
    planes.push_back({n, cube.lo[a]});
    planes.push_back({n, cube.lo[a] + cube.size});
  }
  for (const Slab& s : slabs) planes.push_back({s.normal, s.lo}), planes.push_back({s.normal, s.hi});
  const double eps = 1e-9 * cube.size;
  std::vector<dvec3> out;
  for (std::size_t i = 0; i < planes.size(); ++i)
    for (std::size_t j = i + 1; j < planes.size(); ++j)
      for (std::size_t k = j + 1; k < planes.size(); ++k) {
        const glm::dmat3 m = glm::transpose(glm::dmat3(planes[i].n, planes[j].n, planes[k].n));
        if (std::abs(glm::determinant(m)) < 1e-12) continue;
        const dvec3 x = glm::inverse(m) * dvec3(planes[i].d, planes[j].d, planes[k].d);
        bool inside = true;
        for (int a = 0; a < 3; ++a)
          inside &= x[a] >= cube.lo[a] - eps && x[a] <= cube.lo[a] + cube.size + eps;
        for (const Slab& s : slabs) {
          const double v = glm::dot(s.normal, x);
          inside &= v >= s.lo - eps && v <= s.hi + eps;
        }
        if (inside) out.push_back(x);
      }
  return out;
}

// A slab through a random point of the cube with a random normal and thickness (sometimes zero).
Slab randomSlab(std::mt19937_64& rng, const Cube& cube) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const dvec3 n = randomUnit(rng);
  const dvec3 p = cube.lo + cube.size * dvec3(u(rng), u(rng), u(rng));
  const double thickness = u(rng) < 0.1 ? 0.0 : 0.6 * cube.size * u(rng);
  const double c = glm::dot(n, p);
  return {n, c - 0.5 * thickness, c + 0.5 * thickness};
}

TEST(Geometry, HullVerticesSpanTheSameExtentsAsAllPlaneTriples) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  int nonEmpty = 0;
  for (int trial = 0; trial < 3000; ++trial) {
    const Cube cube{dvec3(1.0) + dvec3(u(rng), u(rng), u(rng)) * 0.5, std::ldexp(1.0, -int(u(rng) * 20))};
    std::vector<Slab> slabs;
    const int count = trial % 3;  // 0, 1 or 2 slabs
    for (int i = 0; i < count; ++i) slabs.push_back(randomSlab(rng, cube));
    // Axis-aligned slab normals and normals in a coordinate plane: the parallel cases.
    if (trial % 7 == 0 && count > 0)
      slabs[0].normal = dvec3(0, 1, 0), slabs[0].lo = slabs[0].hi = cube.centre().y;
    if (trial % 11 == 0 && count > 1) slabs[1].normal = glm::normalize(dvec3(1, 0, 1));
    const svo::geom::HullVertices hull = svo::geom::hullVertices(cube, slabs);
    const std::vector<dvec3> ref = referenceHull(cube, slabs);
    ASSERT_EQ(hull.empty(), ref.empty()) << "trial " << trial;
    if (ref.empty()) continue;
    ++nonEmpty;
    for (int k = 0; k < 16; ++k) {
      const dvec3 dir = randomUnit(rng);
      double lo = 1e300, hi = -1e300, refLo = 1e300, refHi = -1e300;
      for (const dvec3& v : hull.vertices())
        lo = std::min(lo, glm::dot(dir, v)), hi = std::max(hi, glm::dot(dir, v));
      for (const dvec3& v : ref)
        refLo = std::min(refLo, glm::dot(dir, v)), refHi = std::max(refHi, glm::dot(dir, v));
      ASSERT_NEAR(lo, refLo, 1e-9 * cube.size) << "trial " << trial;
      ASSERT_NEAR(hi, refHi, 1e-9 * cube.size) << "trial " << trial;
    }
  }
  EXPECT_GT(nonEmpty, 2000);
}

TEST(Geometry, TriangleOverlapsCubeAgreesWithTheReferenceTest) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 2.0);
  const Cube cube{dvec3(0.0), 1.0};
  int overlaps = 0, trials = 0;
  const auto check = [&](const dvec3& a, const dvec3& b, const dvec3& c) {
    const bool ours = svo::geom::triangleOverlapsCube(a, b, c, cube);
    const bool ref = svotest::triangleBoxOverlap(a, b, c, cube.lo, cube.lo + cube.size);
    ASSERT_EQ(ours, ref) << "triangle (" << a.x << "," << a.y << "," << a.z << ") (" << b.x << "," << b.y
                         << "," << b.z << ") (" << c.x << "," << c.y << "," << c.z << ")";
    overlaps += ours, ++trials;
  };
  for (int i = 0; i < 200000; ++i) {
    const dvec3 a(u(rng), u(rng), u(rng));
    check(a, a + 0.6 * dvec3(u(rng), u(rng), u(rng)), a + 0.6 * dvec3(u(rng), u(rng), u(rng)));
  }
  // Exact contacts: a triangle in the plane x = 1 (the face), one through the edge x = y = 1 only, one with a
  // vertex on the corner (1, 1, 1) pointing away, and the same moved out by one ulp (no contact).
  check({1, 0.2, 0.3}, {1, 0.7, 0.1}, {1, 0.5, 0.9});
  check({1, 1, 0.2}, {1, 1, 0.8}, {2, 2, 0.5});
  check({1, 1, 1}, {2, 1.5, 1.2}, {1.5, 2, 1.7});
  const double out = std::nextafter(1.0, 2.0);
  check({out, out, out}, {2, 1.5, 1.2}, {1.5, 2, 1.7});
  check({out, 0.2, 0.3}, {out, 0.7, 0.1}, {out, 0.5, 0.9});
  EXPECT_GT(overlaps, trials / 10);
  EXPECT_LT(overlaps, trials - trials / 10);
}

TEST(Geometry, ClippedPolygonIsInTheCubeOnThePlaneWithTheRightArea) {
  std::mt19937_64 rng(13);
  std::uniform_real_distribution<double> u(-0.5, 1.5), unit(0.0, 1.0);
  const Cube cube{dvec3(0.0), 1.0};
  int clipped = 0;
  for (int i = 0; i < 300; ++i) {
    const dvec3 a(u(rng), u(rng), u(rng)), b(u(rng), u(rng), u(rng)), c(u(rng), u(rng), u(rng));
    const svo::geom::Polygon p = svo::geom::clipTriangleToCube(a, b, c, cube);
    const dvec3 n = glm::normalize(glm::cross(b - a, c - a));
    for (const dvec3& v : p.vertices()) {
      for (int k = 0; k < 3; ++k) {
        ASSERT_GE(v[k], -1e-12);
        ASSERT_LE(v[k], 1.0 + 1e-12);
      }
      ASSERT_NEAR(glm::dot(n, v - a), 0.0, 1e-12);
    }
    // Monte Carlo: the fraction of uniform samples of the triangle inside the cube.
    constexpr int kSamples = 20000;
    int inside = 0;
    for (int s = 0; s < kSamples; ++s) {
      double r1 = unit(rng), r2 = unit(rng);
      if (r1 + r2 > 1.0) r1 = 1.0 - r1, r2 = 1.0 - r2;
      const dvec3 x = a + r1 * (b - a) + r2 * (c - a);
      inside += x.x >= 0 && x.x <= 1 && x.y >= 0 && x.y <= 1 && x.z >= 0 && x.z <= 1;
    }
    const double triangleArea = 0.5 * glm::length(glm::cross(b - a, c - a));
    const double expected = triangleArea * inside / kSamples;
    // 4 binomial standard deviations of the estimate.
    const double sigma = triangleArea * std::sqrt(0.25 / kSamples);
    EXPECT_NEAR(svo::geom::polygonArea(p, nullptr), expected, 4.0 * sigma + 1e-12) << "triangle " << i;
    clipped += p.n > 3;
  }
  EXPECT_GT(clipped, 30);
}

}  // namespace
