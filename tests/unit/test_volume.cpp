// OpenVDB in and out (builder/volume.hpp). Export: a store's level as a mask grid holds exactly the voxels a
// walk over the decoded octree's records finds at that level, with their colors and normals, read back with
// OpenVDB's own reader; import of that mask rebuilds a store with the same voxels, attributes and scene
// cube (mesh -> svo -> vdb -> svo). A level-set sphere and a fog-volume sphere made by OpenVDB build, from
// the field directly and through volumeToMesh, to voxels on the analytic sphere (radius R, and R less the fog
// threshold's depth) with outward normals and the color grid's color. A fog volume's leaves carry the densest
// point of their cube as their colors' alpha (against the field sampled over the cube), which export writes
// as a density grid and import reads back; a mask's density grid gives alphas, kept only where they differ.
// Bad files and ambiguous or unusable grids are one clear error naming the file; through the `svo` command
// (under AddressSanitizer when the suite has that build), a non-zero exit and nothing written.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>
#include <tuple>

#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/LevelSetSphere.h>
#include <openvdb/tools/LevelSetUtil.h>
#include <glm/geometric.hpp>

#include "command_helpers.hpp"
#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/volume.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_writer.hpp"

namespace fs = std::filesystem;

namespace {

using svotest::errorOf;
using Key = std::tuple<int, int, int>;
struct Values {
  std::uint32_t color = 0, normal = 0;
};

// The level's voxels of a decoded tree by walking its records from the root (a leaf above the level covers
// its whole cube there).
std::map<Key, Values> levelVoxels(const svo::VoxelTree& tree, int level) {
  std::map<Key, Values> out;
  struct Item {
    std::uint32_t index;
    glm::ivec3 coord;
    int depth;
  };
  std::vector<Item> stack{{0, glm::ivec3(0), 0}};
  while (!stack.empty()) {
    const Item item = stack.back();
    stack.pop_back();
    const svo::VoxelRecord& r = tree.voxels[item.index];
    if (item.depth == level || r.childMask == 0) {
      const int side = 1 << (level - item.depth);
      for (int z = 0; z < side; ++z)
        for (int y = 0; y < side; ++y)
          for (int x = 0; x < side; ++x) {
            const glm::ivec3 c = item.coord * side + glm::ivec3(x, y, z);
            out[{c.x, c.y, c.z}] = {r.color, r.normal};
          }
      continue;
    }
    int rank = 0;
    for (int slot = 0; slot < 8; ++slot)
      if (r.childMask >> slot & 1)
        stack.push_back(
            {r.firstChild + std::uint32_t(rank++), svo::childCoord(item.coord, slot), item.depth + 1});
  }
  return out;
}

template <class Grid>
typename Grid::Ptr readGrid(const fs::path& path, const std::string& name) {
  openvdb::io::File file(path.string());
  file.open();
  auto grid = openvdb::gridPtrCast<Grid>(file.readGrid(name));
  file.close();
  return grid;
}

void writeGrids(const fs::path& path, const openvdb::GridPtrVec& grids) {
  openvdb::io::File file(path.string());
  file.write(grids);
  file.close();
}

class Volume : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { openvdb::initialize(); }
  svotest::TempDir dir;
};

