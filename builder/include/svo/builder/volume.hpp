// OpenVDB files in and out: level sets and fog volumes become surfaces the builder voxelizes, voxel masks
// become octree levels voxel for voxel, and a store's level becomes a mask grid (or a level set) with color
// and normal grids beside it.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "svo/builder/mesh.hpp"
#include "svo/store/block.hpp"
#include "svo/store/store_reader.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

// Whether the file is read as a volume (by its extension).
bool isVolumeFile(const std::filesystem::path& path);

// A grid of a .vdb file as `svo build` sees it.
enum class VolumeGridKind : std::uint8_t {
  LevelSet,   // scalar, class level set: the surface is its zero crossing
  FogVolume,  // scalar, any other class: occupied above the density threshold
  Voxels,     // mask or bool: each active voxel is a finest voxel
  Attribute,  // vec3: colors or normals for another grid
  Other,      // nothing svo reads
};
const char* nameOf(VolumeGridKind kind);
struct VolumeGridInfo {
  std::string name, type;  // the grid's name and OpenVDB value type ("float", "vec3s", "mask", ...)
  VolumeGridKind kind = VolumeGridKind::Other;
  std::uint64_t activeVoxels = 0;
  double voxelSize = 0.0;
};
// The grids in the file, in file order. Throws std::runtime_error naming the file when it is not a readable
// OpenVDB file.
std::vector<VolumeGridInfo> listVolumeGrids(const std::filesystem::path& path);

struct VolumeImportOptions {
  std::string grid;        // the shape grid; empty: the file's only level set, fog volume or mask
  std::string colorGrid;   // a vec3 grid of linear RGB in [0, 1]; empty: one named "color" or "Cd"
  std::string normalGrid;  // a vec3 grid (masks only); empty: one named "normal" or "N"
  // A fog volume's voxels with at least this density are occupied: half of a normalized density's range,
  // where OpenVDB's sdfToFogVolume puts it halfway into its narrow band.
  float densityThreshold = 0.5f;
};
// The shape grid the options pick: the named one, or the only level set, fog volume or mask. Throws naming
// the file and listing its grids when none or several could be meant.
VolumeGridInfo chooseVolumeGrid(const std::filesystem::path& path, const VolumeImportOptions& options);

// A level set's zero crossing or a fog volume's threshold surface as triangles (OpenVDB's volumeToMesh at
// the grid's own resolution), outward-facing, with colors sampled from the color grid at the vertices.
Mesh loadVolumeSurface(const std::filesystem::path& path, const VolumeImportOptions& options);

// A mask or bool grid as octree levels, one finest voxel per active voxel: the octree's depth is the grid's
// (from `svo export`'s metadata, else the smallest power of two holding the active voxels), coarser voxels
// average their children's colors and normals, and there are no contours.
struct VoxelVolume {
  VoxelTree tree;
  SceneTransform transform;
  BuildParameters parameters;
  std::uint64_t voxels = 0, leafVoxels = 0;
};
VoxelVolume loadVolumeVoxels(const std::filesystem::path& path, const VolumeImportOptions& options);

// `svo export`: one level of a store as an OpenVDB file. The occupancy grid ("occupancy", a mask; or a
// narrow-band level set around the voxels, OpenVDB's topologyToLevelSet), and vec3 grids "color" (linear RGB,
// when the store has colors) and "normal", in the scene's world frame: a voxel of the level is one VDB
// voxel. A store leaf coarser than the level covers all its cube's voxels there.
struct VolumeExportOptions {
  int level = 0;  // 1 .. the store's levels
  bool levelSet = false;
  std::function<void(double)> progress;
};
struct VolumeExportReport {
  std::uint64_t voxels = 0;
  double voxelSize = 0.0;
  std::uint64_t fileBytes = 0;
};
// Written to a temporary name and renamed when complete. Throws std::runtime_error on a bad level or a store
// that cannot be read.
VolumeExportReport exportVolume(const StoreReader& store, const std::filesystem::path& output,
                                const VolumeExportOptions& options);

}  // namespace svo
