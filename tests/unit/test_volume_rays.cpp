// The ray-casting peers of `svo bench volume` (tools/bench/vdb_peer.hpp, OpenVDB's LevelSetRayIntersector)
// on a level-set sphere made by OpenVDB, against the analytic sphere: both find every ray that meets the
// sphere clearly (not grazing it), miss every ray that passes it clearly, and put their hits within a voxel
// of the analytic surface; near the origin and far from it.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include <glm/geometric.hpp>

#ifdef SVO_TEST_NANOVDB
#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/RayIntersector.h>

#include "vdb_peer.hpp"
#endif

namespace {

#ifdef SVO_TEST_NANOVDB
// Rays whose closest approach to the sphere's surface is within this many voxels count as grazing: the
// narrow band's discretization may decide either way there.
constexpr double kGrazingVoxels = 1.0;

// The analytic hit distance of a unit-direction ray on the sphere, infinity on a miss; `clearance` is how far
// (world units) the ray's closest approach lies from the surface.
double sphereHit(const glm::dvec3& eye, const glm::dvec3& d, const glm::dvec3& centre, double radius,
                 double& clearance) {
  const double along = glm::dot(centre - eye, d);
  const double closest = glm::length(eye + along * d - centre);
  clearance = std::abs(closest - radius);
  if (closest >= radius) return INFINITY;
  return along - std::sqrt(radius * radius - closest * closest);
}

void checkSphere(const glm::dvec3& centre) {
  openvdb::initialize();
  const double radius = 1.0, voxel = 0.05;
  const auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
      float(radius), openvdb::Vec3f(float(centre.x), float(centre.y), float(centre.z)), float(voxel));
  // createLevelSetSphere takes a float centre: the analytic sphere is the one it was given.
  const glm::dvec3 c(float(centre.x), float(centre.y), float(centre.z));
  const svo::tools::bench::NanoLevelSet nano(*grid);
  auto nanoAccessor = nano.accessor();
  openvdb::tools::LevelSetRayIntersector<openvdb::FloatGrid> vdb(*grid);

  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  int hits = 0, misses = 0;
  for (int i = 0; i < 400; ++i) {
    const glm::dvec3 eye = c + glm::normalize(glm::dvec3(unit(rng), unit(rng), unit(rng))) * 4.0;
    const glm::dvec3 target = c + glm::dvec3(unit(rng), unit(rng), unit(rng)) * 1.3;
    const glm::dvec3 d = glm::normalize(target - eye);
    double clearance = 0.0;
    const double want = sphereHit(eye, d, c, radius, clearance);
    if (clearance < kGrazingVoxels * voxel) continue;
    SCOPED_TRACE(::testing::Message() << "ray " << i);

    const double tNano = nano.intersect(nanoAccessor, eye, d);
    openvdb::Vec3d hit;
    double tVdb = INFINITY;
    const bool vdbHit = vdb.intersectsWS(
        openvdb::math::Ray<double>(openvdb::Vec3d(eye.x, eye.y, eye.z), openvdb::Vec3d(d.x, d.y, d.z)), hit,
        tVdb);
    if (!std::isfinite(want)) {
      ++misses;
      EXPECT_FALSE(std::isfinite(tNano));
      EXPECT_FALSE(vdbHit);
      continue;
    }
    ++hits;
    ASSERT_TRUE(std::isfinite(tNano));
    ASSERT_TRUE(vdbHit);
    // Hit points within a voxel of the analytic sphere, and of the analytic hit along the ray.
    EXPECT_NEAR(glm::length(eye + tNano * d - c), radius, voxel);
    EXPECT_NEAR(glm::length(eye + tVdb * d - c), radius, voxel);
    EXPECT_NEAR(tNano, want, 2.0 * voxel);  // a grazing-ish entry angle stretches a voxel along the ray
    EXPECT_NEAR(tVdb, want, 2.0 * voxel);
  }
  EXPECT_GT(hits, 100);
  EXPECT_GT(misses, 20);
}
#endif

TEST(VolumeRays, NanoVdbAndOpenVdbHitTheAnalyticSphere) {
#ifdef SVO_TEST_NANOVDB
  checkSphere(glm::dvec3(0.1, -0.2, 0.3));
#else
  GTEST_SKIP() << "built without the benchmark peers (SVO_BENCH_PEERS=OFF)";
#endif
}

TEST(VolumeRays, FarFromTheOrigin) {
#ifdef SVO_TEST_NANOVDB
  checkSphere(glm::dvec3(4096.0, -2048.0, 1024.5));
#else
  GTEST_SKIP() << "built without the benchmark peers (SVO_BENCH_PEERS=OFF)";
#endif
}

}  // namespace
