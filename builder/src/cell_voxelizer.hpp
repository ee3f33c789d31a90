// The out-of-core voxelizer's cells as work items, so that whoever builds them (threads of this process,
// or other processes sharing the work folder) builds exactly the cells the single-process build would.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <vector>

#include <glm/vec3.hpp>

#include "cell_partition.hpp"
#include "geometry.hpp"
#include "svo/builder/build.hpp"

namespace svo {

// A cell to build: where its triangles are binned and the slabs of its ancestors' contours that cut it.
struct CellTask {
  glm::ivec3 coord{0};
  std::vector<geom::Slab> slabs;
  std::uint32_t bucket = 0;
  std::uint64_t triangles = 0;  // binned to it: its share of the work
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

// voxelizeCells (build.hpp) with the cells built by `runner`.
VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        const CellRunner& runner, const std::filesystem::path& scratch);

// One cell from its triangles in `partition` (which then drops them): its subtree, root first, pruned.
VoxelTree buildCell(const TriangleSource& source, const SceneTransform& transform, const BuildOptions& options,
                    int cellLevel, CellPartition& partition, const CellTask& task, CellRoot& root);

}  // namespace svo
