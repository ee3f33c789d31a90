// Level sets voxelized straight from the field (voxelizeVolumeSurface) against the analytic shapes they
// sample, by brute force over every finest voxel of the region: each voxel touches the analytic surface
// (its centre within half a diagonal of it), each finest voxel the surface clearly crosses is a leaf (no
// holes), leaf normals follow the analytic gradient, and stored contours, at every level, hold the surface. A
// sphere made by OpenVDB's createLevelSetSphere near the origin and far from it (its leaf count also against
// the volumeToMesh path), and hand-made plane level sets: axis-aligned on a plane of samples, grazing a grid
// axis, and diagonal through samples (zeros on the grid).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <set>
#include <tuple>

#include <openvdb/openvdb.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/volume.hpp"
#include "svo/store/format.hpp"

namespace fs = std::filesystem;

namespace {

// How far (grid voxels) the grid's trilinear zero set may stray from the analytic surface it samples: float
// values (far from the origin, createLevelSetSphere's float index arithmetic) and the interpolation's error
// on a sphere 32 voxels in radius, h^2 / 8R = 0.004 voxels.
constexpr double kSampledSurfaceVoxels = 0.05;
// Degrees a leaf's normal may differ from the analytic gradient at its centre: rounding onto the normal
// lattice (under 1 degree, format.hpp) plus, on the sphere, the angle a half diagonal subtends (1.6 degrees).
constexpr double kNormalDegrees = 3.0;
// Voxel widths a stored contour's slab may miss the analytic surface by (the sampled surface's error).
constexpr double kSlabVoxels = 0.1;

struct Voxel {
  glm::ivec3 coord;
  int level;
  svo::VoxelRecord record;
};

// The tree's voxels, every level; leaves are checked to sit at the finest level.
std::vector<Voxel> allVoxels(const svo::VoxelTree& tree, int levels) {
  std::vector<Voxel> out;
  std::vector<Voxel> stack{{glm::ivec3(0), 0, tree.voxels[0]}};
  while (!stack.empty()) {
    const Voxel v = stack.back();
    stack.pop_back();
    out.push_back(v);
    if (v.record.childMask == 0) EXPECT_EQ(v.level, levels);
    int rank = 0;
    for (int slot = 0; slot < 8; ++slot)
      if (v.record.childMask >> slot & 1)
        stack.push_back({svo::childCoord(v.coord, slot), v.level + 1,
                         tree.voxels[v.record.firstChild + std::uint32_t(rank++)]});
  }
  return out;
}

using Sdf = std::function<double(const glm::dvec3&)>;

struct Region {
  glm::dvec3 lo, hi;  // world; voxels not inside are not checked
};

// Checks the built surface against `sdf` (world, negative inside); returns the leaves checked.
std::size_t expectOnSurface(const svo::SurfaceVolume& volume, int levels, const Sdf& sdf, double gridVoxel,
                            const Region& region) {
  const svo::SceneTransform& t = volume.transform;
  const int side = 1 << levels;
  const double width = t.size / side;  // the finest voxels'
  const double slack = kSampledSurfaceVoxels * gridVoxel;
  const auto centreOf = [&](const glm::ivec3& c) { return t.origin + (glm::dvec3(c) + 0.5) * width; };
  const auto inRegion = [&](const glm::dvec3& p) {
    return glm::all(glm::greaterThanEqual(p, region.lo)) && glm::all(glm::lessThanEqual(p, region.hi));
  };
  std::set<std::tuple<int, int, int>> present;
  std::size_t checked = 0, contours = 0;
  for (const Voxel& v : allVoxels(volume.tree, levels)) {
    const double size = t.size / double(1 << v.level);
    const glm::dvec3 corner = t.origin + glm::dvec3(v.coord) * size, centre = corner + 0.5 * size;
    if (!inRegion(corner) || !inRegion(corner + size)) continue;
    SCOPED_TRACE(::testing::Message()
                 << "level " << v.level << " voxel " << v.coord.x << " " << v.coord.y << " " << v.coord.z);
    const double distance = sdf(centre);
    EXPECT_LE(std::abs(distance), 0.5 * std::sqrt(3.0) * size + slack);
    const double step = 1e-4 * size;
    const glm::dvec3 gradient = glm::normalize(
        glm::dvec3(sdf(centre + glm::dvec3(step, 0, 0)) - sdf(centre - glm::dvec3(step, 0, 0)),
                   sdf(centre + glm::dvec3(0, step, 0)) - sdf(centre - glm::dvec3(0, step, 0)),
                   sdf(centre + glm::dvec3(0, 0, step)) - sdf(centre - glm::dvec3(0, 0, step))));
    // The surface's point nearest the centre, where it lies in the voxel, is in the contour's slab.
    const glm::dvec3 u = -distance * gradient / size;  // voxel units from the centre
    if (v.record.hasContour && glm::all(glm::lessThanEqual(glm::abs(u), glm::dvec3(0.5)))) {
      ++contours;
      const svo::Contour c = svo::decodeContour(v.record.contour);
      EXPECT_LE(std::abs(glm::dot(glm::dvec3(c.normal), u) - c.position), 0.5 * c.thickness + kSlabVoxels);
    }
    if (v.level != levels) continue;
    ++checked;
    present.insert({v.coord.x, v.coord.y, v.coord.z});
    const glm::dvec3 normal(svo::decodeNormal(v.record.normal));
    EXPECT_GT(glm::dot(normal, gradient), std::cos(kNormalDegrees * M_PI / 180.0));
  }
  EXPECT_GT(contours, checked / 10);
  // No holes: every voxel whose corners lie clearly on both sides of the surface is a leaf.
  const glm::ivec3 first = glm::clamp(glm::ivec3(glm::floor((region.lo - t.origin) / width)), 0, side - 1);
  const glm::ivec3 last = glm::clamp(glm::ivec3(glm::floor((region.hi - t.origin) / width)), 0, side - 1);
  std::size_t crossed = 0;
  for (int z = first.z; z <= last.z; ++z)
    for (int y = first.y; y <= last.y; ++y)
      for (int x = first.x; x <= last.x; ++x) {
        const glm::ivec3 c(x, y, z);
        const glm::dvec3 corner = t.origin + glm::dvec3(c) * width;
        if (!inRegion(corner) || !inRegion(corner + width) || std::abs(sdf(centreOf(c))) > width)
          continue;  // outside, or far from the surface: not crossed
        bool in = false, out = false;
        for (int k = 0; k < 8; ++k) {
          const double d =
              sdf(t.origin + (glm::dvec3(c) + glm::dvec3(k & 1, k >> 1 & 1, k >> 2 & 1)) * width);
          in |= d<-slack, out |= d> slack;
        }
        if (!(in && out)) continue;
        ++crossed;
        EXPECT_TRUE(present.count({x, y, z})) << "hole at voxel " << x << " " << y << " " << z;
      }
  EXPECT_GT(crossed, checked / 2);
  return checked;
}

class VolumeSurface : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { openvdb::initialize(); }
  fs::path write(openvdb::FloatGrid::Ptr grid, const char* name) {
    const fs::path path = dir.path() / name;
    openvdb::io::File file(path.string());
    file.write({grid});
    file.close();
    return path;
  }
  svotest::TempDir dir;
};

