// What the OpenVDB import and export share (volume_io.cpp): the library's one-time set-up, errors naming the
// file, a file read once with its grids listed, the shape grid chosen, the
// attribute grids sampled, and coarser octree levels made from the finest.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <openvdb/openvdb.h>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

#include "svo/builder/volume.hpp"

namespace svo::volume_file {

// Metadata `svo export` gives its shape grid: the octree depth whose voxels the grid's voxels are, with the
// scene cube's corner at index (0, 0, 0).
inline constexpr const char* kLevelsMetadata = "svo_levels";
// Metadata naming what an attribute grid of `svo export` holds ("density"), so that it is never taken for a
// shape to build from.
inline constexpr const char* kAttributeMetadata = "svo_attribute";
// The scalar grid a voxel mask's densities come from: svo export's name, OpenVDB's and Houdini's.
inline constexpr const char* kDensityGridName = "density";

// OpenVDB's grid types registered, once per process.
void initialize();
[[noreturn]] void fail(const std::filesystem::path& path, const std::string& what);
// The grid's voxel width; throws naming the file unless its transform is linear, axis-aligned and cubic.
double cubicVoxelSize(const std::filesystem::path& path, const openvdb::GridBase& grid);

// A file's grids, read whole once; a grid the reader hands out is freed with the last of the reader and the
// caller's pointers.
class Reader {
 public:
  // Throws naming the file when it is missing or not a readable OpenVDB file.
  explicit Reader(const std::filesystem::path& path);
  ~Reader();
  const std::filesystem::path& path() const { return path_; }
  const std::vector<VolumeGridInfo>& grids() const { return grids_; }
  openvdb::GridBase::Ptr read(const std::string& name) const;  // the first grid of that name

 private:
  std::filesystem::path path_;
  std::vector<VolumeGridInfo> grids_;
  openvdb::GridPtrVec content_;  // grids_'s grids, in file order
};

// The shape grid the options pick (chooseVolumeGrid's rule) among the file's `grids`.
VolumeGridInfo choose(const std::filesystem::path& path, const std::vector<VolumeGridInfo>& grids,
                      const VolumeImportOptions& options);
// The level set or fog volume the options pick, read whole, and the value of its surface. Throws naming the
// file when the pick is a voxel mask or the density threshold is not a number.
struct SurfaceGrid {
  VolumeGridKind kind = VolumeGridKind::LevelSet;
  openvdb::GridBase::Ptr grid;  // float or double
  double isovalue = 0.0;        // 0 for a level set, the density threshold for a fog volume
};
SurfaceGrid readSurfaceGrid(const Reader& file, const VolumeImportOptions& options);
// The vec3 grid the options name, or the first default name present (color, Cd; normal, N); null when none is
// named and none is present. Throws naming the file when the named one is missing or not a vec3 grid.
openvdb::GridBase::Ptr colorGrid(const Reader& file, const VolumeImportOptions& options);
openvdb::GridBase::Ptr normalGrid(const Reader& file, const VolumeImportOptions& options);

// Samples a vec3 grid at world positions (trilinear), whatever its value precision; false when there is none.
class Vec3Sampler {
 public:
  explicit Vec3Sampler(openvdb::GridBase::Ptr grid);
  explicit operator bool() const { return bool(grid_); }
  glm::vec3 at(const glm::dvec3& world) const;

 private:
  openvdb::Vec3SGrid::Ptr grid_;
};
// The float or double grid named kDensityGridName; null when there is none. Throws naming the file when that
// grid is of another type.
openvdb::FloatGrid::Ptr densityGrid(const Reader& file);
// Samples a float grid at world positions (trilinear); false when there is none.
class ScalarSampler {
 public:
  explicit ScalarSampler(openvdb::FloatGrid::Ptr grid) : grid_(std::move(grid)) {}
  explicit operator bool() const { return bool(grid_); }
  float at(const glm::dvec3& world) const;

 private:
  openvdb::FloatGrid::Ptr grid_;
};

// A color grid's value as the builder takes it: clamped to [0, 1], what is not a number black.
glm::vec4 colorOf(glm::vec3 rgb);
// A voxel's color carrying a density as its alpha (clamped to [0, 1], what is not a number 0): the color
// grid's where there is one, else neutral grey.
std::uint32_t colorWithDensity(const Vec3Sampler& colors, const glm::dvec3& world, double density);
// Keeps the leaves' densities (their colors' alpha) where they differ; where all are alike the alpha becomes
// 255 and, without a color grid, the scene carries no colors. Returns whether the scene carries colors.
bool keepDensityWhereItVaries(std::vector<SliceVoxel>& leaves, bool hasColorGrid);

// The levels above the finest (levels.back(), in Morton order, filled): each parent once, in Morton order,
// with its children's mean color and normal.
void addCoarserLevels(VoxelLevels& levels, bool hasColors, bool hasNormals);

}  // namespace svo::volume_file
