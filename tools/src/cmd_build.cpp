// `svo build MESH -o out.svo --levels N`: mesh -> octree -> .svo, with progress and a size summary.

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <memory>
#include <optional>

#include <nlohmann/json.hpp>

#include <spdlog/spdlog.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include "commands.hpp"
#include "machine.hpp"
#include "measure.hpp"
#include "progress.hpp"
#include "svo/builder/build.hpp"
#include "text_file.hpp"

namespace svo::tools {
namespace {

struct BuildArgs {
  std::string mesh, out, report;
  BuildOptions options;
  bool noContours = false;
  int threads = 0;
  std::uint64_t sliceBytes = kDefaultSliceBytes;
  // Out of core (any of these): cells spilled to OUTPUT.build, bounded memory, resumable.
  std::uint64_t memory = 0;
  int cellLevel = 0;
  bool resume = false;
};

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

void runBuild(const BuildArgs& args) {
  checkWritableOutput(args.out);
  if (args.cellLevel >= args.options.levels)
    throw UsageError("--cell-level must be below --levels (" + std::to_string(args.options.levels) + ")");
  const std::filesystem::path reportPath = args.report.empty() ? args.out + ".build.json" : args.report;
  checkWritableOutput(reportPath);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              args.threads > 0 ? args.threads : tbb::info::default_concurrency());
  const auto start = std::chrono::steady_clock::now();
  const std::uint64_t processBytes = residentBytes();  // the program and its libraries, before any input
  nlohmann::json phases = nlohmann::json::object();

  auto phaseStart = std::chrono::steady_clock::now();
  const auto logInput = [&](std::uint64_t triangles, const std::string& format, std::size_t dropped) {
    spdlog::info("{}: {} triangles ({}){}", args.mesh, triangles, format,
                 dropped ? fmt::format(", dropped {} degenerate", dropped) : "");
  };
  BuildOptions options = args.options;
  options.contours = !args.noContours;
  BuildStats stats;
  StoreWriteOptions storeOptions;
  storeOptions.sliceBytes = std::uint32_t(args.sliceBytes);
  storeOptions.inheritance = options.layout;
  std::vector<SliceInfo> slices;
  // Both paths open the input as a source: binary PLY streams from the file, other formats load whole.
  std::unique_ptr<TriangleSource> source = openTriangleSource(args.mesh);
  phases["load"] = secondsSince(phaseStart);
  logInput(source->triangleCount(), source->format(), source->droppedDegenerate());
  const bool hasColors = source->hasColor();
  const std::uint64_t triangles = source->triangleCount();
  OutOfCoreOptions ooc;
  ooc.memoryBytes = args.memory;
  ooc.cellLevel = args.cellLevel;
  ooc.resume = args.resume;
  ooc.processBytes = processBytes;
  if (args.memory == 0 && args.cellLevel == 0) {
    // No bound given: in core when its estimated peak fits the machine's default share, else out of core
    // within that share. A resume is out of core (the interrupted run's cell level, or one for the share).
    const std::uint64_t share = defaultMemoryShare(machineMemory());
    const std::uint64_t estimate =
        args.resume ? 0 : processBytes + estimateInCoreBuildBytes(*source, options);
    if (args.resume || estimate > share) {
      ooc.memoryBytes = share;
      ooc.memoryOrigin = "the default memory bound (half of the available memory; --memory sets it)";
      if (!args.resume)
        spdlog::info(
            "building out of core within {}: in core would take about {}, more than half of the "
            "available memory (--memory sets the bound)",
            formatBytes(share), formatBytes(estimate));
    } else {
      spdlog::info("building in core: about {} of the {} default bound (half of the available memory)",
                   formatBytes(estimate), formatBytes(share));
    }
  }
  if (ooc.memoryBytes > 0 || ooc.cellLevel > 0) {
    ooc.threads = args.threads > 0 ? args.threads : tbb::info::default_concurrency();
    std::unique_ptr<ProgressBar> bar;
    std::string current;
    ooc.progress = [&](const char* phase, double f) {
      if (current != phase) bar = std::make_unique<ProgressBar>(current = phase);
      bar->update(f);
    };
    const OutOfCoreReport built = buildStore(*source, options, storeOptions, ooc, args.out);
    bar.reset();
    for (const auto& [phase, seconds] : built.phaseSeconds) phases[phase] = seconds;
    stats = built.stats;
    slices = built.slices;
    spdlog::info("out of core: {} cells of level {}, {} reused from an interrupted run", built.cells,
                 built.cellLevel, built.cellsReused);
  } else {
    // A streamed PLY source holds only its vertices: the in-core build loads the mesh whole.
    std::optional<Mesh> loaded;
    if (!source->wholeMesh()) {
      source.reset();
      phaseStart = std::chrono::steady_clock::now();
      loaded = loadMesh(args.mesh);
      phases["load"] = phases["load"].get<double>() + secondsSince(phaseStart);
    }
    const Mesh& mesh = loaded ? *loaded : *source->wholeMesh();
    phaseStart = std::chrono::steady_clock::now();
    const SceneTransform transform = fitSceneCube(mesh);
    VoxelTree tree;
    {
      ProgressBar bar("voxelize");
      options.progress = [&bar](double f) { bar.update(f); };
      tree = voxelize(mesh, transform, options, &stats);
    }
    phases["voxelize"] = secondsSince(phaseStart);

    phaseStart = std::chrono::steady_clock::now();
    {
      ProgressBar bar("write");
      storeOptions.progress = [&bar](double f) { bar.update(f); };
      slices = writeStore(args.out, tree, transform, storedParameters(options), storeOptions);
    }
    phases["write"] = secondsSince(phaseStart);
  }