TEST_F(Volume, ExportedMaskHoldsTheLevelsVoxelsAndImportRebuildsThem) {
  const fs::path store = dir.path() / "scene.svo";
  svotest::writeSphereAndBoxStore(store);
  const svo::StoreReader reader(store);
  const svo::VoxelTree tree = reader.loadTree();
  const svo::SceneTransform& scene = reader.header().transform;
  for (const int level : {5, reader.header().parameters.levels}) {
    SCOPED_TRACE(level);
    const std::map<Key, Values> expected = levelVoxels(tree, level);
    const fs::path vdb = dir.path() / "scene.vdb";
    const svo::VolumeExportReport report = svo::exportVolume(reader, vdb, {level, false, nullptr});
    EXPECT_EQ(report.voxels, expected.size());

    // OpenVDB reads it back: one voxel per voxel of the level, in the scene's world frame.
    const auto occupancy = readGrid<openvdb::MaskGrid>(vdb, "occupancy");
    const auto colors = readGrid<openvdb::Vec3SGrid>(vdb, "color");
    const auto normals = readGrid<openvdb::Vec3SGrid>(vdb, "normal");
    ASSERT_TRUE(occupancy && colors && normals);
    {
      openvdb::io::File file(vdb.string());
      file.open();
      EXPECT_FALSE(file.hasGrid("density")) << "opaque colors carry no densities";
    }
    EXPECT_EQ(occupancy->activeVoxelCount(), openvdb::Index64(expected.size()));
    const double width = scene.size / double(1 << level);
    EXPECT_NEAR(occupancy->voxelSize()[0], width, 1e-12 * scene.size);
    const auto colorAt = colors->getConstAccessor();
    const auto normalAt = normals->getConstAccessor();
    const auto occupied = occupancy->getConstAccessor();
    for (const auto& [key, values] : expected) {
      const openvdb::Coord ijk(std::get<0>(key), std::get<1>(key), std::get<2>(key));
      ASSERT_TRUE(occupied.isValueOn(ijk));
      const openvdb::Vec3d centre = occupancy->indexToWorld(ijk);
      const glm::dvec3 want = scene.origin + (glm::dvec3(ijk.x(), ijk.y(), ijk.z()) + 0.5) * width;
      EXPECT_LT((centre - openvdb::Vec3d(want.x, want.y, want.z)).length(), 1e-9 * scene.size);
      const glm::vec4 c = svo::decodeColor(values.color);
      EXPECT_EQ(colorAt.getValue(ijk), openvdb::Vec3s(c.r, c.g, c.b));
      const glm::vec3 n = svo::decodeNormal(values.normal);
      EXPECT_EQ(normalAt.getValue(ijk), openvdb::Vec3s(n.x, n.y, n.z));
    }

    // svo build reads the mask back voxel for voxel: same voxels, same values, same scene cube.
    const svo::VoxelVolume volume = svo::loadVolumeVoxels(vdb, {});
    EXPECT_EQ(volume.parameters.levels, level);
    EXPECT_LT(glm::length(volume.transform.origin - scene.origin), 1e-9 * scene.size);
    EXPECT_NEAR(volume.transform.size, scene.size, 1e-9 * scene.size);
    const fs::path rebuilt = dir.path() / "rebuilt.svo";
    svo::StoreWriteOptions exact;  // as svo build writes a mask: no value rounded to its parent's
    exact.inheritance.inheritEqualOnly = true;
    svo::writeStore(rebuilt, volume.tree, volume.transform, volume.parameters, exact);
    const std::map<Key, Values> back = levelVoxels(svo::StoreReader(rebuilt).loadTree(), level);
    ASSERT_EQ(back.size(), expected.size());
    for (const auto& [key, values] : expected) {
      const auto found = back.find(key);
      ASSERT_NE(found, back.end());
      EXPECT_EQ(found->second.color, values.color);
      EXPECT_EQ(found->second.normal, values.normal);
    }
  }
}

// An OpenVDB level-set sphere far from the origin, with a vec3 color grid beside it.
struct SphereFile {
  glm::dvec3 centre{1000.25, -40.5, 7.0};
  double radius = 1.0, voxelSize = 0.04;
  glm::vec3 color{0.2f, 0.6f, 0.9f};
};
openvdb::FloatGrid::Ptr sphereGrid(const SphereFile& s) {
  auto grid = openvdb::tools::createLevelSetSphere<openvdb::FloatGrid>(
      float(s.radius), openvdb::Vec3f(float(s.centre.x), float(s.centre.y), float(s.centre.z)),
      float(s.voxelSize));
  grid->setName("sphere");
  return grid;
}
openvdb::Vec3SGrid::Ptr colorGrid(const openvdb::FloatGrid& shape, glm::vec3 color, const char* name) {
  auto grid = openvdb::Vec3SGrid::create(openvdb::Vec3s(color.x, color.y, color.z));
  grid->setTransform(shape.transform().copy());
  grid->topologyUnion(shape);
  grid->tree().setValueOn(openvdb::Coord(0), openvdb::Vec3s(color.x, color.y, color.z));
  grid->setName(name);
  return grid;
}

