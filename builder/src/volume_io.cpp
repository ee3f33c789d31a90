// OpenVDB in (volume.hpp): the file's grids read once and listed, the shape grid chosen, then
// either meshed (level sets, fog volumes) for the mesh builder or taken voxel for voxel (masks).
#include <algorithm>
#include <bit>
#include <cmath>
#include <fstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <openvdb/io/Stream.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <openvdb/tools/VolumeToMesh.h>
#include <glm/geometric.hpp>

#include "file_extension.hpp"
#include "svo/builder/volume.hpp"
#include "svo/store/format.hpp"
#include "volume_file.hpp"

namespace svo {

namespace fs = std::filesystem;

namespace {

// Attribute grids looked for by name when none is named (ours, then Houdini's).
constexpr const char* kColorGridNames[] = {"color", "Cd"};
constexpr const char* kNormalGridNames[] = {"normal", "N"};
// Most voxels a mask may bring: each becomes a voxel record (24 B) while the store is written, 24 GiB here.
constexpr std::uint64_t kMaxMaskVoxels = std::uint64_t(1) << 30;

VolumeGridKind kindOf(const openvdb::GridBase& grid) {
  if (grid.getMetadata<openvdb::StringMetadata>(volume_file::kAttributeMetadata))
    return VolumeGridKind::Attribute;
  if (grid.isType<openvdb::FloatGrid>() || grid.isType<openvdb::DoubleGrid>())
    return grid.getGridClass() == openvdb::GRID_LEVEL_SET ? VolumeGridKind::LevelSet
                                                          : VolumeGridKind::FogVolume;
  if (grid.isType<openvdb::MaskGrid>() || grid.isType<openvdb::BoolGrid>()) return VolumeGridKind::Voxels;
  if (grid.isType<openvdb::Vec3SGrid>() || grid.isType<openvdb::Vec3DGrid>())
    return VolumeGridKind::Attribute;
  return VolumeGridKind::Other;
}

std::string describe(const std::vector<VolumeGridInfo>& grids) {
  std::string out;
  for (const VolumeGridInfo& g : grids)
    out += (out.empty() ? "" : "; ") +
           fmt::format("'{}' ({} {}, {} active voxels)", g.name, g.type, nameOf(g.kind), g.activeVoxels);
  return out.empty() ? "no grids" : out;
}

bool isShape(VolumeGridKind kind) {
  return kind == VolumeGridKind::LevelSet || kind == VolumeGridKind::FogVolume ||
         kind == VolumeGridKind::Voxels;
}

template <class Grid>
void meshSurface(const Grid& grid, double isovalue, Mesh& mesh) {
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
  std::vector<openvdb::Vec4I> quads;
  // Adaptivity 0: a polygon per crossed voxel edge, the grid's full resolution.
  openvdb::tools::volumeToMesh(grid, points, triangles, quads, isovalue, 0.0, true);
  mesh.positions.reserve(points.size());
  for (const openvdb::Vec3s& p : points) mesh.positions.emplace_back(p.x(), p.y(), p.z());
  mesh.triangles.reserve(triangles.size() + 2 * quads.size());
  // volumeToMesh winds its polygons clockwise seen from outside (fog volumes too: it turns grids that are
  // not level sets over); the builder's normals follow counter-clockwise winding.
  const auto add = [&](unsigned a, unsigned b, unsigned c) { mesh.triangles.emplace_back(a, c, b); };
  for (const openvdb::Vec3I& t : triangles) add(t[0], t[1], t[2]);
  for (const openvdb::Vec4I& q : quads) add(q[0], q[1], q[2]), add(q[0], q[2], q[3]);
}

}  // namespace

const char* nameOf(VolumeGridKind kind) {
  switch (kind) {
    case VolumeGridKind::LevelSet:
      return "level set";
    case VolumeGridKind::FogVolume:
      return "fog volume";
    case VolumeGridKind::Voxels:
      return "voxel mask";
    case VolumeGridKind::Attribute:
      return "attribute";
    case VolumeGridKind::Other:
      return "unsupported";
  }
  return "?";
}

bool isVolumeFile(const fs::path& path) {
  return detail::lowerExtension(path) == ".vdb";
}

namespace volume_file {

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

double cubicVoxelSize(const fs::path& path, const openvdb::GridBase& grid) {
  const openvdb::math::Transform& transform = grid.transform();
  const openvdb::Vec3d step =
      transform.indexToWorld(openvdb::Vec3d(1, 1, 1)) - transform.indexToWorld(openvdb::Vec3d(0));
  const double voxelSize = transform.voxelSize()[0];
  if (!transform.isLinear() || !transform.hasUniformScale() || !(voxelSize > 0.0) ||
      (step - openvdb::Vec3d(voxelSize)).length() > 1e-9 * voxelSize)
    fail(path, "grid '" + grid.getName() +
                   "' has a rotated, sheared or non-uniform transform; svo takes axis-aligned cubic voxels");
  return voxelSize;
}

void initialize() {
  static const bool initialized = (openvdb::initialize(), true);
  (void)initialized;
}

Reader::Reader(const fs::path& path) : path_(path) {
  initialize();
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "no such file");
  if (!fs::is_regular_file(path, ec)) fail(path, "not a regular file");
  try {
    // Through io::Stream on a stream that throws at the first short read: io::File takes the bytes a
    // truncated file lacks for values (a grid name's length among them) and can spin for minutes on one.
    std::ifstream in(path, std::ios::binary);
    in.exceptions(std::ios::failbit | std::ios::badbit);
    openvdb::io::Stream stream(in, false);
    for (const openvdb::GridBase::Ptr& grid : *stream.getGrids()) {
      VolumeGridInfo info;
      info.name = grid->getName();
      info.type = grid->valueType();
      info.kind = kindOf(*grid);
      info.activeVoxels = std::uint64_t(grid->activeVoxelCount());
      info.voxelSize = grid->voxelSize()[0];
      grids_.push_back(std::move(info));
      content_.push_back(grid);
    }
  } catch (const std::exception& e) {
    fail(path, std::string("not a readable OpenVDB file (") + e.what() + ")");
  }
}

Reader::~Reader() = default;

openvdb::GridBase::Ptr Reader::read(const std::string& name) const {
  for (const openvdb::GridBase::Ptr& grid : content_)
    if (grid->getName() == name) return grid;
  fail(path_, "has no grid named '" + name + "'");
}

VolumeGridInfo choose(const fs::path& path, const std::vector<VolumeGridInfo>& grids,
                      const VolumeImportOptions& options) {
  if (!options.grid.empty()) {
    const auto named = std::find_if(grids.begin(), grids.end(),
                                    [&](const VolumeGridInfo& g) { return g.name == options.grid; });
    if (named == grids.end())
      fail(path, "no grid named '" + options.grid + "'; the file has " + describe(grids));
    if (!isShape(named->kind))
      fail(path, "grid '" + options.grid + "' is a " + named->type +
                     " grid; svo builds from level sets and fog volumes (float or double) and masks (mask or "
                     "bool)");
    return *named;
  }
  std::vector<VolumeGridInfo> shapes;
  std::copy_if(grids.begin(), grids.end(), std::back_inserter(shapes),
               [](const VolumeGridInfo& g) { return isShape(g.kind); });
  if (shapes.empty())
    fail(path, "no level set, fog volume or mask grid to build from; the file has " + describe(grids));
  if (shapes.size() > 1)
    fail(path, "several grids to build from (--grid NAME picks one): " + describe(shapes));
  return shapes.front();
}

namespace {

bool isVec3(const VolumeGridInfo& grid) {
  return grid.type == openvdb::typeNameAsString<openvdb::Vec3s>() ||
         grid.type == openvdb::typeNameAsString<openvdb::Vec3d>();
}

openvdb::GridBase::Ptr attributeGrid(const Reader& file, const std::vector<VolumeGridInfo>& grids,
                                     const std::string& name, std::span<const char* const> defaults,
                                     const char* what) {
  auto found = grids.end();
  if (!name.empty()) {
    found = std::find_if(grids.begin(), grids.end(), [&](const VolumeGridInfo& g) { return g.name == name; });
    if (found == grids.end())
      fail(file.path(), fmt::format("no {} grid named '{}'; the file has {}", what, name, describe(grids)));
  } else {
    for (const char* candidate : defaults) {
      found = std::find_if(grids.begin(), grids.end(),
                           [&](const VolumeGridInfo& g) { return g.name == candidate && isVec3(g); });
      if (found != grids.end()) break;
    }
    if (found == grids.end()) return nullptr;
  }
  if (!isVec3(*found))
    fail(file.path(),
         fmt::format("the {} grid '{}' is a {} grid, not a vec3 one", what, found->name, found->type));
  return file.read(found->name);
}

}  // namespace

openvdb::GridBase::Ptr colorGrid(const Reader& file, const VolumeImportOptions& options) {
  return attributeGrid(file, file.grids(), options.colorGrid, kColorGridNames, "color");
}

openvdb::GridBase::Ptr normalGrid(const Reader& file, const VolumeImportOptions& options) {
  return attributeGrid(file, file.grids(), options.normalGrid, kNormalGridNames, "normal");
}

openvdb::FloatGrid::Ptr densityGrid(const Reader& file) {
  const auto found = std::find_if(file.grids().begin(), file.grids().end(),
                                  [](const VolumeGridInfo& g) { return g.name == kDensityGridName; });
  if (found == file.grids().end()) return nullptr;
  const openvdb::GridBase::Ptr grid = file.read(found->name);
  if (const auto floats = openvdb::gridPtrCast<openvdb::FloatGrid>(grid)) return floats;
  const auto doubles = openvdb::gridPtrCast<openvdb::DoubleGrid>(grid);
  if (!doubles)
    fail(file.path(), fmt::format("the density grid '{}' is a {} grid, not a float or double one",
                                  found->name, found->type));
  auto floats = openvdb::FloatGrid::create(float(doubles->background()));
  floats->setTransform(doubles->transform().copy());
  for (auto it = doubles->cbeginValueOn(); it; ++it) floats->tree().setValueOn(it.getCoord(), float(*it));
  return floats;
}

float ScalarSampler::at(const glm::dvec3& world) const {
  return openvdb::tools::BoxSampler::sample(
      grid_->tree(), grid_->transform().worldToIndex(openvdb::Vec3d(world.x, world.y, world.z)));
}

Vec3Sampler::Vec3Sampler(openvdb::GridBase::Ptr grid) {
  if (!grid) return;
  if (grid->isType<openvdb::Vec3DGrid>()) {
    const auto& doubles = *openvdb::gridPtrCast<openvdb::Vec3DGrid>(grid);
    auto floats = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
    floats->setTransform(doubles.transform().copy());
    for (auto it = doubles.cbeginValueOn(); it; ++it)
      floats->tree().setValueOn(it.getCoord(), openvdb::Vec3s(*it));
    grid_ = floats;
  } else {
    grid_ = openvdb::gridPtrCast<openvdb::Vec3SGrid>(grid);
  }
}

glm::vec3 Vec3Sampler::at(const glm::dvec3& world) const {
  const openvdb::Vec3s v = openvdb::tools::BoxSampler::sample(
      grid_->tree(), grid_->transform().worldToIndex(openvdb::Vec3d(world.x, world.y, world.z)));
  return {v.x(), v.y(), v.z()};
}

glm::vec4 colorOf(glm::vec3 rgb) {
  if (!std::isfinite(rgb.r + rgb.g + rgb.b)) rgb = glm::vec3(0.0f);
  return {glm::clamp(rgb, glm::vec3(0.0f), glm::vec3(1.0f)), 1.0f};
}

std::uint32_t colorWithDensity(const Vec3Sampler& colors, const glm::dvec3& world, double density) {
  const glm::vec3 rgb = colors ? glm::vec3(colorOf(colors.at(world))) : glm::vec3(kNeutralGreyAlbedo);
  return encodeColor(glm::vec4(rgb, std::isfinite(density) ? std::clamp(float(density), 0.0f, 1.0f) : 0.0f));
}

bool keepDensityWhereItVaries(std::vector<SliceVoxel>& leaves, bool hasColorGrid) {
  constexpr std::uint32_t kAlpha = 0xFF000000u;
  const bool varies = std::any_of(leaves.begin(), leaves.end(), [&](const SliceVoxel& v) {
    return (v.color & kAlpha) != (leaves.front().color & kAlpha);
  });
  if (varies) return true;
  for (SliceVoxel& v : leaves) v.color |= kAlpha;
  return hasColorGrid;
}

void addCoarserLevels(VoxelLevels& levels, bool hasColors, bool hasNormals) {
  for (int level = int(levels.size()) - 2; level >= 0; --level) {
    std::vector<SliceVoxel>& parents = levels[level];
    std::vector<SliceVoxel>& children = levels[level + 1];
    glm::vec4 colorSum(0.0f);
    glm::vec3 normalSum(0.0f);
    int count = 0;
    const auto close = [&] {
      if (hasColors) parents.back().color = encodeColor(colorSum / float(count));
      if (hasNormals && glm::dot(normalSum, normalSum) > 0.0f)
        parents.back().normal = latticeNormal(normalSum);
      else if (hasNormals)
        parents.back().normal = children.front().normal;
    };
    for (const SliceVoxel& child : children) {
      const glm::ivec3 coord = child.coord >> 1;
      if (parents.empty() || parents.back().coord != coord) {
        if (!parents.empty()) close();
        parents.push_back(SliceVoxel{coord});
        colorSum = glm::vec4(0.0f), normalSum = glm::vec3(0.0f), count = 0;
      }
      parents.back().childMask |= std::uint8_t(1u << childSlot(child.coord));
      if (hasColors) colorSum += decodeColor(child.color);
      if (hasNormals) normalSum += decodeNormal(child.normal);
      ++count;
    }
    close();
  }
}

SurfaceGrid readSurfaceGrid(const Reader& file, const VolumeImportOptions& options) {
  const VolumeGridInfo chosen = choose(file.path(), file.grids(), options);
  if (chosen.kind == VolumeGridKind::Voxels)
    fail(file.path(), "grid '" + chosen.name + "' is a voxel mask, built voxel for voxel, not as a surface");
  if (chosen.kind == VolumeGridKind::FogVolume && !std::isfinite(options.densityThreshold))
    fail(file.path(), "the density threshold is not a finite number");
  SurfaceGrid out;
  out.kind = chosen.kind;
  out.grid = file.read(chosen.name);
  out.isovalue = chosen.kind == VolumeGridKind::LevelSet ? 0.0 : double(options.densityThreshold);
  return out;
}

}  // namespace volume_file

