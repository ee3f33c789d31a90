// `svo bench build MESH`: in-core octree build time against OpenVDB's mesh to level set conversion at the
// same resolutions, same triangles, all threads, measured in the same run. OpenVDB stays in this file only:
// its headers make a translation unit take ~30 s and ~1.2 GB to compile.
#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <numeric>
#include <optional>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <unistd.h>

#ifdef SVO_BENCH_PEERS
#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>

#include "vdb_peer.hpp"
#endif

#include "bench_common.hpp"
#include "svo/builder/build.hpp"

namespace svo::tools::bench {

namespace {

struct BuildArgs {
  std::string mesh;
  std::string resolutions = "256,512,1024";
  std::vector<int> threads{1, 2};
  int runs = 3;
  std::vector<int> ranks;  // with it: only the MPI comparison
  int cellLevel = 0;
};

#ifdef SVO_BENCH_PEERS
LevelSetResult runOpenVdb(const VdbMesh& mesh, double voxelSize, int runs) {
  const openvdb::math::Transform::Ptr transform = openvdb::math::Transform::createLinearTransform(voxelSize);
  LevelSetResult result;
  std::vector<double> samples;
  for (int i = 0; i < runs; ++i) {
    openvdb::FloatGrid::Ptr grid;
    samples.push_back(timeSeconds([&] {
      grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(*transform, mesh.points, mesh.triangles,
                                                                kLevelSetHalfWidth);
    }));
    result.activeVoxels = grid->activeVoxelCount();
    result.memoryBytes = grid->memUsage();
  }
  result.seconds = summarize(std::move(samples));
  return result;
}
#endif

std::string megabytes(std::uint64_t bytes) {
  return fmt::format("{:.1f}", double(bytes) / (1 << 20));
}

// Cell level of the out-of-core column (and the MPI comparison's default): 8^3 cells, enough to spread over
// any thread or rank count measured here.
constexpr int kBenchCellLevel = 3;

std::string rate(double count, double seconds) {
  return fmt::format("{:.2f}", count / seconds / 1e6);
}

void runBuildBench(const BuildArgs& args) {
  const std::vector<std::int64_t> resolutions = parseResolutions(args.resolutions, "--resolutions");
  requireRuns(args.runs);
  if (!args.ranks.empty()) {
    MpiBuildBenchArgs mpi;
    mpi.mesh = args.mesh;
    mpi.levels = levelsOfResolution(*std::max_element(resolutions.begin(), resolutions.end()), "--resolutions");
    mpi.cellLevel = args.cellLevel > 0 ? args.cellLevel : std::min(kBenchCellLevel, mpi.levels - 1);
    if (mpi.cellLevel >= mpi.levels)
      throw UsageError("--cell-level must be below the levels of the finest resolution (" +
                       std::to_string(mpi.levels) + ")");
    mpi.runs = args.runs;
    mpi.ranks = args.ranks;
    runMpiBuildBench(mpi);
    return;
  }
  std::vector<int> threadCounts;
  for (const int t : args.threads) threadCounts.push_back(resolveThreads(t));
  const Mesh mesh = loadBenchMesh(args.mesh);
  const SceneTransform scene = fitSceneCube(mesh);
  // The out-of-core build reads the file itself, streamed when it is binary PLY.
  const std::unique_ptr<TriangleSource> source = openTriangleSource(args.mesh);
  const ScratchPath scratchStore("svo-bench-build.svo");
  const std::filesystem::path& scratch = scratchStore.path();

  Table table({"resolution", "threads", "ESVO time", "OOC time", "VDB time", "ESVO Mtri/s", "ESVO Mvox/s",
               "OOC Mvox/s", "ESVO leaves", "ESVO voxels", "ESVO MB", "VDB active", "VDB MB", "ESVO/VDB",
               "OOC/VDB"});
  for (const std::int64_t resolution : resolutions) {
    const int levels = levelsOfResolution(resolution, "--resolutions");
    BuildOptions options;
    options.levels = levels;
    options.contours = true;
    for (const int threads : threadCounts) {
      const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(threads));
      BuildStats stats;
      std::uint64_t blockBytes = 0;
      std::vector<double> samples;
      spdlog::info("{}^3, {} threads: ESVO buildOctree, {} runs ...", resolution, threads, args.runs);
      for (int i = 0; i < args.runs; ++i) {
        Octree octree;
        stats = {};
        samples.push_back(timeSeconds([&] { octree = buildOctree(mesh, options, &stats); }));
        blockBytes = octree.block.bytes().size();
      }
      const Summary esvo = summarize(std::move(samples));
      const double voxels =
          double(std::accumulate(stats.voxelsPerLevel.begin(), stats.voxelsPerLevel.end(), std::uint64_t(0)));

      std::optional<Summary> outOfCore;
      if (levels > 1) {
        spdlog::info("{}^3, {} threads: ESVO out-of-core buildStore, {} runs ...", resolution, threads,
                     args.runs);
        OutOfCoreOptions ooc;
        ooc.cellLevel = std::min(kBenchCellLevel, levels - 1);
        ooc.threads = threads;
        std::vector<double> oocSamples;
        for (int i = 0; i < args.runs; ++i)
          oocSamples.push_back(timeSeconds([&] { buildStore(*source, options, {}, ooc, scratch); }));
        std::filesystem::remove(scratch);
        outOfCore = summarize(std::move(oocSamples));
      }

      spdlog::info("{}^3, {} threads: OpenVDB meshToLevelSet, {} runs ...", resolution, threads, args.runs);
      const std::optional<LevelSetResult> peer =
          openVdbLevelSet(mesh, scene.origin, scene.size / double(resolution), args.runs);
      // Without the peer its columns show a dash and the ratio says why.
      const std::string none = "-";
      table.addRow(
          {fmt::format("{}^3", resolution), std::to_string(threads), formatSeconds(esvo.median),
           outOfCore ? formatSeconds(outOfCore->median) : none,
           peer ? formatSeconds(peer->seconds.median) : none,
           rate(double(mesh.triangles.size()), esvo.median), rate(voxels, esvo.median),
           outOfCore ? rate(voxels, outOfCore->median) : none, formatCount(stats.leafVoxels),
           formatCount(std::uint64_t(voxels)), megabytes(blockBytes),
           peer ? formatCount(peer->activeVoxels) : none, peer ? megabytes(peer->memoryBytes) : none,
           peer ? fmt::format("{:.2f}x", esvo.median / peer->seconds.median) : std::string(kPeerNotBuilt),
           peer && outOfCore ? fmt::format("{:.2f}x", outOfCore->median / peer->seconds.median) : none});
    }
  }