// Every leaf voxel of `tree` lies on the sphere with an outward normal (and the color grid's color); points
// spread over the sphere all have a leaf voxel near.
void expectSphereVoxels(const svo::VoxelTree& tree, const svo::SceneTransform& transform, int levels,
                        const SphereFile& s, double radius, bool colored) {
  const std::map<Key, Values> leaves = levelVoxels(tree, levels);
  const double width = transform.size / double(1 << levels);
  // The meshed (or trilinear) surface lies within a grid voxel of the sphere; a voxel it crosses, within a
  // half diagonal.
  const double tolerance = s.voxelSize + 0.5 * std::sqrt(3.0) * width;
  ASSERT_GT(leaves.size(), 1000u);
  for (const auto& [key, values] : leaves) {
    const glm::dvec3 centre =
        transform.origin + (glm::dvec3(std::get<0>(key), std::get<1>(key), std::get<2>(key)) + 0.5) * width;
    const glm::dvec3 radial = centre - s.centre;
    ASSERT_NEAR(glm::length(radial), radius, tolerance);
    // Outward: the meshing faces the polygons away from the inside; the field's gradient points outward.
    EXPECT_GT(glm::dot(glm::dvec3(svo::decodeNormal(values.normal)), glm::normalize(radial)), 0.9);
    if (colored) {
      const glm::vec4 c = svo::decodeColor(values.color);
      EXPECT_NEAR(c.r, s.color.r, 1.5 / 255) << "color";
      EXPECT_NEAR(c.b, s.color.b, 1.5 / 255) << "color";
    }
  }
  // Nothing missing: points spread over the sphere fall in or next to a leaf voxel.
  std::mt19937 random(7);
  std::normal_distribution<double> gauss;
  for (int i = 0; i < 200; ++i) {
    const glm::dvec3 onSphere =
        s.centre + radius * glm::normalize(glm::dvec3(gauss(random), gauss(random), gauss(random)));
    const glm::ivec3 cell(glm::floor((onSphere - transform.origin) / width));
    bool near = false;
    for (int dz = -1; dz <= 1 && !near; ++dz)
      for (int dy = -1; dy <= 1 && !near; ++dy)
        for (int dx = -1; dx <= 1 && !near; ++dx)
          near = leaves.count({cell.x + dx, cell.y + dy, cell.z + dz}) > 0;
    EXPECT_TRUE(near) << "no voxel near " << onSphere.x << ", " << onSphere.y << ", " << onSphere.z;
  }
}

// Builds the file's surface at 7 levels, from the field directly or through its mesh, and checks every leaf
// voxel against a sphere of `radius`.
void expectSphere(const fs::path& vdb, const svo::VolumeImportOptions& options, const SphereFile& s,
                  double radius, bool colored) {
  for (const bool direct : {true, false}) {
    SCOPED_TRACE(direct ? "directly" : "via volumeToMesh");
    svo::BuildOptions build;
    build.levels = 7;
    svo::SceneTransform transform;
    svo::VoxelTree tree;
    if (direct) {
      svo::SurfaceVolume volume = svo::voxelizeVolumeSurface(vdb, options, build);
      transform = volume.transform;
      tree = std::move(volume.tree);
    } else {
      const svo::Mesh mesh = svo::loadVolumeSurface(vdb, options);
      ASSERT_FALSE(mesh.triangles.empty());
      transform = svo::fitSceneCube(mesh);
      tree = svo::voxelize(mesh, transform, build);
    }
    expectSphereVoxels(tree, transform, build.levels, s, radius, colored);
  }
}

TEST_F(Volume, LevelSetSphereBuildsOnItsZeroCrossingWithOutwardNormalsAndGridColors) {
  const SphereFile s;
  const auto sphere = sphereGrid(s);
  const fs::path vdb = dir.path() / "sphere.vdb";
  writeGrids(vdb, {sphere, colorGrid(*sphere, s.color, "Cd")});
  expectSphere(vdb, {}, s, s.radius, true);
  const svo::VolumeGridInfo chosen = svo::chooseVolumeGrid(vdb, {});
  EXPECT_EQ(chosen.name, "sphere");
  EXPECT_EQ(chosen.kind, svo::VolumeGridKind::LevelSet);
}