void checkSphere(const fs::path& path, const glm::dvec3& centre, double radius, double gridVoxel) {
  svo::BuildOptions build;
  build.levels = 6;  // finest voxels about the grid's (1/32 on a cube of 2 and its margin)
  const svo::SurfaceVolume volume = svo::voxelizeVolumeSurface(path, {}, build);
  const Sdf sdf = [&](const glm::dvec3& p) { return glm::length(p - centre) - radius; };
  const std::size_t leaves =
      expectOnSurface(volume, build.levels, sdf, gridVoxel, {centre - 2.0 * radius, centre + 2.0 * radius});
  // About as many leaves as the mesh path's (it voxelizes volumeToMesh's polygons, which reach a little past
  // the trilinear surface where they cut corners).
  const svo::Mesh mesh = svo::loadVolumeSurface(path, {});
  svo::BuildStats stats;
  svo::voxelize(mesh, svo::fitSceneCube(mesh), build, &stats);
  EXPECT_NEAR(double(leaves), double(stats.leafVoxels), 0.1 * double(stats.leafVoxels));
}

TEST_F(VolumeSurface, SphereVoxelsLieOnTheAnalyticSphere) {
  const glm::dvec3 centre(0.1, -0.2, 0.3);
  const double radius = 1.0, voxel = 1.0 / 32.0;
  auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
      float(radius), openvdb::Vec3f(float(centre.x), float(centre.y), float(centre.z)), float(voxel));
  checkSphere(write(grid, "sphere.vdb"), glm::dvec3(glm::vec3(centre)), radius, voxel);
}