  printTitle("Building: ESVO octree (in core and out of core) vs OpenVDB level set, same triangles");
  fmt::print("{}: {} triangles; scene cube {:.4g}; median of {} runs\n", args.mesh,
             formatCount(mesh.triangles.size()), scene.size, args.runs);
  table.print();
  fmt::print(
      "ESVO: svo::buildOctree (voxelize with contours, colors, normals + block layout), levels = log2 "
      "resolution;\n  leaves = leaf voxels, voxels = voxels of all levels, MB = block bytes; Mtri/s and "
      "Mvox/s = triangles and voxels (all levels) per second.\n"
      "OOC: svo::buildStore, the out-of-core build from the file ({}) with cell level {}, spilled cells and "
      "a "
      "store written to {};\n  the same octree as ESVO's, plus zstd store writing.\n"
      "VDB: OpenVDB tools::meshToLevelSet<FloatGrid>, voxel size = scene cube / resolution, half width "
      "{:.0f} voxels;\n  active = active voxels of the narrow band, MB = Grid::memUsage.\n"
      "threads: oneTBB's limit for all three (the out-of-core build also builds that many cells at once).\n"
      "ESVO/VDB, OOC/VDB: ratios of median times (< 1: ESVO faster).\n",
      source->format(), kBenchCellLevel, scratch.parent_path().string(), kLevelSetHalfWidth);
}

}  // namespace

std::optional<LevelSetResult> openVdbLevelSet(const Mesh& mesh, glm::dvec3 corner, double voxelSize,
                                              int runs) {
#ifdef SVO_BENCH_PEERS
  openvdb::initialize();
  return runOpenVdb(toVdbMesh(mesh, corner), voxelSize, runs);
#else
  return std::nullopt;
#endif
}

void addBuildBench(CLI::App& bench) {
  auto args = std::make_shared<BuildArgs>();
  CLI::App* cmd =
      bench.add_subcommand("build", "ESVO octree build vs OpenVDB meshToLevelSet at the same resolutions");
  cmd->add_option("mesh", args->mesh, "triangle mesh (OBJ, PLY, STL, glTF, ...)")->required();
  cmd->add_option("--resolutions", args->resolutions, "comma-separated powers of two (voxels per cube edge)")
      ->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per method; the median is reported")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "thread counts, e.g. 1,2 (0 = all cores)")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--ranks", args->ranks,
                  "instead: the out-of-core build under mpirun with these rank counts (e.g. 1,2), one thread "
                  "a rank, against one plain process, at the finest resolution")
      ->delimiter(',')
      ->check(CLI::PositiveNumber);
  cmd->add_option("--cell-level", args->cellLevel, "with --ranks: the cell level (default 3)")
      ->check(CLI::PositiveNumber);
  cmd->callback([args] { runBuildBench(*args); });
}

}  // namespace svo::tools::bench
