// `svo build MESH -o out.svo --levels N`: mesh (or point cloud, or OpenVDB volume) -> octree -> .svo, with
// progress and a size summary.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
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
#include "number_checks.hpp"
#include "progress.hpp"
#include "report.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/points.hpp"
#include "svo/builder/volume.hpp"
#include "text_file.hpp"
#ifdef SVO_MPI
#include "svo/builder/mpi_build.hpp"
#endif

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
  VolumeImportOptions volume;  // a .vdb input
  bool volumeViaMesh = false;  // a level set or fog volume meshed (volumeToMesh) and voxelized as a mesh
  bool levelsGiven = false;    // --levels on the command line (a voxel mask brings its own)
};

double secondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// What the store was built from and how: the build's statistics, its slices, seconds per phase.
struct BuildOutcome {
  BuildStats stats;
  std::vector<SliceInfo> slices;
  nlohmann::json phases = nlohmann::json::object();
  nlohmann::json ranks;  // an MPI job's, by rank
};

// The ranks of the MPI job that started this process (mpirun, or srun with PMI), 0 outside one.
int mpiLaunchedRanks() {
  for (const char* variable : {"OMPI_COMM_WORLD_SIZE", "PMIX_SIZE", "PMI_SIZE"})
    if (const char* value = std::getenv(variable); value && *value) return std::max(1, std::atoi(value));
  return std::getenv("PMIX_RANK") ? 1 : 0;
}

// The out-of-core options as the command line gives them.
OutOfCoreOptions givenOutOfCoreOptions(const BuildArgs& args, std::uint64_t processBytes) {
  OutOfCoreOptions ooc;
  ooc.memoryBytes = args.memory;
  ooc.cellLevel = args.cellLevel;
  ooc.resume = args.resume;
  ooc.processBytes = processBytes;
  ooc.threads = args.threads > 0 ? args.threads : tbb::info::default_concurrency();
  return ooc;
}

// What the out-of-core build calls a bound the command line did not give.
constexpr const char* kDefaultMemoryOrigin =
    "the default memory bound (half of the available memory; --memory sets it)";

// Says in one line how a build with no bound given runs, from its in-core estimate and the default share.
void sayMemoryChoice(bool outOfCore, std::uint64_t estimate, std::uint64_t share) {
  if (outOfCore)
    spdlog::info(
        "building out of core within {}: in core would take about {}, more than half of the available "
        "memory (--memory sets the bound)",
        formatBytes(share), formatBytes(estimate));
  else
    spdlog::info("building in core: about {} of the {} default bound (half of the available memory)",
                 formatBytes(estimate), formatBytes(share));
}

// The out-of-core options the command line asks for. With no bound given: in core when its estimated peak
// fits the machine's default share, else out of core within that share. A resume, and an MPI job, is out
// of core (the interrupted run's cell level, or one for the share).
OutOfCoreOptions outOfCoreOptions(const BuildArgs& args, const TriangleSource& source,
                                  const BuildOptions& options, std::uint64_t processBytes,
                                  bool outOfCore = false) {
  OutOfCoreOptions ooc = givenOutOfCoreOptions(args, processBytes);
  if (args.memory != 0 || args.cellLevel != 0) return ooc;
  const std::uint64_t share = defaultMemoryShare(machineMemory());
  const bool chosen = args.resume || outOfCore;
  const std::uint64_t estimate = chosen ? 0 : processBytes + estimateInCoreBuildBytes(source, options);
  if (chosen || estimate > share) {
    ooc.memoryBytes = share;
    ooc.memoryOrigin = kDefaultMemoryOrigin;
  }
  if (!chosen) sayMemoryChoice(estimate > share, estimate, share);
  return ooc;
}

