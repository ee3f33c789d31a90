// OpenVDB files in and out: level sets and fog volumes become octree levels straight from their field (or
// surfaces the mesh builder voxelizes), voxel masks become octree levels voxel for voxel, and a store's level
// becomes a mask grid (or a level set) with color and normal grids beside it.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "svo/builder/build.hpp"
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
  Attribute,  // vec3, or marked by svo export: colors, normals or densities for another grid
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

// A level set's zero crossing or a fog volume's threshold surface voxelized straight from the grid, without a
// mesh. The surface is the zero set of the grid's trilinear field (a fog volume's: density minus the
// threshold); the scene cube is fitted to it as to a mesh (fitSceneCube), so the finest voxels need not be
// the grid's: a finest voxel is occupied where the trilinear field changes sign within it, which is exact at
// any ratio of the two widths (the field over a box within one grid cell is the trilinear interpolation of
// its values at the box's corners). A finest voxel's normal is the field's normalized gradient (central
// differences a grid voxel either way) at the mean of the points where the surface crosses the edges of its
// pieces of grid cells, its color the color grid's there; its contour (options.contours) is the slab along
// its normal holding those points, kept as the mesh builder keeps one. A fog volume's finest voxel carries,
// as its color's alpha, the highest density the field reaches in its cube (clamped to [0, 1]; the color
// neutral grey without a color grid), where those densities differ: a scene whose densities are all alike
// carries none. Coarser voxels average their children's colors and normals and fit their contours to their
// finest voxels' points. Every leaf is at the
// finest level (the error-driven stop is the mesh builder's). Throws naming the file on a grid that is not a
// level set or fog volume, has no surface, or has a rotated or non-cubic transform.
struct SurfaceVolume {
  VoxelTree tree;
  SceneTransform transform;
};
SurfaceVolume voxelizeVolumeSurface(const std::filesystem::path& path, const VolumeImportOptions& import,
                                    const BuildOptions& options, BuildStats* stats = nullptr);

// A mask or bool grid as octree levels, one finest voxel per active voxel: the octree's depth is the grid's
// (from `svo export`'s metadata, else the smallest power of two holding the active voxels), coarser voxels
// average their children's colors and normals, and there are no contours. A float grid named "density"
// gives the colors' alpha, as for a fog volume's surface.
struct VoxelVolume {
  VoxelTree tree;
  SceneTransform transform;
  BuildParameters parameters;
  std::uint64_t voxels = 0, leafVoxels = 0;
};
VoxelVolume loadVolumeVoxels(const std::filesystem::path& path, const VolumeImportOptions& options);

// `svo export`: one level of a store as an OpenVDB file. The occupancy grid ("occupancy", a mask; or a
// narrow-band level set around the voxels, OpenVDB's topologyToLevelSet), vec3 grids "color" (linear RGB,
// when the store has colors) and "normal", and a float grid "density" (the colors' alpha, when some is below
// 1; marked as an attribute so that it is not taken for a shape), in the scene's world frame: a voxel of the
// level is one VDB voxel. A store leaf coarser than the level covers all its cube's voxels there.
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