TEST_F(Volume, FogVolumeBuildsOnItsDensityThreshold) {
  const SphereFile s;
  const auto fog = sphereGrid(s);
  // Density rises linearly from 0 at the zero crossing to 1 a narrow band (3 voxels) inside.
  openvdb::tools::sdfToFogVolume(*fog);
  ASSERT_EQ(fog->getGridClass(), openvdb::GRID_FOG_VOLUME);
  const fs::path vdb = dir.path() / "fog.vdb";
  writeGrids(vdb, {fog});
  const double bandWidth = 3.0 * s.voxelSize;
  svo::VolumeImportOptions options;
  options.densityThreshold = 0.5f;
  expectSphere(vdb, options, s, s.radius - 0.5 * bandWidth, false);
  EXPECT_EQ(svo::chooseVolumeGrid(vdb, {}).kind, svo::VolumeGridKind::FogVolume);
}

// The highest value the grid's trilinear field (OpenVDB's BoxSampler) takes on a lattice of points spanning
// the world box [lo, lo + width]^3: an independent estimate of the maximum the builder finds exactly.
double sampledMaximum(const openvdb::FloatGrid& grid, const glm::dvec3& lo, double width) {
  constexpr int kSteps = 16;
  const auto accessor = grid.getConstAccessor();
  double best = -1e300;
  for (int z = 0; z <= kSteps; ++z)
    for (int y = 0; y <= kSteps; ++y)
      for (int x = 0; x <= kSteps; ++x) {
        const glm::dvec3 p = lo + glm::dvec3(x, y, z) * (width / kSteps);
        const openvdb::Vec3d index = grid.worldToIndex(openvdb::Vec3d(p.x, p.y, p.z));
        best = std::max(best, double(openvdb::tools::BoxSampler::sample(accessor, index)));
      }
  return best;
}

std::uint8_t alphaOf(std::uint32_t abgr) {
  return std::uint8_t(abgr >> 24);
}