// The out-of-core build with one progress bar (cells done and their voxels while they are built), by
// `build` (buildStore, or an MPI job's rank 0).
void buildOutOfCore(OutOfCoreOptions ooc, BuildOutcome& outcome,
                    const std::function<OutOfCoreReport(const OutOfCoreOptions&)>& build) {
  std::unique_ptr<ProgressBar> bar;
  std::string current;
  ooc.progress = [&](const char* phase, double f) {
    if (current != phase) bar = std::make_unique<ProgressBar>(current = phase);
    bar->update(f);
  };
  ooc.cellProgress = [&](std::size_t done, std::size_t cells, std::uint64_t voxels) {
    if (bar) bar->setDetail(fmt::format("{}/{} cells, {} voxels", done, cells, formatCount(voxels)));
  };
  const OutOfCoreReport built = build(ooc);
  bar.reset();
  for (const auto& [phase, seconds] : built.phaseSeconds) outcome.phases[phase] = seconds;
  outcome.stats = built.stats;
  outcome.slices = built.slices;
  spdlog::info("out of core: {} cells of level {}, {} reused from an interrupted run", built.cells,
               built.cellLevel, built.cellsReused);
}

void buildInCore(const BuildArgs& args, std::unique_ptr<TriangleSource> source, BuildOptions options,
                 StoreWriteOptions storeOptions, BuildOutcome& outcome) {
  // A streamed PLY source holds only its vertices: the in-core build loads the mesh whole.
  std::optional<Mesh> loaded;
  auto phaseStart = std::chrono::steady_clock::now();
  if (!source->wholeMesh()) {
    source.reset();
    loaded = loadMesh(args.mesh);
    outcome.phases["load"] = outcome.phases["load"].get<double>() + secondsSince(phaseStart);
  }
  const Mesh& mesh = loaded ? *loaded : *source->wholeMesh();
  phaseStart = std::chrono::steady_clock::now();
  const SceneTransform transform = fitSceneCube(mesh);
  VoxelTree tree;
  {
    ProgressBar bar("voxelize");
    options.progress = [&bar](double f) { bar.update(f); };
    tree = voxelize(mesh, transform, options, &outcome.stats);
  }
  outcome.phases["voxelize"] = secondsSince(phaseStart);
  phaseStart = std::chrono::steady_clock::now();
  {
    ProgressBar bar("write");
    storeOptions.progress = [&bar](double f) { bar.update(f); };
    outcome.slices = writeStore(args.out, tree, transform, storedParameters(options), storeOptions);
  }
  outcome.phases["write"] = secondsSince(phaseStart);
}

// A voxel mask (.vdb) laid out voxel for voxel: its own depth, no contours. Returns whether it has colors.
bool buildFromVoxels(const BuildArgs& args, StoreWriteOptions storeOptions, BuildOutcome& outcome) {
  auto phaseStart = std::chrono::steady_clock::now();
  const VoxelVolume volume = loadVolumeVoxels(args.mesh, args.volume);
  outcome.phases["load"] = secondsSince(phaseStart);
  if (args.levelsGiven && volume.parameters.levels != args.options.levels)
    throw UsageError(
        fmt::format("{}: the voxel mask's voxels make {} levels, not --levels {} (masks are not "
                    "resampled)",
                    args.mesh, volume.parameters.levels, args.options.levels));
  spdlog::info("{}: {} voxels of level {} (a voxel mask)", args.mesh, volume.leafVoxels,
               volume.parameters.levels);
  addTreeStats(volume.tree, 0, outcome.stats);
  // The grid's values as they are: a child inherits only a value equal to its parent's.
  storeOptions.inheritance.inheritEqualOnly = true;
  phaseStart = std::chrono::steady_clock::now();
  {
    ProgressBar bar("write");
    storeOptions.progress = [&bar](double f) { bar.update(f); };
    outcome.slices = writeStore(args.out, volume.tree, volume.transform, volume.parameters, storeOptions);
  }
  outcome.phases["write"] = secondsSince(phaseStart);
  return volume.tree.hasColors;
}

// A scan's depth: --levels, checked against the points' spacing (a warning where its finest voxels are too
// small for the points to cover), or else the level the spacing fits.
int levelsForScan(const BuildArgs& args, double spacing, const SceneTransform& transform) {
  const int levels = args.options.levels, fits = levelsForSpacing(spacing, transform);
  const auto voxelAt = [&](int level) { return std::ldexp(transform.size, -level); };
  if (!args.levelsGiven) {
    spdlog::info("{}: the points lie {:.3g} apart: {} levels (finest voxel {:.3g}, at least {} spacings)",
                 args.mesh, spacing, fits, voxelAt(fits), kVoxelsPerSpacing);
    return fits;
  }
  if (levels > fits)
    spdlog::warn(
        "{}: the points lie {:.3g} apart, too sparse for the finest voxel ({:.3g}) of --levels {}: the "
        "surface will have holes; --levels {} fits (a voxel of at least {} spacings)",
        args.mesh, spacing, voxelAt(levels), levels, fits, kVoxelsPerSpacing);
  return levels;
}