std::vector<VolumeGridInfo> listVolumeGrids(const fs::path& path) {
  return volume_file::Reader(path).grids();
}

VolumeGridInfo chooseVolumeGrid(const fs::path& path, const VolumeImportOptions& options) {
  return volume_file::choose(path, listVolumeGrids(path), options);
}

Mesh loadVolumeSurface(const fs::path& path, const VolumeImportOptions& options) {
  volume_file::Reader file(path);
  const volume_file::SurfaceGrid surface = volume_file::readSurfaceGrid(file, options);
  const bool levelSet = surface.kind == VolumeGridKind::LevelSet;
  Mesh mesh;
  if (surface.grid->isType<openvdb::FloatGrid>())
    meshSurface(*openvdb::gridPtrCast<openvdb::FloatGrid>(surface.grid), surface.isovalue, mesh);
  else
    meshSurface(*openvdb::gridPtrCast<openvdb::DoubleGrid>(surface.grid), surface.isovalue, mesh);
  if (mesh.triangles.empty())
    volume_file::fail(path, fmt::format("grid '{}' has no surface ({} {})", surface.grid->getName(),
                                        levelSet ? "no zero crossing in its" : "no density crossing",
                                        levelSet ? "narrow band" : std::to_string(surface.isovalue)));
  const volume_file::Vec3Sampler colors(volume_file::colorGrid(file, options));
  if (colors) {
    mesh.colors.reserve(mesh.positions.size());
    for (const glm::dvec3& p : mesh.positions) mesh.colors.push_back(volume_file::colorOf(colors.at(p)));
  }
  validateMesh(mesh, path.string());
  return mesh;
}