TEST_F(Volume, FogDensityRidesInTheColorsAlphaAndSurvivesExport) {
  // A fog sphere whose density grows along x: its surface voxels' densest points differ.
  const SphereFile s;
  const auto fog = sphereGrid(s);
  openvdb::tools::sdfToFogVolume(*fog);
  constexpr double kLowFactor = 0.55;
  for (auto it = fog->beginValueOn(); it; ++it) {
    const double x = fog->indexToWorld(it.getCoord()).x();
    const double t = std::clamp((x - (s.centre.x - s.radius)) / (2.0 * s.radius), 0.0, 1.0);
    it.setValue(float(*it * (kLowFactor + (1.0 - kLowFactor) * t)));
  }
  const fs::path vdb = dir.path() / "fog.vdb";
  writeGrids(vdb, {fog});
  svo::VolumeImportOptions options;
  options.densityThreshold = 0.3f;
  svo::BuildOptions build;
  build.levels = 7;
  const svo::SurfaceVolume volume = svo::voxelizeVolumeSurface(vdb, options, build);
  ASSERT_TRUE(volume.tree.hasColors);

  // Each leaf's alpha is its cube's densest point, against the field sampled on a lattice over the cube.
  // The lattice misses the maximum by at most the field's steepest slope (the band's 1 per 3 grid voxels
  // along each axis) over half a lattice cell's diagonal.
  const std::map<Key, Values> leaves = levelVoxels(volume.tree, build.levels);
  const double width = volume.transform.size / double(1 << build.levels);
  const double latticeMiss = std::sqrt(3.0) / (3.0 * s.voxelSize) * 0.5 * std::sqrt(3.0) * width / 16.0;
  const double quantum = 0.5 / 255.0 + 1e-6;
  std::set<int> alphas;
  constexpr std::size_t kEveryNthLeaf = 37;  // keeps the lattice sampling to a second
  std::size_t seen = 0, checked = 0;
  for (const auto& [key, values] : leaves) {
    if (seen++ % kEveryNthLeaf != 0) continue;
    const glm::dvec3 lo =
        volume.transform.origin + glm::dvec3(std::get<0>(key), std::get<1>(key), std::get<2>(key)) * width;
    const double sampled = std::clamp(sampledMaximum(*fog, lo, width), 0.0, 1.0);
    const double alpha = alphaOf(values.color) / 255.0;
    EXPECT_GE(alpha, sampled - quantum);
    EXPECT_LE(alpha, std::min(1.0, sampled + latticeMiss) + quantum);
    // No color grid: neutral grey, so the density changes no image.
    EXPECT_EQ(values.color & 0xFFFFFFu, svo::encodeColor(glm::vec4(svo::kNeutralGreyAlbedo)) & 0xFFFFFFu);
    alphas.insert(alphaOf(values.color));
    ++checked;
  }
  EXPECT_GT(checked, 100u);
  EXPECT_GT(alphas.size(), 20u) << "the densities should differ along x";

  // Export writes the alphas as a density grid marked as an attribute: the file still has one shape, and
  // building it back gives the same alphas.
  const fs::path store = dir.path() / "fog.svo";
  svo::BuildParameters parameters;
  parameters.levels = build.levels;
  svo::writeStore(store, volume.tree, volume.transform, parameters);
  const svo::StoreReader reader(store);
  const std::map<Key, Values> stored = levelVoxels(reader.loadTree(), build.levels);
  const fs::path exported = dir.path() / "fog-export.vdb";
  svo::exportVolume(reader, exported, {build.levels, false, nullptr});
  const auto densities = readGrid<openvdb::FloatGrid>(exported, "density");
  ASSERT_TRUE(densities);
  EXPECT_EQ(densities->activeVoxelCount(), openvdb::Index64(stored.size()));
  const auto densityAt = densities->getConstAccessor();
  for (const auto& [key, values] : stored)
    ASSERT_EQ(densityAt.getValue(openvdb::Coord(std::get<0>(key), std::get<1>(key), std::get<2>(key))),
              float(alphaOf(values.color)) / 255.0f);
  EXPECT_EQ(svo::chooseVolumeGrid(exported, {}).name, "occupancy");
  const svo::VoxelVolume back = svo::loadVolumeVoxels(exported, {});
  ASSERT_TRUE(back.tree.hasColors);
  const std::map<Key, Values> rebuilt = levelVoxels(back.tree, build.levels);
  ASSERT_EQ(rebuilt.size(), stored.size());
  for (const auto& [key, values] : stored) ASSERT_EQ(rebuilt.at(key).color, values.color);
}

TEST_F(Volume, MaskDensitiesAreKeptOnlyWhereTheyDiffer) {
  auto mask = openvdb::MaskGrid::create();
  mask->setName("occupancy");
  auto density = openvdb::FloatGrid::create(0.0f);
  density->setName("density");
  std::map<Key, float> expected;
  for (int z = 0; z < 4; ++z)
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 4; ++x) {
        mask->tree().setValueOn(openvdb::Coord(x, y, z));
        const float d = float(x + 2 * y + 4 * z) / 28.0f;
        density->tree().setValueOn(openvdb::Coord(x, y, z), d);
        expected[{x, y, z}] = d;
      }
  const fs::path varying = dir.path() / "varying.vdb";
  writeGrids(varying, {mask, density});
  svo::VolumeImportOptions pick;
  pick.grid = "occupancy";  // the density grid is a fog volume too
  const svo::VoxelVolume volume = svo::loadVolumeVoxels(varying, pick);
  ASSERT_TRUE(volume.tree.hasColors);
  const std::map<Key, Values> leaves = levelVoxels(volume.tree, volume.parameters.levels);
  ASSERT_EQ(leaves.size(), expected.size());
  for (const auto& [key, d] : expected)
    EXPECT_EQ(leaves.at(key).color, svo::encodeColor(glm::vec4(glm::vec3(svo::kNeutralGreyAlbedo), d)));

  // The same density everywhere is no attribute: no colors at all, or opaque ones beside a color grid.
  density->tree().fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(3)), 0.5f, true);
  const fs::path uniform = dir.path() / "uniform.vdb";
  writeGrids(uniform, {mask, density});
  EXPECT_FALSE(svo::loadVolumeVoxels(uniform, pick).tree.hasColors);
  auto colors = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.25f, 0.5f, 1.0f));
  colors->setName("color");
  writeGrids(uniform, {mask, density, colors});
  const svo::VoxelVolume colored = svo::loadVolumeVoxels(uniform, pick);
  ASSERT_TRUE(colored.tree.hasColors);
  for (const auto& [key, values] : levelVoxels(colored.tree, colored.parameters.levels))
    EXPECT_EQ(values.color, svo::encodeColor(glm::vec4(0.25f, 0.5f, 1.0f, 1.0f)));
}