// A level set or fog volume voxelized from its field, in core. Returns whether it has colors.
bool buildFromVolumeSurface(const BuildArgs& args, BuildOptions options, StoreWriteOptions storeOptions,
                            BuildOutcome& outcome) {
  auto phaseStart = std::chrono::steady_clock::now();
  SurfaceVolume volume;
  {
    ProgressBar bar("voxelize");
    options.progress = [&bar](double f) { bar.update(f); };
    volume = voxelizeVolumeSurface(args.mesh, args.volume, options, &outcome.stats);
  }
  outcome.phases["voxelize"] = secondsSince(phaseStart);
  spdlog::info("{}: {} finest voxels on the surface", args.mesh, outcome.stats.leafVoxels);
  phaseStart = std::chrono::steady_clock::now();
  {
    ProgressBar bar("write");
    storeOptions.progress = [&bar](double f) { bar.update(f); };
    outcome.slices =
        writeStore(args.out, volume.tree, volume.transform, storedParameters(options), storeOptions);
  }
  outcome.phases["write"] = secondsSince(phaseStart);
  return volume.tree.hasColors;
}

// A point cloud (scan): normals estimated where the file has none, each point in a finest voxel, contours
// fitted to each voxel's points. Returns whether it has colors.
bool buildFromPoints(const BuildArgs& args, BuildOptions options, StoreWriteOptions storeOptions,
                     BuildOutcome& outcome) {
  auto phaseStart = std::chrono::steady_clock::now();
  PointCloud cloud = loadPointCloud(args.mesh);
  outcome.phases["load"] = secondsSince(phaseStart);
  SceneTransform transform;
  try {
    transform = fitSceneCube(cloud);
  } catch (const std::runtime_error& e) {
    throw std::runtime_error(args.mesh + ": " + e.what());
  }
  spdlog::info("{}: {} points ({}{}{})", args.mesh, cloud.positions.size(), cloud.format,
               cloud.normals.empty() ? "" : ", normals", cloud.colors.empty() ? "" : ", colors");
  if (cloud.missing > 0)
    spdlog::warn(
        "{}: the file ends inside point {} of the {} its header declares; building from the {} "
        "before",
        args.mesh, cloud.positions.size(), cloud.positions.size() + cloud.missing, cloud.positions.size());
  options.levels = levelsForScan(args, estimatePointSpacing(cloud), transform);
  phaseStart = std::chrono::steady_clock::now();
  const NormalEstimate normals = estimateNormals(cloud);
  if (normals.estimated > 0) {
    outcome.phases["normals"] = secondsSince(phaseStart);
    spdlog::info("estimated {} normals ({} nearest neighbours), oriented from {} seeds", normals.estimated,
                 kNormalNeighbours, normals.components);
  }
  phaseStart = std::chrono::steady_clock::now();
  VoxelTree tree;
  {
    ProgressBar bar("voxelize");
    options.progress = [&bar](double f) { bar.update(f); };
    tree = voxelizePoints(cloud, transform, options, &outcome.stats);
  }
  outcome.phases["voxelize"] = secondsSince(phaseStart);
  cloud = PointCloud();  // the store's writing needs the tree only
  phaseStart = std::chrono::steady_clock::now();
  {
    ProgressBar bar("write");
    storeOptions.progress = [&bar](double f) { bar.update(f); };
    outcome.slices = writeStore(args.out, tree, transform, storedParameters(options), storeOptions);
  }
  outcome.phases["write"] = secondsSince(phaseStart);
  return tree.hasColors;
}

