// OpenVDB out (volume.hpp): one walk over the store's slices fills a mask grid with the level's voxels (and
// the cubes of coarser leaves), vec3 grids with their colors and normals, a float grid with their densities
// (the colors' alpha) where some are below 1, then the file is written beside its target and renamed.
#include <cstdio>
#include <stdexcept>
#include <string>

#include <unistd.h>

#include <fmt/format.h>
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/TopologyToLevelSet.h>

#include "svo/builder/volume.hpp"
#include "svo/store/format.hpp"
#include "volume_file.hpp"

namespace svo {

namespace fs = std::filesystem;

namespace {

// The level set's narrow band on each side of the voxels: OpenVDB's default half width.
constexpr int kLevelSetHalfWidth = 3;

struct ExportGrids {
  openvdb::MaskGrid::Ptr occupancy = openvdb::MaskGrid::create();
  openvdb::Vec3SGrid::Ptr colors, normals;
  openvdb::FloatGrid::Ptr densities;  // the colors' alpha; kept only when some voxel's is below 1
  bool translucent = false;
};

openvdb::Vec3SGrid::Ptr vectorGrid(const char* name, openvdb::VecType type,
                                   const openvdb::math::Transform::Ptr& transform) {
  auto grid = openvdb::Vec3SGrid::create(openvdb::Vec3s(0.0f));
  grid->setName(name);
  grid->setVectorType(type);
  grid->setTransform(transform);
  return grid;
}

// The voxels of a store level from one walk: those of the level, and the cubes of leaves above it.
void fillGrids(const StoreReader& store, int level, ExportGrids& grids,
               const std::function<void(double)>& progress) {
  auto occupancy = grids.occupancy->getAccessor();
  std::optional<openvdb::Vec3SGrid::Accessor> colors, normals;
  std::optional<openvdb::FloatGrid::Accessor> densities;
  if (grids.colors) colors = grids.colors->getAccessor(), densities = grids.densities->getAccessor();
  if (grids.normals) normals = grids.normals->getAccessor();
  struct Values {
    openvdb::Vec3s color, normal;
    float density = 1.0f;
  };
  const auto valuesOf = [&](const SliceVoxel& v) {
    Values out;
    if (colors) {
      const glm::vec4 c = decodeColor(v.color);
      out.color = openvdb::Vec3s(c.r, c.g, c.b), out.density = c.a;
      grids.translucent |= c.a < 1.0f;
    }
    if (normals) {
      const glm::vec3 n = decodeNormal(v.normal);
      out.normal = openvdb::Vec3s(n.x, n.y, n.z);
    }
    return out;
  };
  const auto put = [&](const SliceVoxel& v) {
    const openvdb::Coord ijk(v.coord.x, v.coord.y, v.coord.z);
    const Values values = valuesOf(v);
    occupancy.setValueOn(ijk);
    if (colors) colors->setValueOn(ijk, values.color), densities->setValueOn(ijk, values.density);
    if (normals) normals->setValueOn(ijk, values.normal);
  };
  const auto fillCube = [&](const SliceVoxel& v, int voxelLevel) {
    const int shift = level - voxelLevel;
    const openvdb::Coord lower(v.coord.x << shift, v.coord.y << shift, v.coord.z << shift);
    const openvdb::CoordBBox box(lower, lower.offsetBy((1 << shift) - 1));
    const Values values = valuesOf(v);
    grids.occupancy->tree().fill(box, true, true);
    if (colors)
      grids.colors->tree().fill(box, values.color, true),
          grids.densities->tree().fill(box, values.density, true);
    if (normals) grids.normals->tree().fill(box, values.normal, true);
  };
  const std::vector<SliceInfo>& slices = store.slices();
  std::size_t walked = 0;
  store.walk(
      [&](std::uint32_t slice, std::span<const SliceVoxel>, std::span<const SliceVoxel> voxels) {
        if (slices[slice].voxelLevel == level)
          for (const SliceVoxel& v : voxels) put(v);
      },
      [&](std::uint32_t slice, std::span<const SliceVoxel>, std::span<const SliceVoxel> voxels) {
        const int voxelLevel = slices[slice].voxelLevel;
        if (voxelLevel < level)
          for (const SliceVoxel& v : voxels)
            if (v.childMask == 0) fillCube(v, voxelLevel);
        if (progress) progress(double(++walked) / double(slices.size()));
      });
}

void writeAtomically(const fs::path& output, const openvdb::GridPtrVec& grids) {
  const fs::path temp = output.string() + ".partial-" + std::to_string(::getpid());
  try {
    openvdb::io::File file(temp.string());
    file.write(grids);
    file.close();
    fs::rename(temp, output);
  } catch (const std::exception& e) {
    std::error_code ec;
    fs::remove(temp, ec);
    throw std::runtime_error(output.string() + ": cannot write (" + e.what() + ")");
  }
}

}  // namespace

VolumeExportReport exportVolume(const StoreReader& store, const fs::path& output,
                                const VolumeExportOptions& options) {
  volume_file::initialize();
  const StoreHeader& header = store.header();
  const int levels = header.parameters.levels;
  if (options.level < 1 || options.level > levels)
    throw std::runtime_error(fmt::format("{}: level {} is outside the store's levels 1..{}",
                                         store.path().string(), options.level, levels));
  // A voxel of the level is one VDB voxel, its centre at the index point.
  const double voxelSize = header.transform.size / double(std::uint64_t(1) << options.level);
  const glm::dvec3 centre = header.transform.origin + 0.5 * voxelSize;
  auto transform = openvdb::math::Transform::createLinearTransform(voxelSize);
  transform->postTranslate(openvdb::Vec3d(centre.x, centre.y, centre.z));

  ExportGrids grids;
  grids.occupancy->setTransform(transform);
  if (header.hasColors) {
    grids.colors = vectorGrid("color", openvdb::VEC_INVARIANT, transform);
    grids.densities = openvdb::FloatGrid::create(0.0f);
    grids.densities->setName(volume_file::kDensityGridName);
    grids.densities->setGridClass(openvdb::GRID_FOG_VOLUME);
    grids.densities->insertMeta(volume_file::kAttributeMetadata, openvdb::StringMetadata("density"));
    grids.densities->setTransform(transform);
  }
  if (header.hasNormals) grids.normals = vectorGrid("normal", openvdb::VEC_COVARIANT_NORMALIZE, transform);
  fillGrids(store, options.level, grids, options.progress);

  VolumeExportReport report;
  report.voxels = grids.occupancy->activeVoxelCount();
  report.voxelSize = voxelSize;
  openvdb::GridBase::Ptr shape = grids.occupancy;
  if (options.levelSet) {
    shape = openvdb::tools::topologyToLevelSet(*grids.occupancy, kLevelSetHalfWidth, 0, 0, 0);
    shape->setGridClass(openvdb::GRID_LEVEL_SET);
    shape->setName("surface");
  } else {
    shape->setName("occupancy");
    shape->insertMeta(volume_file::kLevelsMetadata, openvdb::Int32Metadata(options.level));
  }
  openvdb::GridPtrVec out{shape};
  if (grids.colors) out.push_back(grids.colors);
  if (grids.translucent) out.push_back(grids.densities);
  if (grids.normals) out.push_back(grids.normals);
  for (const openvdb::GridBase::Ptr& grid : out) grid->pruneGrid();
  writeAtomically(output, out);
  report.fileBytes = fs::file_size(output);
  return report;
}

}  // namespace svo