  // The report: phases, voxels and slices per level, bytes per leaf voxel on disk and decoded by part.
  const std::uint64_t fileBytes = std::filesystem::file_size(args.out);
  const double leaves = double(std::max<std::uint64_t>(stats.leafVoxels, 1));
  std::vector<std::uint64_t> slicesPerLevel(stats.voxelsPerLevel.size(), 0);
  SliceParts parts;
  for (const SliceInfo& s : slices) {
    if (std::size_t(s.voxelLevel) < slicesPerLevel.size()) ++slicesPerLevel[s.voxelLevel];
    const SliceParts p = slicePartsOf(s, hasColors, true);
    parts.hierarchy += p.hierarchy, parts.contours += p.contours, parts.colors += p.colors,
        parts.normals += p.normals;
  }
  std::uint64_t voxels = 0;
  for (const std::uint64_t v : stats.voxelsPerLevel) voxels += v;
  nlohmann::json report;
  report["input"] = args.mesh;
  report["output"] = args.out;
  report["triangles"] = triangles;
  report["levels"] = options.levels;
  report["seconds"] = secondsSince(start);
  report["phaseSeconds"] = phases;
  report["peakResidentBytes"] = peakResidentBytes();
  report["voxels"] = voxels;
  report["leafVoxels"] = stats.leafVoxels;
  report["contours"] = stats.contours;
  report["voxelsPerLevel"] = stats.voxelsPerLevel;
  report["slices"] = slices.size();
  report["slicesPerLevel"] = slicesPerLevel;
  report["fileBytes"] = fileBytes;
  report["bytesPerLeafVoxel"] = {{"file", double(fileBytes) / leaves},
                                 {"decodedHierarchy", double(parts.hierarchy) / leaves},
                                 {"decodedContours", double(parts.contours) / leaves},
                                 {"decodedColors", double(parts.colors) / leaves},
                                 {"decodedNormals", double(parts.normals) / leaves}};
  writeTextFile(reportPath, report.dump(2) + "\n");

  spdlog::info("{} levels, {} voxels ({} leaves), {} contours; {} slices", options.levels, voxels,
               stats.leafVoxels, stats.contours, slices.size());
  std::string phaseTimes;
  for (const auto& [phase, seconds] : phases.items())
    phaseTimes += fmt::format("{}{} {:.2f} s", phaseTimes.empty() ? "" : ", ", phase, seconds.get<double>());
  spdlog::info("{}; peak resident {:.0f} MiB", phaseTimes, double(peakResidentBytes()) / (1 << 20));
  std::printf("wrote %s (%.1f MiB, %.2f B per leaf voxel) and %s\n", args.out.c_str(),
              double(fileBytes) / (1 << 20), double(fileBytes) / leaves, reportPath.c_str());
}

}  // namespace

void addBuildCommand(CLI::App& app) {
  auto args = std::make_shared<BuildArgs>();
  auto* cmd = app.add_subcommand(
      "build", "voxelize a mesh (OBJ, PLY, STL, glTF/GLB, DAE, FBX, DRC) into a .svo octree");
  cmd->add_option("mesh", args->mesh, "input mesh")->required();
  cmd->add_option("-o,--output", args->out, "output .svo file")->required();
  cmd->add_option("--levels", args->options.levels, "octree depth: finest voxels are 2^-levels of the scene")
      ->check(CLI::Range(1, kMaxLevels))
      ->capture_default_str();
  cmd->add_flag("--no-contours", args->noContours, "cube voxels only (no contour slabs)");
  cmd->add_option("--leaf-contour-min-reduction", args->options.leafContourMinReduction,
                  "store a finest voxel's contour only where it cuts more than this many voxels off the hull")
      ->check(CLI::Range(0.0, 2.0))
      ->capture_default_str();
  cmd->add_option("--inner-contour-min-reduction", args->options.innerContourMinReduction,
                  "the same for the voxels above the finest (their contours bound every voxel below)")
      ->check(CLI::Range(0.0, 2.0))
      ->capture_default_str();
  cmd->add_option("--geometry-error", args->options.geometryError,
                  "stop refining where the contour fits the surface within this many finest voxels (0 = off)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--color-error", args->options.colorError,
                  "with --geometry-error: also require colors within this many 8-bit steps (0 = not checked)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--normal-error", args->options.normalError,
                  "with --geometry-error: also require normals within this many degrees (0 = not checked)")
      ->check(CLI::Range(0.0, 180.0));
  cmd->add_option("--slice-size", args->sliceBytes,
                  "bytes a slice may hold before its cube splits into 8 (sec. 7; suffixes K, M)")
      ->transform(CLI::AsSizeValue(false))
      ->check(CLI::Range(std::uint64_t(256), std::uint64_t(1) << 30))
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "worker threads (0 = all cores)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--report", args->report, "JSON build report (default: OUTPUT.build.json)");
  cmd->add_option("--memory", args->memory,
                  "build out of core within about this much memory (e.g. 1G): cells spilled to OUTPUT.build, "
                  "a cell level chosen to fit (default: in core when the estimate fits half of the available "
                  "memory, else out of core within that half)")
      ->transform(CLI::AsSizeValue(false));
  cmd->add_option("--cell-level", args->cellLevel,
                  "build out of core with cells of this level (instead of choosing one from --memory)")
      ->check(CLI::Range(1, kMaxLevels - 1));
  cmd->add_flag("--resume", args->resume,
                "out of core: keep the cells an interrupted build of the same input and options left in "
                "OUTPUT.build");
  cmd->callback([args] { runBuild(*args); });
}

}  // namespace svo::tools
