// `svo export STORE -o out.vdb --level N`: one level of a store as an OpenVDB file (a voxel mask or a level
// set, with color and normal grids), for any OpenVDB tool.
#include <cstdio>
#include <memory>

#include <fmt/format.h>

#include "commands.hpp"
#include "progress.hpp"
#include "remote.hpp"
#include "svo/builder/volume.hpp"
#include "svo/client/locator.hpp"
#include "usage.hpp"

namespace svo::tools {
namespace {

struct ExportArgs {
  std::string store, out, token;
  VolumeExportOptions options;
};

void runExport(ExportArgs& args) {
  if (!isVolumeFile(args.out)) throw UsageError("--output must name a .vdb file: " + args.out);
  checkWritableOutput(args.out);
  const StoreReader reader(openByteSource(args.store, remoteOptions(args.token)));
  const int levels = reader.header().parameters.levels;
  if (args.options.level == 0) args.options.level = levels;
  if (args.options.level > levels)
    throw UsageError(
        fmt::format("--level {} is deeper than the store's {} levels", args.options.level, levels));
  VolumeExportReport report;
  {
    ProgressBar bar("export");
    args.options.progress = [&bar](double f) { bar.update(f); };
    report = exportVolume(reader, args.out, args.options);
  }
  std::printf("wrote %s: %llu voxels of level %d (%g wide), %s, %.1f MiB\n", args.out.c_str(),
              static_cast<unsigned long long>(report.voxels), args.options.level, report.voxelSize,
              args.options.levelSet ? "a level set around them" : "a voxel mask",
              double(report.fileBytes) / (1 << 20));
}

}  // namespace

void addExportCommand(CLI::App& app) {
  auto args = std::make_shared<ExportArgs>();
  auto* cmd = app.add_subcommand("export", "write one level of a store as an OpenVDB file (.vdb)");
  cmd->add_option("store", args->store, "the .svo store (a file or an http(s):// URL)")->required();
  cmd->add_option("-o,--output", args->out, "output .vdb file")->required();
  cmd->add_option("--level", args->options.level,
                  "the level whose voxels become the grid's voxels (default: the finest)")
      ->check(CLI::Range(1, kMaxLevels));
  cmd->add_flag("--level-set", args->options.levelSet,
                "a narrow-band level set around the voxels (grid 'surface') instead of a voxel mask "
                "('occupancy', which svo build reads back voxel for voxel)");
  addTokenOption(cmd, args->token);
  cmd->callback([args] { runExport(*args); });
}

}  // namespace svo::tools