TEST_F(VolumeSurface, FarFromTheOrigin) {
  const glm::dvec3 centre(4096.5, -2048.25, 1024.0);
  const double radius = 1.0, voxel = 1.0 / 32.0;
  auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
      float(radius), openvdb::Vec3f(float(centre.x), float(centre.y), float(centre.z)), float(voxel));
  checkSphere(write(grid, "far.vdb"), centre, radius, voxel);
}

// A level set of the plane n.x = offset over the index box [-half, half]^3, every voxel active. Past the box
// the background (outside) meets the box's inside voxels: the region checked stays clear of its faces.
openvdb::FloatGrid::Ptr planeGrid(const glm::dvec3& n, double offset, double voxel, int half) {
  const float background = float(3.0 * voxel);
  auto grid = openvdb::FloatGrid::create(background);
  grid->setTransform(openvdb::math::Transform::createLinearTransform(voxel));
  grid->setGridClass(openvdb::GRID_LEVEL_SET);
  auto access = grid->getAccessor();
  for (int z = -half; z <= half; ++z)
    for (int y = -half; y <= half; ++y)
      for (int x = -half; x <= half; ++x) {
        const double d = glm::dot(n, glm::dvec3(x, y, z) * voxel) - offset;
        access.setValue(openvdb::Coord(x, y, z), float(std::clamp(d, -3.0 * voxel, 3.0 * voxel)));
      }
  return grid;
}

TEST_F(VolumeSurface, PlanesAxisAlignedGrazingAndThroughSamples) {
  const double voxel = 1.0 / 16.0;
  const int half = 20;
  struct Plane {
    const char* name;
    glm::dvec3 normal;
    double offset;
  };
  for (const Plane& p : {Plane{"axis-aligned on a plane of samples", {0, 0, 1}, 2 * voxel},
                         Plane{"grazing the x axis", glm::normalize(glm::dvec3(0, 1e-3, 1)), 0.3 * voxel},
                         Plane{"diagonal through samples", glm::normalize(glm::dvec3(1, 1, 1)), 0.0}}) {
    SCOPED_TRACE(p.name);
    const fs::path path = write(planeGrid(p.normal, p.offset, voxel, half), "plane.vdb");
    svo::BuildOptions build;
    build.levels = 6;
    const svo::SurfaceVolume volume = svo::voxelizeVolumeSurface(path, {}, build);
    const Sdf sdf = [&](const glm::dvec3& x) { return glm::dot(p.normal, x) - p.offset; };
    const double inner = (half - 4) * voxel;  // clear of the box's faces and the gradient's reach
    const std::size_t leaves =
        expectOnSurface(volume, build.levels, sdf, voxel, {glm::dvec3(-inner), glm::dvec3(inner)});
    EXPECT_GT(leaves, 100u);
  }
}

}  // namespace