// The report: phases, voxels and slices per level, bytes per leaf voxel on disk and decoded by part; and
// its summary on the terminal.
void writeBuildReport(const BuildArgs& args, const std::filesystem::path& reportPath, std::uint64_t triangles,
                      bool hasColors, int levels, double seconds, const BuildOutcome& outcome) {
  const BuildStats& stats = outcome.stats;
  const std::uint64_t fileBytes = std::filesystem::file_size(args.out);
  const double leaves = double(std::max<std::uint64_t>(stats.leafVoxels, 1));
  std::vector<std::uint64_t> slicesPerLevel(stats.voxelsPerLevel.size(), 0);
  SliceParts parts;
  for (const SliceInfo& s : outcome.slices) {
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
  report["levels"] = levels;
  report["seconds"] = seconds;
  report["phaseSeconds"] = outcome.phases;
  if (!outcome.ranks.is_null()) report["ranks"] = outcome.ranks;
  report["peakResidentBytes"] = peakResidentBytes();
  report["voxels"] = voxels;
  report["leafVoxels"] = stats.leafVoxels;
  report["contours"] = stats.contours;
  report["voxelsPerLevel"] = stats.voxelsPerLevel;
  report["slices"] = outcome.slices.size();
  report["slicesPerLevel"] = slicesPerLevel;
  report["fileBytes"] = fileBytes;
  report["bytesPerLeafVoxel"] = {{"file", double(fileBytes) / leaves},
                                 {"decodedHierarchy", double(parts.hierarchy) / leaves},
                                 {"decodedContours", double(parts.contours) / leaves},
                                 {"decodedColors", double(parts.colors) / leaves},
                                 {"decodedNormals", double(parts.normals) / leaves}};
  writeTextFile(reportPath, report.dump(2) + "\n");

  spdlog::info("{} levels, {} voxels ({} leaves), {} contours; {} slices", levels, voxels, stats.leafVoxels,
               stats.contours, outcome.slices.size());
  std::string phaseTimes;
  for (const auto& [phase, phaseSeconds] : outcome.phases.items())
    phaseTimes +=
        fmt::format("{}{} {:.2f} s", phaseTimes.empty() ? "" : ", ", phase, phaseSeconds.get<double>());
  spdlog::info("{}; peak resident {:.0f} MiB", phaseTimes, double(peakResidentBytes()) / (1 << 20));
  std::printf("wrote %s (%.1f MiB, %.2f B per leaf voxel) and %s\n", args.out.c_str(),
              double(fileBytes) / (1 << 20), double(fileBytes) / leaves, reportPath.c_str());
}

// Whether the input is a .vdb voxel mask, which is laid out voxel for voxel rather than voxelized.
bool isVoxelMask(const BuildArgs& args) {
  return isVolumeFile(args.mesh) && chooseVolumeGrid(args.mesh, args.volume).kind == VolumeGridKind::Voxels;
}

// The input as triangles: binary PLY streams from the file, other formats load whole; a level set or fog
// volume is meshed first (into `volumeSurface`, which the source refers to).
std::unique_ptr<TriangleSource> openInput(const BuildArgs& args, std::optional<Mesh>& volumeSurface) {
  if (!isVolumeFile(args.mesh)) return openTriangleSource(args.mesh);
  volumeSurface = loadVolumeSurface(args.mesh, args.volume);
  return meshTriangleSource(*volumeSurface, "meshed volume");
}

// What every build checks and derives from its command line before it opens the input.
struct BuildSetup {
  std::filesystem::path reportPath;
  BuildOptions options;
  StoreWriteOptions storeOptions;
};

BuildSetup setUpBuild(const BuildArgs& args) {
  checkWritableOutput(args.out);
  if (args.cellLevel >= args.options.levels && (args.levelsGiven || !isPointCloudFile(args.mesh)))
    throw UsageError("--cell-level must be below --levels (" + std::to_string(args.options.levels) + ")");
  BuildSetup setup;
  setup.reportPath = args.report.empty() ? args.out + ".build.json" : args.report;
  checkWritableOutput(setup.reportPath);
  setup.options = args.options;
  setup.options.contours = !args.noContours;
  setup.storeOptions.sliceBytes = std::uint32_t(args.sliceBytes);
  setup.storeOptions.inheritance = setup.options.layout;
  return setup;
}

// A scan's --levels, refused before any pass reads the file.
void checkScanLevels(const BuildArgs& args) {
  const int levels = args.options.levels;
  if (args.levelsGiven && (levels < kMinPointLevels || levels > kMaxPointLevels))
    throw UsageError(fmt::format("--levels {}: point clouds build {} to {} levels", levels, kMinPointLevels,
                                 kMaxPointLevels));
}

// A scan's out-of-core options: as given, or with none given (or --resume alone) within the default share;
// nullopt (in core) where no bound is given and the in-core build's estimated peak fits that share.
std::optional<OutOfCoreOptions> scanOutOfCoreOptions(const BuildArgs& args, std::uint64_t processBytes) {
  OutOfCoreOptions ooc = givenOutOfCoreOptions(args, processBytes);
  if (args.memory != 0 || args.cellLevel != 0) return ooc;
  const std::uint64_t share = defaultMemoryShare(machineMemory());
  if (!args.resume) {
    const PointBuildPlan plan = planPointBuild(surveyPointFile(args.mesh).points, processBytes, share);
    sayMemoryChoice(plan.outOfCore, plan.inCoreBytes, share);
    if (!plan.outOfCore) return std::nullopt;
  }
  ooc.memoryBytes = share;
  ooc.memoryOrigin = kDefaultMemoryOrigin;
  return ooc;
}

// A scan out of core: streamed from the file, never held whole. Returns the depth built and whether it has
// colors.
std::pair<int, bool> buildPointsOutOfCore(const BuildArgs& args, const BuildSetup& setup,
                                          const OutOfCoreOptions& ooc, BuildOutcome& outcome) {
  PointStoreReport built;
  buildOutOfCore(ooc, outcome, [&](const OutOfCoreOptions& o) {
    built = buildPointStore(args.mesh, setup.options, setup.storeOptions, o, args.out,
                            [&](double spacing, const SceneTransform& transform) {
                              return levelsForScan(args, spacing, transform);
                            });
    return built.build;
  });
  spdlog::info("{}: {} points ({}{}{}), {} normals estimated", args.mesh, built.file.points,
               built.file.format, built.file.normals ? ", normals" : "", built.file.colors ? ", colors" : "",
               built.normalsEstimated);
  if (built.file.missing > 0)
    spdlog::warn("{}: the file ends inside point {} of the {} its header declares; built from the {} before",
                 args.mesh, built.file.points, built.file.points + built.file.missing, built.file.points);
  return {built.levels, built.file.colors};
}

void logInput(const std::string& mesh, const TriangleSource& source) {
  const std::size_t dropped = source.droppedDegenerate();
  spdlog::info("{}: {} triangles ({}){}", mesh, source.triangleCount(), source.format(),
               dropped ? fmt::format(", dropped {} degenerate", dropped) : "");
}

#ifdef SVO_MPI
// One rank of `mpirun -n N svo build`: every rank opens the input, MpiJob::build checks that they agree
// and shares the cells out, rank 0 writes the store and the report. Only rank 0 prints.
void runMpiBuild(const BuildArgs& args) {
  MpiJob job;
  const bool root = job.rank() == 0;
  if (!root) spdlog::set_level(spdlog::level::warn);
  // Rank 0 writes the store on the cores of the ranks beside it as well (its cell builders keep to
  // --threads, MpiJob::build).
  const int cellThreads = args.threads > 0 ? args.threads : tbb::info::default_concurrency();
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              root ? std::max(cellThreads, tbb::info::default_concurrency()) : cellThreads);
  const auto start = std::chrono::steady_clock::now();
  const std::uint64_t processBytes = residentBytes();  // the program, its libraries and MPI
  // A rank that cannot start says so to rank 0 (MpiJob::build), which reports it for the job.
  BuildSetup setup;
  std::optional<Mesh> volumeSurface;
  std::unique_ptr<TriangleSource> source;
  OutOfCoreOptions ooc;
  std::string openError;
  BuildOutcome outcome;
  try {
    setup = setUpBuild(args);
    if (isVoxelMask(args))
      throw UsageError(args.mesh + ": a voxel mask is laid out voxel for voxel in one process, not over MPI");
    if (isPointCloudFile(args.mesh))
      throw UsageError(args.mesh + ": a point cloud builds in core in one process, not over MPI");
    source = openInput(args, volumeSurface);
    outcome.phases["load"] = secondsSince(start);
    if (root) logInput(args.mesh, *source);
    ooc = outOfCoreOptions(args, *source, setup.options, processBytes, true);
  } catch (const std::exception& e) {
    source.reset();
    openError = e.what();
  }
  try {
    if (!root) {
      job.build(source.get(), openError, setup.options, setup.storeOptions, ooc, args.out);
      return;
    }
    spdlog::info("MPI: {} ranks, rank 0 on {}", job.size(), job.host());
    buildOutOfCore(ooc, outcome, [&](const OutOfCoreOptions& o) {
      std::optional<MpiBuildReport> built =
          job.build(source.get(), openError, setup.options, setup.storeOptions, o, args.out);
      for (const RankReport& r : built->ranks) {
        outcome.ranks.push_back({{"rank", r.rank},
                                 {"host", r.host},
                                 {"cells", r.cells},
                                 {"buildSeconds", r.buildSeconds},
                                 {"peakResidentBytes", r.peakResidentBytes}});
        spdlog::info("rank {} on {}: {} cells in {:.2f} s, peak resident {}", r.rank, r.host, r.cells,
                     r.buildSeconds, formatBytes(r.peakResidentBytes));
      }
      return std::move(built->build);
    });
  } catch (const MpiJobFailed& e) {
    throw FailureReportedElsewhere(e.what());
  }
  writeBuildReport(args, setup.reportPath, source->triangleCount(), source->hasColor(), setup.options.levels,
                   secondsSince(start), outcome);
}
#endif