TEST_F(Volume, BadFilesAndGridsAreOneClearError) {
  const fs::path text = dir.file("mesh.vdb", "solid nothing\n");
  EXPECT_NE(errorOf([&] { svo::listVolumeGrids(text); }).find("mesh.vdb: not a readable OpenVDB file"),
            std::string::npos);
  EXPECT_NE(errorOf([&] { svo::listVolumeGrids(dir.path() / "missing.vdb"); }).find("no such file"),
            std::string::npos);

  const fs::path empty = dir.path() / "empty.vdb";
  writeGrids(empty, {});
  EXPECT_NE(errorOf([&] { svo::loadVolumeSurface(empty, {}); }).find("no level set, fog volume or mask grid"),
            std::string::npos);

  // An integer grid is listed but not built from.
  auto ints = openvdb::Int32Grid::create(0);
  ints->setName("labels");
  ints->tree().setValueOn(openvdb::Coord(1, 2, 3), 7);
  const SphereFile s;
  auto a = sphereGrid(s), b = sphereGrid(s);
  b->setName("other");
  const fs::path several = dir.path() / "several.vdb";
  writeGrids(several, {ints, a, b});
  const std::string ambiguous = errorOf([&] { svo::loadVolumeSurface(several, {}); });
  EXPECT_NE(ambiguous.find("several grids to build from (--grid NAME picks one)"), std::string::npos)
      << ambiguous;
  EXPECT_NE(ambiguous.find("'sphere'"), std::string::npos) << ambiguous;
  EXPECT_NE(ambiguous.find("'other'"), std::string::npos) << ambiguous;
  svo::VolumeImportOptions pick;
  pick.grid = "labels";
  EXPECT_NE(errorOf([&] { svo::loadVolumeSurface(several, pick); }).find("grid 'labels' is a int32 grid"),
            std::string::npos);
  pick.grid = "nope";
  EXPECT_NE(errorOf([&] { svo::loadVolumeSurface(several, pick); }).find("no grid named 'nope'"),
            std::string::npos);
  pick.grid = "other";
  pick.colorGrid = "paint";
  EXPECT_NE(errorOf([&] { svo::loadVolumeSurface(several, pick); }).find("no color grid named 'paint'"),
            std::string::npos);

  // A mask on a rotated transform is not cubic voxels of the scene's axes.
  auto mask = openvdb::MaskGrid::create();
  mask->tree().setValueOn(openvdb::Coord(0));
  auto rotated = openvdb::math::Transform::createLinearTransform(0.5);
  rotated->postRotate(0.3, openvdb::math::Z_AXIS);
  mask->setTransform(rotated);
  mask->setName("mask");
  const fs::path turned = dir.path() / "turned.vdb";
  writeGrids(turned, {mask});
  EXPECT_NE(errorOf([&] { svo::loadVolumeVoxels(turned, {}); }).find("rotated, sheared or non-uniform"),
            std::string::npos);

  // A mask whose active tiles stand for more voxels than a store is written from.
  auto huge = openvdb::MaskGrid::create();
  huge->setName("huge");
  huge->tree().fill(openvdb::CoordBBox(openvdb::Coord(0), openvdb::Coord(2047)), true, true);
  const fs::path tiles = dir.path() / "tiles.vdb";
  writeGrids(tiles, {huge});
  EXPECT_NE(
      errorOf([&] { svo::loadVolumeVoxels(tiles, {}); }).find("more than the 1073741824 a mask may bring"),
      std::string::npos);

  // A level set with no zero crossing inside its band (all outside) has no surface.
  auto far = openvdb::FloatGrid::create(0.3f);
  far->setGridClass(openvdb::GRID_LEVEL_SET);
  far->tree().setValueOn(openvdb::Coord(0), 0.1f);
  const fs::path flat = dir.path() / "flat.vdb";
  writeGrids(flat, {far});
  EXPECT_NE(errorOf([&] { svo::loadVolumeSurface(flat, {}); }).find("has no surface"), std::string::npos);

  // Export: a level outside the store's.
  const fs::path store = dir.path() / "scene.svo";
  svotest::writeSphereAndBoxStore(store);
  const fs::path out = dir.path() / "out.vdb";
  EXPECT_NE(errorOf([&] {
              svo::exportVolume(svo::StoreReader(store), out, {9, false, nullptr});
            }).find("level 9 is outside the store's levels 1..8"),
            std::string::npos);
  EXPECT_FALSE(fs::exists(out));
}

