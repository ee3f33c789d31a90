// Top-down voxelization of a triangle mesh into an ESVO octree with contours, colors and normals.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

#include "svo/builder/mesh.hpp"
#include "svo/store/block.hpp"
#include "svo/store/store_writer.hpp"

namespace svo {

struct BuildOptions {
  int levels = 10;       // octree depth: the finest voxels are 2^-levels of the scene cube
  bool contours = true;  // fit contours (sec. 5.2); off gives cube voxels
  // A contour is stored only where it cuts the voxel's ancestor-bounded hull, along its normal, by more than
  // a fraction of the voxel size (sec. 5.2: "only where it reduces the approximation error enough"): one
  // fraction for the finest voxels, one for those above. A voxel's shape is its cube cut by all its
  // ancestors' contours (sec. 5.3), so an inner voxel's contour bounds every voxel below it and spares many
  // of the finest their own. Against 1/8 for both (svo bench quality, 1 voxel per pixel and 4x closer):
  // stores 9-33% smaller; depth p99 14% smaller where the finest voxels are below a pixel (bunny, 9 and 10
  // levels), up to 23% larger where they are magnified (bunny, 9 levels 4x closer; 2M terrain: within 2%).
  float leafContourMinReduction = 0.25f;
  float innerContourMinReduction = 0.0f;  // any cut
  // Error-driven stop (0 = off): a voxel is not refined when its contour thickness is within
  // `geometryError` finest voxels and its attributes within the color / normal errors.
  float geometryError = 0.0f;
  float colorError = 0.0f;   // 8-bit steps, max over the voxel's geometry
  float normalError = 0.0f;  // degrees, max over the voxel's geometry
  LayoutOptions layout;
  // Called from worker threads with the completed fraction in [0, 1].
  std::function<void(double)> progress;
};

// What a store built with `options` records of them in its header.
inline BuildParameters storedParameters(const BuildOptions& options) {
  return {options.levels, options.geometryError, options.colorError, options.normalError,
          std::uint32_t(options.contours)};
}

struct BuildStats {
  std::vector<std::uint64_t> voxelsPerLevel;  // index 0 = root
  std::uint64_t leafVoxels = 0, contours = 0, trianglesUsed = 0;
  LayoutStats layout;
  double seconds = 0.0;
};

// Scene cube: the mesh bounds' centre, widened to a cube with a small margin so no triangle lies on the
// outer boundary. Throws when the mesh has no extent at all.
SceneTransform fitSceneCube(const Mesh& mesh);
SceneTransform fitSceneCube(glm::dvec3 lower, glm::dvec3 upper);  // of the triangles' vertex bounds

// Builds the voxel tree in the octree's [1,2]^3 frame given by `transform`. Deterministic for a given input
// and options, whatever the thread count.
VoxelTree voxelize(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options,
                   BuildStats* stats = nullptr);

// The out-of-core build voxelizes cell by cell: a cell is a voxel of the cell level with its whole subtree.
struct CellRoot {
  VoxelRecord record;  // the cell's root voxel (its children are in the cell's subtree)
  struct Sums {        // area-weighted attribute sums; the cell's ancestors' attributes add them up
    double weight = 0.0;
    glm::dvec4 color{0.0};
    glm::dvec3 normal{0.0};
  } sums;
};
struct CellCallbacks {
  // The streaming passes' progress ("partition", "contours"), fraction of the triangles read.
  std::function<void(const char* phase, double fraction)> progress;
  // A cell an earlier run finished (resume): its root, or nullopt to build it. Asked once per cell once the
  // triangles are binned.
  std::function<std::optional<CellRoot>(glm::ivec3 cell)> finished;
  // How many cells the top levels found (once, before any cell is built).
  std::function<void(std::size_t cells)> planned;
  // A cell's subtree (root first), pruned, with its root; from worker threads.
  std::function<void(glm::ivec3 cell, VoxelTree&& subtree, const CellRoot& root)> built;
  // A cell another process built and spilled, with its voxel count (a build shared out over MPI).
  std::function<void(glm::ivec3 cell, std::uint64_t voxels)> builtElsewhere;
};

// voxelize() cell by cell below `cellLevel` (in [1, levels - 1]), never holding the whole mesh:
// 1. one pass over the source bins each triangle into the cells and the octants below the root it overlaps
//    (in `scratch`, a folder that is created and removed);
// 2. two passes over each octant's triangles gather the contour candidates of the voxels above the cells,
//    then their extents, which settles the top voxels' contours;
// 3. each cell is built from its binned triangles, `concurrency` at a time, handed to `callbacks.built` and
//    dropped.
// Returns the tree down to the cell level, the cells' roots as leaves. The top tree plus the cells' subtrees
// are exactly voxelize()'s tree of the same triangles.
VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        int concurrency, const std::filesystem::path& scratch);

// Adds a tree's voxels per level, leaves and contours to `stats`; its root is a voxel of `rootLevel`.
void addTreeStats(const VoxelTree& tree, int rootLevel, BuildStats& stats);

// The out-of-core build: mesh -> store with bounded memory, resumable.
struct OutOfCoreOptions {
  // Peak resident bytes to stay within: picks the shallowest cell level whose fullest cell (estimated from
  // the surface area in it) fits next to the mesh. Not needed when cellLevel is given.
  std::size_t memoryBytes = 0;
  std::string memoryOrigin = "--memory";  // what set memoryBytes, for the messages of a bound too small
  // What the process holds besides the build (the program and its libraries), counted against memoryBytes.
  std::size_t processBytes = 0;
  int cellLevel = 0;  // in [1, levels - 1]; 0: chosen from memoryBytes
  int threads = 1;    // cells built at once (each holds its own subtree)
  // Threads writing the store once every cell is built; 0: `threads`. An MPI job's rank 0 writes with the
  // cores of the ranks on its host too, idle by then.
  int writeThreads = 0;
  // Keep the cells an interrupted run of the same build spilled (same input and options), build the rest.
  bool resume = false;
  std::filesystem::path workDir;  // spilled cells; default: STORE.build, removed when the store is written
  std::function<void(const char* phase, double fraction)> progress;
  // As cells complete (here or, shared out, elsewhere): cells done of all, and the voxels they hold.
  std::function<void(std::size_t done, std::size_t cells, std::uint64_t voxels)> cellProgress;
  // After each cell's spill file is complete on disk (a throw here interrupts the build, as a kill would).
  std::function<void(glm::ivec3 cell)> cellSpilled;
};
struct OutOfCoreReport {
  int cellLevel = 0;
  std::size_t cells = 0, cellsReused = 0;
  std::vector<SliceInfo> slices;
  BuildStats stats;
  std::map<std::string, double> phaseSeconds;
};
// Writes `store` from the source with voxelizeCells: its octree (StoreReader::loadTree) is exactly the
// in-core build's. Like writeStore, the target is written only complete.
OutOfCoreReport buildStore(const TriangleSource& source, const BuildOptions& options,
                           const StoreWriteOptions& write, const OutOfCoreOptions& ooc,
                           const std::filesystem::path& store);

// Peak bytes the in-core build (voxelize, then writeStore) of these triangles adds to the process, from their
// surface area (voxels cross it at about two per finest voxel face, as the out-of-core build's cell estimate
// has it) and their count. One pass over the source.
std::uint64_t estimateInCoreBuildBytes(const TriangleSource& source, const BuildOptions& options);

// voxelize + layoutBlock: the whole in-core build.
Octree buildOctree(const Mesh& mesh, const BuildOptions& options, BuildStats* stats = nullptr);

}  // namespace svo