void runBuild(const BuildArgs& args) {
  if (mpiLaunchedRanks() > 0) {
#ifdef SVO_MPI
    runMpiBuild(args);
    return;
#else
    if (mpiLaunchedRanks() > 1)
      throw UsageError(
          "this svo is built without MPI (Open MPI was absent, or -DSVO_MPI=OFF): under mpirun every rank "
          "would build the whole store; run one process, or build svo with Open MPI");
#endif
  }
  const BuildSetup setup = setUpBuild(args);
  tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                              args.threads > 0 ? args.threads : tbb::info::default_concurrency());
  const auto start = std::chrono::steady_clock::now();
  const std::uint64_t processBytes = residentBytes();  // the program and its libraries, before any input
  BuildOutcome outcome;
  if (isPointCloudFile(args.mesh)) {
    checkScanLevels(args);
    if (const std::optional<OutOfCoreOptions> ooc = scanOutOfCoreOptions(args, processBytes)) {
      const auto [levels, hasColors] = buildPointsOutOfCore(args, setup, *ooc, outcome);
      writeBuildReport(args, setup.reportPath, 0, hasColors, levels, secondsSince(start), outcome);
      return;
    }
    const bool hasColors = buildFromPoints(args, setup.options, setup.storeOptions, outcome);
    writeBuildReport(args, setup.reportPath, 0, hasColors, int(outcome.stats.voxelsPerLevel.size()) - 1,
                     secondsSince(start), outcome);
    return;
  }
  if (isVoxelMask(args)) {
    const bool hasColors = buildFromVoxels(args, setup.storeOptions, outcome);
    writeBuildReport(args, setup.reportPath, 0, hasColors, int(outcome.stats.voxelsPerLevel.size()) - 1,
                     secondsSince(start), outcome);
    return;
  }
  // A level set or fog volume in core, without an error-driven stop: voxelized from its field.
  const bool outOfCore = args.memory != 0 || args.cellLevel != 0 || args.resume;
  const BuildOptions& given = setup.options;
  const bool errorDriven = given.geometryError > 0.0f || given.colorError > 0.0f || given.normalError > 0.0f;
  if (isVolumeFile(args.mesh) && !args.volumeViaMesh && !outOfCore && !errorDriven) {
    const bool hasColors = buildFromVolumeSurface(args, setup.options, setup.storeOptions, outcome);
    writeBuildReport(args, setup.reportPath, 0, hasColors, setup.options.levels, secondsSince(start),
                     outcome);
    return;
  }
  std::optional<Mesh> volumeSurface;
  std::unique_ptr<TriangleSource> source = openInput(args, volumeSurface);
  outcome.phases["load"] = secondsSince(start);
  logInput(args.mesh, *source);
  const bool hasColors = source->hasColor();
  const std::uint64_t triangles = source->triangleCount();
  const OutOfCoreOptions ooc = outOfCoreOptions(args, *source, setup.options, processBytes);
  if (ooc.memoryBytes > 0 || ooc.cellLevel > 0)
    buildOutOfCore(ooc, outcome, [&](const OutOfCoreOptions& o) {
      return buildStore(*source, setup.options, setup.storeOptions, o, args.out);
    });
  else
    buildInCore(args, std::move(source), setup.options, setup.storeOptions, outcome);
  writeBuildReport(args, setup.reportPath, triangles, hasColors, setup.options.levels, secondsSince(start),
                   outcome);
}

}  // namespace