// `svo ARGS` with stderr apart: its exit status and what it printed there.
struct CommandRun {
  int exitCode = 0;
  std::string err;
};
CommandRun svoCommand(const fs::path& dir, const std::string& args) {
  const char* asan = std::getenv("SVO_ASAN_BINARY");
  const std::string program = asan && *asan ? asan : SVO_BINARY;
  const fs::path err = dir / "stderr.txt";
  const std::string out =
      svotest::runShell("(" + program + " " + args + " 2>" + err.string() + " >/dev/null)");
  CommandRun run;
  run.exitCode = std::atoi(out.substr(out.rfind("exit ") + 5).c_str());
  std::ifstream in(err);
  std::stringstream text;
  text << in.rdbuf();
  run.err = text.str();
  return run;
}

void expectCleanFailure(const CommandRun& run, const std::string& needle, const fs::path& target) {
  EXPECT_NE(run.exitCode, 0) << run.err;
  EXPECT_LT(run.exitCode, 128) << "crashed: " << run.err;
  EXPECT_NE(run.err.find(needle), std::string::npos) << run.err;
  EXPECT_EQ(std::count(run.err.begin(), run.err.end(), '\n'), 1) << run.err;
  EXPECT_FALSE(fs::exists(target)) << target;
}

TEST_F(Volume, CommandsExportBuildAndRefuseBadVolumes) {
  const fs::path store = dir.path() / "scene.svo", vdb = dir.path() / "scene.vdb",
                 back = dir.path() / "back.svo";
  svotest::writeSphereAndBoxStore(store);
  const std::string s = store.string(), v = vdb.string(), b = back.string();
  CommandRun run = svoCommand(dir.path(), "export " + s + " -o " + v + " --level 6");
  ASSERT_EQ(run.exitCode, 0) << run.err;
  // OpenVDB's own tool lists what svo wrote.
  const std::string listed = svotest::runShell("vdb_print " + v);
  EXPECT_NE(listed.find("exit 0"), std::string::npos) << listed;
  for (const char* grid : {"occupancy", "color", "normal"})
    EXPECT_NE(listed.find(grid), std::string::npos) << listed;
  run = svoCommand(dir.path(), "build " + v + " -o " + b);
  ASSERT_EQ(run.exitCode, 0) << run.err;
  EXPECT_EQ(svoCommand(dir.path(), "verify " + b).exitCode, 0);
  const std::map<Key, Values> original = levelVoxels(svo::StoreReader(store).loadTree(), 6);
  const std::map<Key, Values> rebuilt = levelVoxels(svo::StoreReader(back).loadTree(), 6);
  EXPECT_EQ(original.size(), rebuilt.size());
  EXPECT_TRUE(std::equal(original.begin(), original.end(), rebuilt.begin(), rebuilt.end(),
                         [](const auto& a, const auto& b) { return a.first == b.first; }));

  const fs::path out = dir.path() / "out.svo";
  expectCleanFailure(svoCommand(dir.path(), "build " + v + " -o " + out.string() + " --levels 9"),
                     "the voxel mask's voxels make 6 levels, not --levels 9", out);
  std::ifstream whole(vdb, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(whole)), std::istreambuf_iterator<char>());
  for (const std::size_t keep : {std::size_t(0), std::size_t(40), bytes.size() / 2}) {
    SCOPED_TRACE(keep);
    const fs::path truncated = dir.file("truncated.vdb", bytes.substr(0, keep));
    expectCleanFailure(svoCommand(dir.path(), "build " + truncated.string() + " -o " + out.string()),
                       "truncated.vdb", out);
  }
  const fs::path text = dir.file("text.vdb", "ply\nformat ascii 1.0\n");
  expectCleanFailure(svoCommand(dir.path(), "build " + text.string() + " -o " + out.string()),
                     "text.vdb: not a readable OpenVDB file", out);
  expectCleanFailure(svoCommand(dir.path(), "build " + v + " -o " + out.string() + " --grid color"),
                     "grid 'color' is a vec3s grid", out);

  const fs::path png = dir.path() / "scene.png";
  expectCleanFailure(svoCommand(dir.path(), "export " + s + " -o " + png.string()), "must name a .vdb file",
                     png);
  const fs::path deep = dir.path() / "deep.vdb";
  expectCleanFailure(svoCommand(dir.path(), "export " + s + " -o " + deep.string() + " --level 12"),
                     "deeper than the store's 8 levels", deep);
}