namespace {

template <class Grid>
std::vector<glm::ivec3> activeVoxels(const Grid& grid, const fs::path& path) {
  if (grid.activeVoxelCount() > kMaxMaskVoxels)
    volume_file::fail(path, fmt::format("grid '{}' has {} active voxels, more than the {} a mask may bring",
                                        grid.getName(), grid.activeVoxelCount(), kMaxMaskVoxels));
  typename Grid::TreeType tree = grid.tree();  // a copy: its active tiles become voxels
  tree.voxelizeActiveTiles();
  std::vector<glm::ivec3> coords;
  coords.reserve(std::size_t(tree.activeVoxelCount()));
  for (auto it = tree.cbeginValueOn(); it; ++it)
    coords.emplace_back(it.getCoord().x(), it.getCoord().y(), it.getCoord().z());
  return coords;
}

}  // namespace

VoxelVolume loadVolumeVoxels(const fs::path& path, const VolumeImportOptions& options) {
  volume_file::Reader file(path);
  const VolumeGridInfo chosen = volume_file::choose(path, file.grids(), options);
  if (chosen.kind != VolumeGridKind::Voxels)
    volume_file::fail(path, "grid '" + chosen.name + "' is a " + nameOf(chosen.kind) + ", not a voxel mask");
  const openvdb::GridBase::Ptr grid = file.read(chosen.name);
  const openvdb::math::Transform& transform = grid->transform();
  const double voxelSize = volume_file::cubicVoxelSize(path, *grid);
  std::vector<glm::ivec3> coords = grid->isType<openvdb::MaskGrid>()
                                       ? activeVoxels(*openvdb::gridPtrCast<openvdb::MaskGrid>(grid), path)
                                       : activeVoxels(*openvdb::gridPtrCast<openvdb::BoolGrid>(grid), path);
  if (coords.empty()) volume_file::fail(path, "grid '" + chosen.name + "' has no active voxels");

  glm::ivec3 lower(std::numeric_limits<int>::max()), upper(std::numeric_limits<int>::min());
  for (const glm::ivec3& c : coords) lower = glm::min(lower, c), upper = glm::max(upper, c);
  int levels = 0;
  if (const auto stored = grid->getMetadata<openvdb::Int32Metadata>(volume_file::kLevelsMetadata)) {
    levels = stored->value();
    lower = glm::ivec3(0);
    if (levels < 1 || levels > kMaxLevels)
      volume_file::fail(path, fmt::format("grid '{}': metadata {} = {} is outside 1..{}", chosen.name,
                                          volume_file::kLevelsMetadata, levels, kMaxLevels));
  } else {
    const glm::i64vec3 extent = glm::i64vec3(upper) - glm::i64vec3(lower) + std::int64_t(1);
    const std::uint64_t side = std::uint64_t(std::max({extent.x, extent.y, extent.z}));
    levels = std::max(1, int(std::bit_width(side - 1)));
    if (levels > kMaxLevels)
      volume_file::fail(path, fmt::format("grid '{}' spans {} voxels, more than {} octree levels hold",
                                          chosen.name, side, kMaxLevels));
  }
  const std::int64_t side = std::int64_t(1) << levels;
  VoxelLevels tree(levels + 1);
  tree.back().reserve(coords.size());
  for (const glm::ivec3& c : coords) {
    const glm::i64vec3 local = glm::i64vec3(c) - glm::i64vec3(lower);
    if (glm::any(glm::lessThan(local, glm::i64vec3(0))) ||
        glm::any(glm::greaterThanEqual(local, glm::i64vec3(side))))
      volume_file::fail(path, fmt::format("grid '{}': voxel ({}, {}, {}) lies outside its {}-level cube",
                                          chosen.name, c.x, c.y, c.z, levels));
    tree.back().push_back(SliceVoxel{glm::ivec3(local)});
  }
  std::sort(tree.back().begin(), tree.back().end(),
            [](const SliceVoxel& a, const SliceVoxel& b) { return mortonLess(a.coord, b.coord); });

  const volume_file::Vec3Sampler colors(volume_file::colorGrid(file, options));
  const volume_file::Vec3Sampler normals(volume_file::normalGrid(file, options));
  const volume_file::ScalarSampler densities(volume_file::densityGrid(file));
  const auto worldOf = [&](const glm::ivec3& local) {
    const openvdb::Vec3d w =
        transform.indexToWorld(openvdb::Vec3d(local.x + lower.x, local.y + lower.y, local.z + lower.z));
    return glm::dvec3(w.x(), w.y(), w.z());
  };
  for (SliceVoxel& v : tree.back()) {
    const glm::dvec3 world = worldOf(v.coord);
    if (densities)
      v.color = volume_file::colorWithDensity(colors, world, densities.at(world));
    else if (colors)
      v.color = encodeColor(volume_file::colorOf(colors.at(world)));
    if (normals) {
      const glm::vec3 n = normals.at(world);
      v.normal = latticeNormal(std::isfinite(glm::dot(n, n)) && glm::dot(n, n) > 0.0f ? glm::normalize(n)
                                                                                      : glm::vec3(0, 0, 1));
    }
  }
  const bool hasColors =
      densities ? volume_file::keepDensityWhereItVaries(tree.back(), bool(colors)) : bool(colors);
  volume_file::addCoarserLevels(tree, hasColors, bool(normals));

  VoxelVolume volume;
  for (const auto& level : tree) volume.voxels += level.size();
  volume.leafVoxels = tree.back().size();
  volume.tree = treeOfLevels(tree, hasColors, bool(normals));
  // The cube's corner is the lower voxel's corner: half a voxel below its centre.
  volume.transform.origin = worldOf(glm::ivec3(0)) - 0.5 * voxelSize;
  volume.transform.size = voxelSize * double(side);
  volume.parameters.levels = levels;
  volume.parameters.contours = 0;
  return volume;
}

}  // namespace svo
