// `svo verify STORE` and `svo inspect STORE`: every checksum and structural invariant of a slice store, and
// what it holds per level (slices, voxels, branching, bytes per voxel per part, slice sizes), or with
// --dimensions its dimensional analysis (paper sec. 4). STORE is a file or an http(s):// URL of one.
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cstdio>
#include <map>
#include <memory>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "commands.hpp"
#include "dimensions_report.hpp"
#include "number_checks.hpp"
#include "progress.hpp"
#include "remote.hpp"
#include "store_stats.hpp"
#include "svo/client/locator.hpp"
#include "svo/store/dimensions.hpp"
#include "svo/store/store_reader.hpp"
#include "usage.hpp"

namespace svo::tools {
namespace {

// Slice size histogram buckets: powers of two of raw bytes, from 2^kFirstBucket up.
constexpr int kFirstBucket = 6;
// The predicted base view of --dimensions: 1024 pixels (a common window) resolving the level 3 above the
// finest, so that 3 of the image size doublings still find finer levels in the store.
constexpr double kDefaultViewPixels = 1024.0;
constexpr int kViewLevelsAboveFinest = 3;
// Doublings of distance and image size predicted: 2x to 16x.
constexpr int kDefaultPredictionSteps = 4;

double per(std::uint64_t bytes, std::uint64_t voxels) {
  return voxels ? double(bytes) / double(voxels) : 0.0;
}

void inspect(const std::string& path, const std::string& token, bool json) {
  const StoreReader reader(openByteSource(path, remoteOptions(token)));
  const StoreHeader& h = reader.header();
  std::map<int, LevelSummary> levels;
  LevelSummary total;
  std::map<int, std::uint64_t> histogram;  // log2 bucket -> slices
  for (const SliceInfo& s : reader.slices()) {
    const LevelSummary l = summarizeSlice(s, h);
    add(levels[s.voxelLevel], l);
    add(total, l);
    ++histogram[std::max(kFirstBucket, int(std::bit_width(s.rawBytes)) - 1)];
  }
  if (json) {
    nlohmann::json j;
    j["file"] = path;
    j["formatVersion"] = h.version;
    j["fileBytes"] = h.fileBytes;
    j["levels"] = h.parameters.levels;
    j["sliceBytes"] = h.sliceBytes;
    j["attachments"] = nlohmann::json::array();
    if (h.hasColors) j["attachments"].push_back("color");
    if (h.hasNormals) j["attachments"].push_back("normal");
    for (const auto& [level, l] : levels)
      j["perLevel"].push_back({{"level", level},
                               {"slices", l.slices},
                               {"voxels", l.voxels},
                               {"branching", l.parents ? double(l.voxels) / double(l.parents) : 0.0},
                               {"rawBytes", l.rawBytes},
                               {"diskBytes", l.diskBytes},
                               {"hierarchyBytes", l.hierarchyBytes},
                               {"contourBytes", l.contourBytes},
                               {"colorBytes", l.colorBytes},
                               {"normalBytes", l.normalBytes},
                               {"smallestSlice", l.smallestSlice},
                               {"largestSlice", l.largestSlice}});
    for (const auto& [bucket, count] : histogram)
      j["sliceSizeHistogram"].push_back({{"fromBytes", 1ull << bucket}, {"slices", count}});
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  fmt::print("{}: format {}, {:.2f} MiB, {} levels, {} slices (slice size {} B), attachments:{}{}\n", path,
             h.version, double(h.fileBytes) / (1 << 20), h.parameters.levels, reader.slices().size(),
             h.sliceBytes, h.hasColors ? " color" : "",
             h.hasNormals ? " normal" : (h.hasColors ? "" : " none"));
  if (h.version < kFileVersion)
    fmt::print("(format {} is read as it is; svo build writes format {}, smaller on disk)\n", h.version,
               kFileVersion);
  fmt::print("{:>5} {:>7} {:>11} {:>6} {:>9} {:>9} {:>9} {:>9} {:>9} {:>10} {:>10}\n", "level", "slices",
             "voxels", "branch", "B/v disk", "B/v raw", "hierarchy", "contours", "colors", "normals",
             "max slice");
  const auto row = [&](const std::string& name, const LevelSummary& l) {
    fmt::print("{:>5} {:>7} {:>11} {:>6.2f} {:>9.3f} {:>9.3f} {:>9.3f} {:>9.3f} {:>9.3f} {:>10.3f} {:>10}\n",
               name, l.slices, l.voxels, l.parents ? double(l.voxels) / double(l.parents) : 0.0,
               per(l.diskBytes, l.voxels), per(l.rawBytes, l.voxels), per(l.hierarchyBytes, l.voxels),
               per(l.contourBytes, l.voxels), per(l.colorBytes, l.voxels), per(l.normalBytes, l.voxels),
               l.largestSlice);
  };
  for (const auto& [level, l] : levels) row(std::to_string(level), l);
  row("all", total);
  fmt::print("bytes per voxel (B/v): disk = compressed, raw and its parts = decoded slice sections\n");
  fmt::print("slice sizes (decoded bytes):\n");
  const std::uint64_t most = std::max_element(histogram.begin(), histogram.end(), [](auto& a, auto& b) {
                               return a.second < b.second;
                             })->second;
  for (const auto& [bucket, count] : histogram)
    fmt::print("  {:>10} - {:<10} {:>6}  {}\n", 1ull << bucket, (2ull << bucket) - 1, count,
               std::string(std::size_t(40.0 * double(count) / double(most) + 0.5), '#'));
}

struct DimensionArgs {
  std::string output = "dimensions-report";
  int viewLevel = -1;  // -1: kViewLevelsAboveFinest above the finest level
  double viewPixels = kDefaultViewPixels;
  int steps = kDefaultPredictionSteps;
};

void inspectDimensions(const std::string& path, const std::string& token, bool json,
                       const DimensionArgs& args) {
  // The folder is made once the store has been read, but a path that cannot become one fails first.
  const std::filesystem::path output = args.output;
  if (std::filesystem::exists(output) && !std::filesystem::is_directory(output))
    throw UsageError(output.string() + ": is not a folder");
  if (!std::filesystem::exists(output)) checkWritableOutput(output);
  const StoreReader reader(openByteSource(path, remoteOptions(token)));
  std::unique_ptr<ProgressBar> bar = ::isatty(2) ? std::make_unique<ProgressBar>("dimensions") : nullptr;
  const VoxelDimensions dims = measureDimensions(reader, [&bar](double f) {
    if (bar) bar->update(f);
  });
  bar.reset();
  const int finest = dims.finestLevel();
  const int level = args.viewLevel < 0 ? std::max(1, finest - kViewLevelsAboveFinest) : args.viewLevel;
  if (level < 1 || level > finest)
    throw UsageError(fmt::format("--view-level {}: the store's levels are 1 to {}", level, finest));
  const std::vector<double> weights = decodedBytesPerVoxel(reader.index(), finest);
  const ViewLevels base = viewLevels(level, args.viewPixels, 1.0);
  const std::vector<PredictedView> views = predictViews(dims, weights, base, args.steps);
  std::filesystem::create_directories(output);
  const std::filesystem::path png = writeDimensionsPlot(output, dims);
  if (json) {
    nlohmann::json j = dimensionsJson(dims, views);
    j["file"] = path;
    j["plot"] = png.string();
    std::printf("%s\n", j.dump(2).c_str());
    return;
  }
  fmt::print("{}: dimensional analysis (paper sec. 4), {} levels\n", path, finest);
  printDimensions(dims);
  printPrediction(views,
                  fmt::format("a view {:g} pixels wide resolving level {} at distance d (1-pixel voxels)",
                              args.viewPixels, level));
  fmt::print("wrote {}\n", png.string());
}

}  // namespace

void addStoreCommands(CLI::App& app) {
  {
    struct Args {
      std::string path, token;
    };
    auto args = std::make_shared<Args>();
    auto* cmd = app.add_subcommand("verify", "check every checksum and structural invariant of a .svo store");
    cmd->add_option("store", args->path, "the .svo store: a file, or its http(s):// URL")->required();
    addTokenOption(cmd, args->token);
    cmd->callback([args] {
      // Any problem throws with the file and, for a slice, its number: main prints it and exits 1.
      const StoreReader reader(openByteSource(args->path, remoteOptions(args->token)));
      // A bar on a terminal only: in a log, the one line a failure prints stays the only one.
      std::unique_ptr<ProgressBar> bar = ::isatty(2) ? std::make_unique<ProgressBar>("verify") : nullptr;
      const std::uint64_t voxels = reader.verify([&bar](double f) {
        if (bar) bar->update(f);
      });
      bar.reset();
      std::printf("%s: ok (%zu slices, %llu voxels, %.2f MiB)\n", args->path.c_str(), reader.slices().size(),
                  static_cast<unsigned long long>(voxels), double(reader.header().fileBytes) / (1 << 20));
    });
  }
  {
    struct Args {
      std::string path, token;
      bool json = false, dimensions = false;
      DimensionArgs dims;
    };
    auto args = std::make_shared<Args>();
    auto* cmd =
        app.add_subcommand("inspect", "per level: slices, voxels, branching, bytes per voxel, slice sizes");
    cmd->add_option("store", args->path, "the .svo store: a file, or its http(s):// URL")->required();
    cmd->add_flag("--json", args->json, "print JSON instead of a table");
    addTokenOption(cmd, args->token);
    auto* dims = cmd->add_flag("--dimensions", args->dimensions,
                               "dimensional analysis (paper sec. 4): N(c, L), D_local, D_global, D_scale per "
                               "cube and voxel level, a plot, and how a view's data grows with its distance "
                               "and image size");
    cmd->add_option("-o,--output", args->dims.output, "--dimensions: folder for dimensions.png")
        ->needs(dims)
        ->capture_default_str();
    cmd->add_option("--view-level", args->dims.viewLevel,
                    "--dimensions: the voxel level the predicted base view resolves (default: 3 above the "
                    "finest)")
        ->needs(dims)
        ->check(CLI::Range(1, 30));
    cmd->add_option("--view-pixels", args->dims.viewPixels, "--dimensions: the base view's image size")
        ->needs(dims)
        ->check(finiteRange(1.0, 65536.0))
        ->capture_default_str();
    cmd->add_option("--steps", args->dims.steps,
                    "--dimensions: doublings of the base view's distance and of its image size")
        ->needs(dims)
        ->check(CLI::Range(1, 16))
        ->capture_default_str();
    cmd->callback([args] {
      if (args->dimensions)
        inspectDimensions(args->path, args->token, args->json, args->dims);
      else
        inspect(args->path, args->token, args->json);
    });
  }
}

}  // namespace svo::tools