// `svo bench volume` (the optimized build: the sanitized one has no peers) casts the same rays through the
// octrees built from the level set (directly and via volumeToMesh), OpenVDB's level set and NanoVDB's: each
// hits the pixels OpenVDB's intersector hits and agrees with it on depth within a voxel.
TEST_F(Volume, BenchCastsTheSameLevelSetAsOpenVdb) {
  const fs::path sphere = dir.path() / "sphere.ply";
  ASSERT_EQ(std::system((std::string(SVO_BINARY) + " gen sphere --triangles 2000 -o " + sphere.string() +
                         " >/dev/null 2>&1")
                            .c_str()),
            0);
  const std::string out = svotest::runShell(std::string(SVO_BINARY) + " bench volume " + sphere.string() +
                                            " --levels 6 --size 48 --runs 1 --threads 1");
  ASSERT_NE(out.find("exit 0"), std::string::npos) << out;
  for (const char* row :
       {"OpenVDB meshToLevelSet", "svo from the level set", "OpenVDB grid in memory", "svo octree in memory"})
    EXPECT_NE(out.find(row), std::string::npos) << row << "\n" << out;
  for (const char* row : {"svo from the level set, directly", "--volume-via-mesh", "NanoVDB buffer"})
    EXPECT_NE(out.find(row), std::string::npos) << row << "\n" << out;
  // A caster's row of the ray table, after its name: Mrays/s, speed-up, hit share, then against OpenVDB
  // the one-sided hits (percent of pixels) and the depth difference's median and p99 (voxels).
  const auto agreement = [&](const std::string& caster, double oneOnlyMax, double tailMax) {
    const std::size_t at = out.find(caster, out.find("hit by one only"));
    ASSERT_NE(at, std::string::npos) << caster << "\n" << out;
    std::istringstream row(out.substr(at + caster.size(), out.find('\n', at) - at - caster.size()));
    std::string rate, speedUp, hits, oneOnly, median, medianUnit, tail;
    row >> rate >> speedUp >> hits >> oneOnly >> median >> medianUnit >> tail;
    SCOPED_TRACE(caster + "\n" + out);
    EXPECT_GT(std::stod(hits), 10.0);
    EXPECT_LT(std::stod(oneOnly), oneOnlyMax);
    EXPECT_LT(std::stod(median), 0.5);
    EXPECT_LT(std::stod(tail), tailMax);
  };
  agreement("octree built directly", 1.0, 1.0);
  agreement("octree built via volumeToMesh", 1.0, 1.0);
  // NanoVDB's hits are the faces of the voxels where the sign changes: within a voxel of the surface
  // (test_volume_rays.cpp), further along grazing rays, and a silhouette voxel wider.
  agreement("NanoVDB HDDA ZeroCrossing (CPU)", 2.0, 4.0);
}

}  // namespace
