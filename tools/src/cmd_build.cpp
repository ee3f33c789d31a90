// `svo build MESH -o out.svo --levels N`: mesh -> octree -> .svo, with progress and a size summary.
#include <unistd.h>

#include <filesystem>

#include <spdlog/spdlog.h>
#include <tbb/global_control.h>
#include <tbb/info.h>

#include "commands.hpp"
#include "progress.hpp"
#include "svo/builder/build.hpp"

namespace svo::tools {

// Fails before any work when the output folder is missing or not writable.
void checkWritableOutput(const std::filesystem::path& out) {
  const std::filesystem::path dir = out.has_parent_path() ? out.parent_path() : ".";
  if (!std::filesystem::is_directory(dir))
    throw UsageError(out.string() + ": folder " + dir.string() + " does not exist");
  if (::access(dir.c_str(), W_OK) != 0)
    throw UsageError(out.string() + ": folder " + dir.string() + " is not writable");
  if (std::filesystem::is_directory(out)) throw UsageError(out.string() + ": is a folder");
}

void addBuildCommand(CLI::App& app) {
  struct Args {
    std::string mesh, out;
    BuildOptions options;
    bool noContours = false;
    int threads = 0;
    std::uint64_t sliceBytes = kDefaultSliceBytes;
  };
  auto args = std::make_shared<Args>();
  auto* cmd = app.add_subcommand(
      "build", "voxelize a mesh (OBJ, PLY, STL, glTF/GLB, DAE, FBX, DRC) into a .svo octree");
  cmd->add_option("mesh", args->mesh, "input mesh")->required();
  cmd->add_option("-o,--output", args->out, "output .svo file")->required();
  cmd->add_option("--levels", args->options.levels, "octree depth: finest voxels are 2^-levels of the scene")
      ->check(CLI::Range(1, kMaxLevels))
      ->capture_default_str();
  cmd->add_flag("--no-contours", args->noContours, "cube voxels only (no contour slabs)");
  cmd->add_option("--contour-min-reduction", args->options.contourMinReduction,
                  "store a contour only where it cuts more than this many voxels off the hull")
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
  cmd->callback([args] {
    checkWritableOutput(args->out);
    tbb::global_control threads(tbb::global_control::max_allowed_parallelism,
                                args->threads > 0 ? args->threads : tbb::info::default_concurrency());
    MeshLoadReport report;
    const Mesh mesh = loadMesh(args->mesh, &report);
    spdlog::info(
        "{}: {} triangles, {} vertices ({}){}", args->mesh, mesh.triangles.size(), mesh.positions.size(),
        report.format,
        report.droppedDegenerate ? fmt::format(", dropped {} degenerate", report.droppedDegenerate) : "");
    BuildOptions options = args->options;
    options.contours = !args->noContours;
    ProgressBar bar("build");
    options.progress = [&bar](double f) { bar.update(f); };
    BuildStats stats;
    const Octree octree = buildOctree(mesh, options, &stats);
    bar.finish();
    StoreWriteOptions storeOptions;
    storeOptions.sliceBytes = std::uint32_t(args->sliceBytes);
    writeOctree(args->out, octree, storeOptions);
    const LayoutStats& l = stats.layout;
    const double leaves = double(stats.leafVoxels);
    spdlog::info(
        "{} levels, {} voxels ({} leaves), {} contours, {:.2f} s", options.levels,
        [&] {
          std::uint64_t n = 0;
          for (auto v : stats.voxelsPerLevel) n += v;
          return n;
        }(),
        stats.leafVoxels, stats.contours, stats.seconds);
    spdlog::info("bytes per leaf voxel: hierarchy {:.2f}, contours {:.2f}, attributes {:.2f}, total {:.2f}",
                 l.hierarchyBytes / leaves, l.contourBytes / leaves, l.attributeBytes / leaves,
                 l.totalBytes / leaves);
    std::printf(
        "wrote %s (%.1f MiB in memory, %s)\n", args->out.c_str(), double(l.totalBytes) / (1 << 20),
        std::filesystem::exists(args->out)
            ? fmt::format("{:.1f} MiB on disk", double(std::filesystem::file_size(args->out)) / (1 << 20))
                  .c_str()
            : "");
  });
}

}  // namespace svo::tools