void addBuildCommand(CLI::App& app) {
  auto args = std::make_shared<BuildArgs>();
  auto* cmd = app.add_subcommand("build",
                                 "voxelize a mesh (OBJ, PLY, STL, glTF/GLB, DAE, FBX, DRC), a point cloud "
                                 "(PLY or DRC without faces, .xyz) or an OpenVDB volume (.vdb) into a .svo "
                                 "octree");
  cmd->add_option("mesh", args->mesh,
                  "input mesh, point cloud (a PLY or DRC without faces: normals estimated where missing; "
                  ".xyz lines: x y z [r g b] [nx ny nz]) or OpenVDB volume (.vdb)")
      ->required();
  cmd->add_option("-o,--output", args->out, "output .svo file")->required();
  cmd->add_option("--levels", args->options.levels,
                  "octree depth: finest voxels are 2^-levels of the scene (a scan without it: the depth its "
                  "point spacing fits)")
      ->check(CLI::Range(1, kMaxLevels))
      ->capture_default_str();
  cmd->add_flag("--no-contours", args->noContours, "cube voxels only (no contour slabs)");
  cmd->add_option("--leaf-contour-min-reduction", args->options.leafContourMinReduction,
                  "store a finest voxel's contour only where it cuts more than this many voxels off the hull")
      ->check(finiteRange(0.0, 2.0))
      ->capture_default_str();
  cmd->add_option("--inner-contour-min-reduction", args->options.innerContourMinReduction,
                  "the same for the voxels above the finest (their contours bound every voxel below)")
      ->check(finiteRange(0.0, 2.0))
      ->capture_default_str();
  cmd->add_option("--geometry-error", args->options.geometryError,
                  "stop refining where the contour fits the surface within this many finest voxels (0 = off)")
      ->check(finiteNonNegative());
  cmd->add_option("--color-error", args->options.colorError,
                  "with --geometry-error: also require colors within this many 8-bit steps (0 = not checked)")
      ->check(finiteNonNegative());
  cmd->add_option("--normal-error", args->options.normalError,
                  "with --geometry-error: also require normals within this many degrees (0 = not checked)")
      ->check(finiteRange(0.0, 180.0));
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
  cmd->add_option("--grid", args->volume.grid,
                  ".vdb: the grid to build (a level set, fog volume or mask; default: the file's only one)");
  cmd->add_option("--color-grid", args->volume.colorGrid,
                  ".vdb: vec3 grid of linear RGB colors (default: one named color or Cd, if present)");
  cmd->add_option("--normal-grid", args->volume.normalGrid,
                  ".vdb masks: vec3 grid of normals (default: one named normal or N, if present)");
  cmd->add_flag("--volume-via-mesh", args->volumeViaMesh,
                ".vdb level sets and fog volumes: mesh the surface (OpenVDB's volumeToMesh) and voxelize the "
                "mesh, instead of voxelizing the field directly (also taken out of core and with "
                "--geometry-error)");
  cmd->add_option(
         "--density-threshold", args->volume.densityThreshold,
         ".vdb fog volumes: voxels of at least this density are occupied (each keeps its densest point as "
         "its color's alpha where those differ)")
      ->capture_default_str();
  cmd->callback([args, cmd] {
    args->levelsGiven = cmd->count("--levels") > 0;
    runBuild(*args);
  });
}

}  // namespace svo::tools
