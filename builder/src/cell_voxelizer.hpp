// The out-of-core voxelizer's cells as work items, so that whoever builds them (threads of this process,
// or other processes sharing the work folder) builds exactly the cells the single-process build would.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "cell_partition.hpp"
#include "geometry.hpp"
#include "svo/builder/build.hpp"

namespace svo {

// Where some of a cell's triangles are binned: a process's partition (by rank) and the cell's bucket there.
struct CellPart {
  std::int32_t rank = 0;
  std::uint32_t bucket = 0;
};
// A cell to build: where its triangles are binned (in rank order, which is input order) and the slabs of its
// ancestors' contours that cut it.
struct CellTask {
  glm::ivec3 coord{0};
  std::vector<geom::Slab> slabs;
  std::vector<CellPart> parts;
  std::uint64_t triangles = 0;  // binned to it: its share of the work
};

// How the pass over the input and the gathering of the levels above the cells are shared among the processes
// of a job: process `rank` of `ranks` bins its share of the input's triangles and gathers some of the octants
// below the root. `exchange` is collective: each process passes its message and gets every process's, by
// rank. One process alone: rank 0 of 1.
struct TopSharing {
  int rank = 0, ranks = 1;
  std::function<std::vector<std::string>(const std::string& mine)> exchange = [](const std::string& mine) {
    return std::vector<std::string>{mine};
  };
  // Rank 0, once the scratch folder is ready: the other processes may start (null: none waits).
  std::function<void(int cellLevel)> start;
  // A process as failure messages name it.
  std::function<std::string(int rank)> describe = [](int rank) { return "rank " + std::to_string(rank); };
};

// The triangles every process binned, read per cell (thread-safe; a cell's are dropped once read).
class BinnedTriangles {
 public:
  BinnedTriangles(const std::filesystem::path& scratch, int ranks, const TriangleSource& source);
  std::vector<SourceTriangle> take(const CellTask& task) const;

 private:
  std::vector<CellPartition> partitions_;  // by rank
};

// The cells still to build, largest first, and how to build one in this process (thread-safe: it builds
// task i, hands it to CellCallbacks::built and returns its root).
struct CellJobs {
  int cellLevel = 0;
  std::vector<CellTask> tasks;
  std::function<CellRoot(std::size_t task)> buildHere;
  std::function<void(glm::ivec3 cell, std::uint64_t voxels)> builtElsewhere;  // CellCallbacks::builtElsewhere
};
// Builds every task, here or elsewhere, and returns their roots in task order.
using CellRunner = std::function<std::vector<CellRoot>(const CellJobs& jobs)>;
// Every task in this process, `concurrency` at a time; the first error stops the rest and is rethrown.
CellRunner localCellRunner(int concurrency);

// voxelizeCells (build.hpp) with the cells built by `runner`, on rank 0 of `sharing` (which tells the other
// processes `cellLevel` before they call shareTopLevels).
VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        const CellRunner& runner, const std::filesystem::path& scratch,
                        const TopSharing& sharing = {});
// A process other than rank 0 in voxelizeCells: bins its share of the input into `scratch` and gathers its
// octants, exchanging with the others. Returns false when the job failed there (rank 0 says why).
bool shareTopLevels(const TriangleSource& source, const SceneTransform& transform,
                    const BuildOptions& options, int cellLevel, const std::filesystem::path& scratch,
                    const TopSharing& sharing);

// One cell from its binned triangles (which are then dropped): its subtree, root first, pruned.
VoxelTree buildCell(const TriangleSource& source, const SceneTransform& transform,
                    const BuildOptions& options, int cellLevel, const BinnedTriangles& binned,
                    const CellTask& task, CellRoot& root);

}  // namespace svo
