// The out-of-core build (build.hpp, buildStore): the triangles are streamed from the source and binned per
// cell, the levels above the cell level are voxelized in memory, every cell's subtree is built on its own
// from its triangles and spilled to a work folder (zstd, checksummed, renamed into
// place when complete, so an interrupted build resumes from the cells on disk), then the store is written
// (StoreFileWriter::appendForest): the same slices as an in-core build's, cell by cell.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <memory>
#include <mutex>
#include <new>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include <tbb/task_arena.h>
#include <glm/geometric.hpp>
#include <nlohmann/json.hpp>

#include "cell_spill.hpp"
#include "out_of_core.hpp"
#include "svo/builder/build.hpp"

namespace svo {
namespace {

// Resident bytes per voxel of a cell at its peak, while its store slices are written: the records (24 B)
// plus the writer's per-voxel levels, prefix counts and inheritance state (~46 B). Measured: see
// kVoxelsPerArea.
constexpr double kPeakBytesPerVoxel = 72.0;
// Voxels (all levels) per finest-voxel-face of surface area: a surface crosses ~1.5 voxels per voxel face
// of area on average over orientations (|nx| + |ny| + |nz|), and the coarser levels add a third.
constexpr double kVoxelsPerArea = 2.0;
// Resident bytes per triangle of a cell while it is built: its binned record (108-188 B) turned into a
// mesh of its own (three corners each, ~166 B), the voxelizer's copy (88 B), its corner normals (36 B) and
// its per-level index lists.
constexpr double kBytesPerCellTriangle = 430.0;
// Besides the source and the cells: the partition's buffers (64 MiB, cell_partition.cpp) and the top levels.
constexpr double kPartitionBytes = 80.0 * (1 << 20);
// The in-core build's peak per voxel (voxelize's records, then writeStore's per-level arrays beside them) and
// per triangle (the file as assimp reads it, the Mesh, the voxelizer's copy and index lists). Measured as svo
// build's peak resident less that of a 2-level tetrahedron (147 MiB, the program and its libraries): 61-68 B
// per voxel (20k-triangle sphere at 9 and 10 levels, npm bunny at 10, 110k-triangle CAD model at 11) and
// 372 B per triangle (2M-triangle terrain at 8 levels); rounded up.
constexpr double kInCorePeakBytesPerVoxel = 70.0;
constexpr double kInCoreBytesPerTriangle = 380.0;
// The deepest cell level --memory considers: 2^9 cells a side is 512^3 work items, far past any budget's
// need.
constexpr int kDeepestChosenCellLevel = 9;
// Work-folder format; a resume refuses a folder of another format.
constexpr int kWorkFormat = 2;

// What a resume must agree on: the input (hashed) and every option that changes the voxels or the slices.
nlohmann::json manifestOf(const TriangleSource& source, const BuildOptions& options,
                          const StoreWriteOptions& write, int cellLevel) {
  return {{"format", kWorkFormat},
          {"meshHash", std::to_string(source.fingerprint())},
          {"triangles", source.triangleCount()},
          {"levels", options.levels},
          {"contours", options.contours},
          {"leafContourMinReduction", options.leafContourMinReduction},
          {"innerContourMinReduction", options.innerContourMinReduction},
          {"geometryError", options.geometryError},
          {"colorError", options.colorError},
          {"normalError", options.normalError},
          {"cellLevel", cellLevel},
          {"sliceBytes", write.sliceBytes}};
}

// The shallowest cell level whose fullest cell, by the surface area and triangles binned to it, fits the
// memory left after the source and the partition; throws when even the deepest does not.
int chooseCellLevel(const TriangleSource& source, const SceneTransform& transform,
                    const BuildOptions& options, const OutOfCoreOptions& ooc, int concurrency,
                    const std::function<void(double)>& progress) {
  const std::size_t memoryBytes = ooc.memoryBytes;
  const double fixed = double(ooc.processBytes + source.residentBytes()) + kPartitionBytes;
  const double perCell = (double(memoryBytes) - fixed) / double(std::max(1, concurrency));
  const auto sizeText = [&](double bytes) {
    return bytes < double(1 << 20) ? std::to_string(std::llround(bytes / 1024.0)) + " KiB"
                                   : std::to_string(std::llround(bytes / double(1 << 20))) + " MiB";
  };
  const std::string bound = ooc.memoryOrigin + ": " + sizeText(double(memoryBytes));
  if (perCell <= 0.0)
    throw std::runtime_error(bound + " does not hold the input (" + sizeText(fixed) + " for the program, " +
                             std::to_string(source.triangleCount()) +
                             " triangles and the partition buffers)");
  const double finest = std::ldexp(1.0, -options.levels);  // octree units: the scene cube is [1, 2]^3
  // Area and triangles per cell of the deepest level considered (by centroid), then summed up level by level.
  struct Load {
    double area = 0.0, triangles = 0.0;
  };
  const int deepest = std::min(options.levels - 1, kDeepestChosenCellLevel);
  const auto key = [](glm::ivec3 c) {
    return (std::uint64_t(c.z) << 42) | (std::uint64_t(c.y) << 21) | std::uint64_t(c.x);
  };
  std::unordered_map<std::uint64_t, Load> cells;
  std::uint64_t read = 0;
  const double side = std::ldexp(1.0, deepest);
  source.read([&](std::span<const SourceTriangle> batch) {
    for (const SourceTriangle& t : batch) {
      const glm::dvec3 a = transform.toOctree(t.positions[0]), b = transform.toOctree(t.positions[1]),
                       c = transform.toOctree(t.positions[2]);
      const glm::ivec3 cell = glm::clamp(glm::ivec3(glm::floor(((a + b + c) / 3.0 - 1.0) * side)),
                                         glm::ivec3(0), glm::ivec3(int(side) - 1));
      Load& load = cells[key(cell)];
      load.area += 0.5 * glm::length(glm::cross(b - a, c - a));
      load.triangles += 1.0;
    }
    read += batch.size();
    progress(double(read) / double(std::max<std::uint64_t>(source.triangleCount(), 1)));
  });
  std::vector<std::pair<glm::ivec3, Load>> deepestCells;
  deepestCells.reserve(cells.size());
  for (const auto& [k, load] : cells)
    deepestCells.push_back({glm::ivec3(int(k & 0x1FFFFF), int(k >> 21 & 0x1FFFFF), int(k >> 42)), load});
  std::unordered_map<std::uint64_t, Load>().swap(cells);
  double needed = 0.0;
  for (int level = 1; level <= deepest; ++level) {
    std::unordered_map<std::uint64_t, Load> atLevel;
    for (const auto& [cell, load] : deepestCells) {
      Load& l = atLevel[key(cell >> (deepest - level))];
      l.area += load.area, l.triangles += load.triangles;
    }
    needed = 0.0;
    for (const auto& [k, load] : atLevel)
      needed = std::max(needed, kPeakBytesPerVoxel * kVoxelsPerArea * load.area / (finest * finest) +
                                    kBytesPerCellTriangle * load.triangles);
    if (needed <= perCell) return level;
  }
  throw std::runtime_error(bound + " is too small for " + std::to_string(options.levels) +
                           " levels of this mesh (a cell needs about " + sizeText(needed) + " next to " +
                           sizeText(fixed) + " for the input)");
}

}  // namespace

std::filesystem::path scratchOf(const std::filesystem::path& work) {
  return work / "triangles";
}

std::filesystem::path workFolderOf(const OutOfCoreOptions& ooc, const std::filesystem::path& store) {
  return ooc.workDir.empty() ? std::filesystem::path(store.string() + ".build") : ooc.workDir;
}

std::uint64_t estimateInCoreBuildBytes(const TriangleSource& source, const BuildOptions& options) {
  const SceneTransform transform = fitSceneCube(source.lower(), source.upper());
  double area = 0.0;  // octree units: the scene cube is [1, 2]^3
  source.read([&](std::span<const SourceTriangle> batch) {
    for (const SourceTriangle& t : batch) {
      const glm::dvec3 a = transform.toOctree(t.positions[0]), b = transform.toOctree(t.positions[1]),
                       c = transform.toOctree(t.positions[2]);
      area += 0.5 * glm::length(glm::cross(b - a, c - a));
    }
  });
  const double finest = std::ldexp(1.0, -options.levels);
  return std::uint64_t(kInCorePeakBytesPerVoxel * kVoxelsPerArea * area / (finest * finest) +
                       kInCoreBytesPerTriangle * double(source.triangleCount()));
}

OutOfCoreReport buildStore(const TriangleSource& source, const BuildOptions& options,
                           const StoreWriteOptions& write, const OutOfCoreOptions& ooc,
                           const std::filesystem::path& store) {
  return buildStore(source, options, write, ooc, store, localCellRunner(std::max(1, ooc.threads)));
}

OutOfCoreReport buildStore(const TriangleSource& source, const BuildOptions& options,
                           const StoreWriteOptions& write, const OutOfCoreOptions& ooc,
                           const std::filesystem::path& store, const CellRunner& runner,
                           const TopSharing& sharing) {
  const auto start = std::chrono::steady_clock::now();
  const auto seconds = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  const auto progress = [&](const char* phase, double f) {
    if (ooc.progress) ooc.progress(phase, f);
  };
  OutOfCoreReport report;
  const SceneTransform transform = fitSceneCube(source.lower(), source.upper());
  const int concurrency = std::max(1, ooc.threads);
  const std::filesystem::path work = workFolderOf(ooc, store);
  const std::filesystem::path manifestPath = work / "manifest.json";
  // The work folder of an interrupted run, when resuming.
  std::optional<nlohmann::json> old;
  if (ooc.resume && std::filesystem::exists(manifestPath)) {
    try {
      std::ifstream(manifestPath) >> old.emplace();
    } catch (const std::exception&) {
      throw std::runtime_error(manifestPath.string() + ": unreadable; delete " + work.string() +
                               " or drop --resume");
    }
  }
  if (ooc.cellLevel > 0) {
    report.cellLevel = ooc.cellLevel;
  } else if (old && old->contains("cellLevel") && (*old)["cellLevel"].is_number_integer()) {
    report.cellLevel = (*old)["cellLevel"].get<int>();  // a resume keeps the interrupted run's cells
  } else {
    const auto planStart = std::chrono::steady_clock::now();
    report.cellLevel =
        chooseCellLevel(source, transform, options, ooc, concurrency, [&](double f) { progress("plan", f); });
    report.phaseSeconds["plan"] = seconds(planStart);
  }

  // The work folder: kept from an interrupted run with --resume (if it is this build's), else fresh.
  const nlohmann::json manifest = manifestOf(source, options, write, report.cellLevel);
  bool reuse = false;
  if (old) {
    for (const auto& [key, value] : manifest.items())
      if (!old->contains(key) || (*old)[key] != value)
        throw std::runtime_error("--resume: " + work.string() + " holds a build with another " + key +
                                 "; delete it or drop --resume");
    reuse = true;
  } else {
    std::filesystem::remove_all(work);
    std::filesystem::create_directories(work);
    std::ofstream out(manifestPath);
    if (!(out << manifest.dump(2) << "\n").flush())
      throw std::runtime_error(manifestPath.string() + ": cannot write (disk full?)");
  }

  // 1. Voxels: the triangles binned per cell, the top in memory, cells spilled as they complete.
  auto phase = std::chrono::steady_clock::now();
  std::mutex mutex;
  std::size_t cellsDone = 0, cellCount = 1;
  std::uint64_t voxelsDone = 0;
  const auto cellDone = [&](std::uint64_t voxels) {  // under `mutex`
    ++cellsDone;
    voxelsDone += voxels;
    progress("voxelize", std::min(1.0, double(cellsDone) / double(cellCount)));
    if (ooc.cellProgress) ooc.cellProgress(cellsDone, cellCount, voxelsDone);
  };
  CellCallbacks callbacks;
  callbacks.progress = [&](const char* name, double f) {
    progress(name, f);
    if (f >= 1.0) report.phaseSeconds[name] = seconds(phase), phase = std::chrono::steady_clock::now();
  };
  callbacks.planned = [&](std::size_t count) { cellCount = std::max<std::size_t>(count, 1); };
  callbacks.finished = [&](glm::ivec3 cell) -> std::optional<CellRoot> {
    if (!reuse) return std::nullopt;
    const std::optional<CellFileHeader> h = readCellHeader(cellPath(work, cell), nullptr);
    if (!h) return std::nullopt;
    std::lock_guard lock(mutex);
    ++report.cellsReused;
    cellDone(h->recordCount);
    return rootOf(*h);
  };
  callbacks.built = [&](glm::ivec3 cell, VoxelTree&& tree, const CellRoot& root) {
    writeCell(cellPath(work, cell), tree, root);
    {
      std::lock_guard lock(mutex);
      cellDone(tree.voxels.size());
    }
    if (ooc.cellSpilled) ooc.cellSpilled(cell);
  };
  callbacks.builtElsewhere = [&](glm::ivec3, std::uint64_t voxels) {
    std::lock_guard lock(mutex);
    cellDone(voxels);
  };
  const VoxelTree top = voxelizeCells(source, transform, options, report.cellLevel, callbacks, runner,
                                      scratchOf(work), sharing);
  report.phaseSeconds["voxelize"] = seconds(phase);

  // 2. The store: the slices writeStore would make of the whole tree, the top's and every cell's, with the
  // slices spanning several cells assembled from their parts.
  phase = std::chrono::steady_clock::now();
  StoreWriteOptions writeOptions = write;
  writeOptions.progress = [&](double f) { progress("write", f); };
  StoreFileWriter writer(store, writeOptions);
  BuildStats& stats = report.stats;
  // The cells are loaded and planned on these threads, as many cells in flight.
  tbb::task_arena writing(ooc.writeThreads > 0 ? ooc.writeThreads : concurrency);
  writing.execute([&] { appendSpilledForest(writer, top, report.cellLevel, work, report); });
  writer.finish({transform, storedParameters(options), top.hasColors, top.hasNormals, top.voxels[0].color,
                 top.voxels[0].normal});
  report.phaseSeconds["write"] = seconds(phase);
  std::error_code ignored;
  std::filesystem::remove_all(work, ignored);
  stats.trianglesUsed = source.triangleCount();
  stats.seconds = seconds(start);
  return report;
}

}  // namespace svo
