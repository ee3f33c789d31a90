// `svo bench dimensions STORE`: the dimensional analysis's prediction of a view's data (`svo inspect
// --dimensions`) against what the pager loads. A base view looks at the surface the centre of a framing view
// sees, from the distance at which its image loads the store's finest level there; then from 2, 4, ... times
// that distance, and with images 2, 4, ... times smaller. Each view converges from a cold pager whose budget
// holds it; what it loaded is the decoded bytes of the slices it wants inside its frustum, resident when
// nothing there was left to load (and, beside them, of every slice resident then).
// The prediction is the model's data of each view (VoxelDimensions::viewData at its cube and voxel levels,
// weighted by the store's decoded bytes per voxel of each level); the table gives it absolutely and relative
// to the base view, beside what was loaded.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <set>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <glm/geometric.hpp>

#include "bench_common.hpp"
#include "dimensions_report.hpp"
#include "measure.hpp"
#include "number_checks.hpp"
#include "pager_flags.hpp"
#include "plot.hpp"
#include "remote.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/streaming.hpp"
#include "svo/store/dimensions.hpp"
#include "svo/store/schedule.hpp"

namespace svo::tools::bench {
namespace {

// A budget that holds every view of a bunny at 10 levels or a terrain at 12 without an eviction; the bench
// refuses to report a view whose frustum did not fit.
constexpr std::size_t kDefaultBudget = std::size_t(1) << 30;
// The smallest image of the image size sweep: below it a view is a handful of pixels.
constexpr int kSmallestImage = 8;

struct DimensionArgs {
  std::string input, output = "dimensions-report", token, direction = defaultViewText();
  bool rangeOnly = false;
  int size = 512, steps = 4;
  std::size_t budget = kDefaultBudget;
  PagerOptions pager;
  float lodPixels = 1.0f;
  double timeout = 300.0;
};

struct Loaded {
  std::uint64_t view = 0, all = 0;  // decoded bytes: inside the frustum, and all resident
  double seconds = 0.0;             // until the view converged
};

// A cold pager over the store with the bench's budget and threads.
std::unique_ptr<Pager> coldPager(const DimensionArgs& args) {
  PagerOptions options = args.pager;
  options.budgetBytes = args.budget;
  options.fetchThreads = resolvedFetchThreads(options.fetchThreads, args.input);
  return std::make_unique<Pager>(openSliceSource(args.input, remoteOptions(args.token, args.rangeOnly)),
                                 options);
}

// Converges `camera` from a cold pager and sums what was resident then.
Loaded loadView(const DimensionArgs& args, const Camera& camera) {
  const std::unique_ptr<Pager> cold = coldPager(args);
  Pager& pager = *cold;
  RenderOptions render;
  render.lodPixels = args.lodPixels;
  const Convergence c = convergeView(pager, camera, render, args.timeout);
  if (!c.converged())
    throw std::runtime_error(fmt::format("{}: a view {} pixels wide did not converge within {} s (--timeout)",
                                         args.input, camera.width, args.timeout));
  std::set<std::uint32_t> inFrustum;
  for (const SliceRequest& r :
       scheduleSlices(pager.index(), viewOf(pager.transform(), camera, args.lodPixels)))
    if (r.inFrustum) inFrustum.insert(r.slice);
  Loaded loaded;
  loaded.seconds = c.viewSeconds;
  std::size_t found = 0;
  for (const std::uint32_t s : c.viewResidentSlices) {
    const std::uint64_t bytes = pager.index().slices()[s].rawBytes;
    loaded.all += bytes;
    if (inFrustum.count(s)) loaded.view += bytes, ++found;
  }
  if (found != inFrustum.size())
    throw std::runtime_error(fmt::format(
        "{}: {} slices inside a view {} pixels wide did not load (failed, or no room: raise --budget)",
        args.input, inFrustum.size() - found, camera.width));
  return loaded;
}

struct Row {
  double distance = 1.0;  // multiples of the base view's
  int size = 0;
  ViewLevels levels;
  double predicted = 0.0;  // the model's decoded bytes
  Loaded loaded;
};

std::string times(double x) {
  return fmt::format("{:.3g}", x);
}

void printRows(const std::string& title, const std::vector<Row>& rows, const Row& base) {
  printTitle(title);
  Table table({"distance", "image", "cube level", "voxel level", "predicted", "loaded (view)",
               "loaded / predicted", "predicted x", "loaded x", "resident (all)", "view converged"});
  for (const Row& r : rows)
    table.addRow(
        {fmt::format("{:g}d", r.distance), fmt::format("{}^2", r.size), fmt::format("{:.2f}", r.levels.cube),
         fmt::format("{:.2f}", r.levels.voxel), formatBytes(std::size_t(r.predicted)),
         formatBytes(r.loaded.view), fmt::format("{:.2f}", double(r.loaded.view) / r.predicted),
         times(r.predicted / base.predicted), times(double(r.loaded.view) / double(base.loaded.view)),
         formatBytes(r.loaded.all), formatSeconds(r.loaded.seconds)});
  table.print();
}

plot::Panel panelOf(const std::string& title, const std::vector<Row>& rows, double (*x)(const Row&)) {
  plot::Panel p{title, {{"predicted", {}}, {"loaded (view)", {}}, {"resident (all)", {}}}};
  for (const Row& r : rows) {
    p.series[0].points.push_back({x(r), r.predicted});
    p.series[1].points.push_back({x(r), double(r.loaded.view)});
    p.series[2].points.push_back({x(r), double(r.loaded.all)});
  }
  return p;
}

void runDimensionBench(const DimensionArgs& args) {
  keepFreedMemoryForReuse();
  if ((args.size >> args.steps) < kSmallestImage)
    throw UsageError(fmt::format("--size {} halved {} times (--steps) is below {} pixels", args.size,
                                 args.steps, kSmallestImage));
  const glm::dvec3 direction = parseDirection(args.direction, "--direction");
  const StoreReader reader(openByteSource(args.input, remoteOptions(args.token)));
  const auto start = std::chrono::steady_clock::now();
  const VoxelDimensions dims = measureDimensions(reader);
  const double measureSeconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::filesystem::create_directories(args.output);
  const int finest = dims.finestLevel();
  const std::vector<double> weights = decodedBytesPerVoxel(reader.index(), finest);
  const SceneTransform& scene = reader.header().transform;

  // The base view: its image loads the finest level at the surface it looks at (viewLevelsOf).
  Camera base;
  {
    Camera probe;
    probe.width = probe.height = args.size;
    const double distance = std::exp2(kLoadedLevelOffset - finest) / (args.lodPixels * probe.pixelAngle());
    base = closeUp(coldPager(args)->trunk(), scene, args.size, distance, direction);
  }
  const glm::dvec3 forward = glm::normalize(base.target - base.eye);
  const double baseDistance = glm::length(base.target - base.eye);
  const auto rowOf = [&](double distance, int size) {
    Camera c = base;
    c.eye = c.target - forward * (baseDistance * distance);
    c.width = c.height = size;
    Row r{distance, size, viewLevelsOf(scene, c, args.lodPixels), 0.0, {}};
    r.predicted = dims.viewData(r.levels.cube, r.levels.voxel, weights);
    spdlog::info("view at {:g}d, {}^2: cube level {:.2f}, voxel level {:.2f}", distance, size, r.levels.cube,
                 r.levels.voxel);
    r.loaded = loadView(args, c);
    return r;
  };
  std::vector<Row> distances, sizes;
  for (int k = 0; k <= args.steps; ++k) distances.push_back(rowOf(std::ldexp(1.0, k), args.size));
  for (int k = args.steps; k >= 1; --k) sizes.push_back(rowOf(1.0, args.size >> k));
  sizes.push_back(distances.front());

  printTitle(fmt::format("svo bench dimensions {} ({} levels, LOD {:g} px, budget {}; N measured in {})",
                         args.input, finest, args.lodPixels, formatBytes(args.budget),
                         formatSeconds(measureSeconds)));
  printRows("doubling the distance", distances, distances.front());
  printRows("doubling the image size", sizes, distances.front());
  std::printf(
      "d: the base view's distance, where its %d^2 image loads level %d at the surface it looks at; cube and "
      "voxel level: the view's extent there and the level it loads (the first whose voxels look at most %g "
      "px wide: half a level finer than the one exactly that wide, on average); predicted: decoded bytes of "
      "every level down to that one in a cube of that level around a point of the content (N, weighted by "
      "the store's bytes per voxel of each level); loaded (view): decoded bytes of the slices the view wants "
      "inside its frustum, resident when nothing there was left to load; resident (all): every slice "
      "resident then, the trunk and slices around the view included; x: over the base view's\n",
      args.size, finest, args.lodPixels);
  const std::filesystem::path png = std::filesystem::path(args.output) / "dimensions_check.png";
  plot::writeLogLogPlot(png,
                        {panelOf("doubling the distance (x: multiple of d)", distances,
                                 [](const Row& r) { return r.distance; }),
                         panelOf("doubling the image size (x: pixels across)", sizes,
                                 [](const Row& r) { return double(r.size); })},
                        "distance (multiple of d) or image size (pixels)", "decoded bytes", 1400, 700);
  std::printf("wrote %s\n", png.c_str());
}

}  // namespace

void addDimensionBench(CLI::App& bench) {
  auto args = std::make_shared<DimensionArgs>();
  auto* cmd = bench.add_subcommand(
      "dimensions",
      "the dimensional analysis's prediction of a view's data (svo inspect --dimensions) "
      "against what the pager loads at doubling distances and image sizes");
  cmd->add_option("input", args->input, "a .svo store: a file, or its http(s):// URL")
      ->required()
      ->check(storeLocator());
  addTokenOption(cmd, args->token);
  addRangeOnlyFlag(cmd, args->rangeOnly);
  cmd->add_option("-o,--output", args->output, "folder for dimensions_check.png")->capture_default_str();
  cmd->add_option("--size", args->size, "the base view's image width and height")
      ->check(CLI::Range(kSmallestImage, 4096))
      ->capture_default_str();
  cmd->add_option("--steps", args->steps, "doublings of the distance and halvings of the image size")
      ->check(CLI::Range(1, 10))
      ->capture_default_str();
  cmd->add_option("--direction", args->direction, "the views' direction x,y,z")->capture_default_str();
  cmd->add_option("--budget", args->budget, "each view's pool budget (default 1G)")
      ->transform(CLI::AsSizeValue(false));
  cmd->add_option("--lod-pixels", args->lodPixels, "target voxel size in pixels")
      ->check(finiteRange(0.01, 64.0))
      ->capture_default_str();
  cmd->add_option("--timeout", args->timeout, "seconds a view may take to converge")
      ->check(finiteRange(1.0, 86400.0))
      ->capture_default_str();
  addPagerThreadFlags(*cmd, args->pager);
  cmd->callback([args] { runDimensionBench(*args); });
}

}  // namespace svo::tools::bench
