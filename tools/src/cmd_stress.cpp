// `svo stress IN.svo`: the memory-budget stress test. Camera sequences that want far more than the budget —
// close-ups down to the finest level at many places on the surface, teleports between them, zooms in and out,
// a flight skimming the surface — stream against each budget. Every frame checks resident bytes <= budget
// and the pool's and pager's invariants; a violation prints the frame and fails the run, as does a budget
// below the store's decoded size that saw no eviction (the sequences did not stress it). The table reports
// what the views wanted against the budget, loads, evictions, cancellations, re-loads, the worst frame and
// the time the final view takes to converge. With --minutes the sequences repeat as a soak test that also
// records the process's resident memory over time, which must stay flat.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <random>
#include <set>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <glm/geometric.hpp>

#include "commands.hpp"
#include "machine.hpp"
#include "measure.hpp"
#include "number_checks.hpp"
#include "pager_flags.hpp"
#include "plot.hpp"
#include "remote.hpp"
#include "report.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/streaming.hpp"
#include "svo/client/whole_scene.hpp"

namespace svo::tools {
namespace {

struct StressArgs {
  std::string input, output = "stress-report", token;
  bool rangeOnly = false;
  std::vector<std::size_t> budgets{std::size_t(4) << 20, std::size_t(64) << 20};
  int frames = 120;
  int size = 256;
  unsigned seed = 1;
  float lodPixels = 1.0f;
  double timeout = 120.0;
  double minutes = 0.0;  // soak: repeat the sequences this long
  AttributeOptions attributes;
  PoolLayout layout = PoolLayout::Blocks;
};

// Field of view of the stress cameras, degrees.
constexpr double kStressFovDegrees = 50.0;
// Framing views the surface points are taken from, and their size in pixels: enough directions to find
// surface on every side of a scene, few pixels so that finding them costs little next to the sequences.
constexpr int kSurfaceViews = 8;
constexpr int kSurfaceViewPixels = 64;
// Close-ups stand between these multiples of the distance at which a finest voxel is lodPixels wide: below
// 1 every close-up wants the finest level, above it some stop one or two levels up.
constexpr double kNearestCloseUp = 0.25, kFarthestCloseUp = 4.0;
// Frames a teleport stays at one place before jumping: one to ask, one to see part of it arrive.
constexpr int kTeleportHold = 2;
// Zooms run from this many scene sizes away down to the nearest close-up and back, several per sequence.
constexpr double kZoomFarScenes = 2.5;
constexpr int kZoomsPerSequence = 3;
// Places a flight visits; it moves between them at close-up distance.
constexpr int kFlightStops = 6;
// Frames come at most this often, as in a viewer at 60 Hz: the pager's workers have the rest of the period,
// so what a sequence loads depends on the frames, not on how fast tiny frames render.
constexpr std::chrono::duration<double> kFramePeriod(1.0 / 60.0);
// Soak: resident memory may grow at most this much from the first half of a budget's run to its second
// (allocator noise) before the run fails as a leak.
constexpr double kSoakGrowthShare = 0.05;
constexpr std::uint64_t kSoakGrowthBytes = std::uint64_t(16) << 20;

// A point on the surface as one framing view saw it, with that view's direction.
struct SurfacePoint {
  glm::dvec3 position, direction;
};

// Surface points from framing views of what is resident (the trunk at first): a coarse voxel contains the
// surface it stands for, so the finer surface lies on or behind the point along the direction, and a camera
// in front of it is never inside the scene.
std::vector<SurfacePoint> surfacePoints(Pager& pager, std::mt19937& rng) {
  std::normal_distribution<double> gaussian;
  std::vector<SurfacePoint> points;
  RenderOptions options;
  options.lodPixels = 1.0f;
  for (int v = 0; v < kSurfaceViews; ++v) {
    const glm::dvec3 direction =
        glm::normalize(glm::dvec3(gaussian(rng), gaussian(rng), gaussian(rng)) + 1e-9);
    const Camera camera =
        Camera::framing(pager.transform(), direction, kSurfaceViewPixels, kSurfaceViewPixels);
    const Frame frame = render(pager, camera, options);
    const Camera::Basis basis = camera.basis();
    for (int y = 0; y < frame.height; ++y)
      for (int x = 0; x < frame.width; ++x) {
        const float depth = frame.depth[std::size_t(y) * std::size_t(frame.width) + std::size_t(x)];
        if (!std::isfinite(depth)) continue;
        glm::dvec3 ray;
        Camera::pixelRay(camera, basis, x, y, ray);
        points.push_back({camera.eye + ray * double(depth), ray});
      }
  }
  if (points.empty()) throw std::runtime_error("stress: no view of the scene hits anything");
  return points;
}

Camera lookingAt(const glm::dvec3& target, const glm::dvec3& direction, double distance, int size) {
  Camera c;
  c.width = c.height = size;
  c.fovYDegrees = kStressFovDegrees;
  c.target = target;
  c.eye = target - direction * distance;
  if (glm::length(glm::cross(direction, c.up)) < 1e-6) c.up = glm::dvec3(1, 0, 0);
  return c;
}

// Frames of one sequence. `finestDistance`: where a finest voxel looks lodPixels wide.
std::vector<Camera> sequence(const std::string& kind, const std::vector<SurfacePoint>& surface,
                             const SceneTransform& scene, double finestDistance, int frames, int size,
                             std::mt19937& rng) {
  std::uniform_int_distribution<std::size_t> anyPoint(0, surface.size() - 1);
  std::uniform_real_distribution<double> logDistance(std::log(kNearestCloseUp), std::log(kFarthestCloseUp));
  const auto closeDistance = [&] { return finestDistance * std::exp(logDistance(rng)); };
  std::vector<Camera> out;
  if (kind == "teleport") {  // close-ups anywhere on the surface, a jump every few frames
    while (int(out.size()) < frames) {
      const SurfacePoint& p = surface[anyPoint(rng)];
      const Camera c = lookingAt(p.position, p.direction, closeDistance(), size);
      for (int k = 0; k < kTeleportHold && int(out.size()) < frames; ++k) out.push_back(c);
    }
  } else if (kind == "zoom") {  // from far outside down to the finest voxels and back, at several places
    const int perZoom = std::max(2, frames / kZoomsPerSequence);
    while (int(out.size()) < frames) {
      const SurfacePoint& p = surface[anyPoint(rng)];
      const double far = kZoomFarScenes * scene.size, near = kNearestCloseUp * finestDistance;
      for (int i = 0; i < perZoom && int(out.size()) < frames; ++i) {
        const double s = 1.0 - std::abs(2.0 * double(i) / double(perZoom - 1) - 1.0);  // 0 -> 1 -> 0
        out.push_back(lookingAt(p.position, p.direction, far * std::pow(near / far, s), size));
      }
    }
  } else {  // flight: skims the surface from place to place at close-up distance
    std::vector<SurfacePoint> stops;
    for (int i = 0; i < kFlightStops; ++i) stops.push_back(surface[anyPoint(rng)]);
    const int perLeg = std::max(1, frames / (kFlightStops - 1));
    for (int i = 0; int(out.size()) < frames; ++i) {
      const SurfacePoint& a = stops[std::size_t(std::min(i / perLeg, kFlightStops - 2))];
      const SurfacePoint& b = stops[std::size_t(std::min(i / perLeg, kFlightStops - 2) + 1)];
      const double s = std::min(1.0, double(i % perLeg) / double(perLeg));
      const glm::dvec3 target = glm::mix(a.position, b.position, s);
      const glm::dvec3 direction = glm::normalize(glm::mix(a.direction, b.direction, s) + 1e-9);
      out.push_back(lookingAt(target, direction, kFarthestCloseUp * finestDistance, size));
    }
  }
  return out;
}

// Where a finest voxel of the store looks `lodPixels` wide in a `size`-pixel stress camera.
double finestDistance(const Pager& pager, int size, float lodPixels) {
  Camera c;
  c.width = c.height = size;
  c.fovYDegrees = kStressFovDegrees;
  const double finest = pager.transform().size * std::ldexp(1.0, -pager.index().header().parameters.levels);
  return finest / (c.pixelAngle() * std::max(lodPixels, 1e-3f));
}

// What one sequence did.
struct SequenceResult {
  std::size_t frames = 0;
  std::uint64_t loads = 0, evictions = 0, cancelled = 0, reloads = 0, denied = 0, failed = 0;
  std::uint64_t peakWanted = 0,
                allWanted = 0;  // decoded bytes the views wanted: most in one, distinct in all
  std::vector<double> frameMs;
  std::vector<std::uint32_t> loaded;  // every slice loaded, once each
  std::size_t maxResident = 0;
  double convergeSeconds = -1.0;
  bool violated = false;
};

// Streams the cameras through the pager, checking every frame. The slices ever evicted persist across
// sequences of one pager, so a re-load is counted whenever a slice comes back.
SequenceResult runSequence(Pager& pager, const std::vector<Camera>& cameras, const RenderOptions& render,
                           double timeout, std::set<std::uint32_t>& everEvicted, const std::string& label) {
  SequenceResult r;
  std::set<std::uint32_t> wanted;
  std::vector<std::uint32_t> before = pager.residentSlices();
  for (const Camera& camera : cameras) {
    const auto frameStart = std::chrono::steady_clock::now();
    const StreamedFrame step = streamFrame(pager, camera, render);
    r.frameMs.push_back(step.seconds() * 1e3);
    r.maxResident = std::max(r.maxResident, step.stats.residentBytes);
    r.failed += step.stats.failed;
    r.cancelled += step.stats.cancelled;
    r.denied += step.stats.denied;
    r.peakWanted = std::max(r.peakWanted, step.stats.wantedRawBytes);
    for (const std::uint32_t s : pager.wantedSlices()) wanted.insert(s);
    try {
      if (step.stats.residentBytes > pager.budgetBytes())
        throw std::logic_error("resident bytes exceed the budget");
      pager.checkInvariants();
    } catch (const std::logic_error& e) {
      std::fprintf(stderr, "svo stress: %s frame %zu: %s\n", label.c_str(), r.frameMs.size() - 1, e.what());
      r.violated = true;
      return r;
    }
    const std::vector<std::uint32_t> after = pager.residentSlices();
    std::vector<std::uint32_t> added, removed;
    std::set_difference(after.begin(), after.end(), before.begin(), before.end(), std::back_inserter(added));
    std::set_difference(before.begin(), before.end(), after.begin(), after.end(),
                        std::back_inserter(removed));
    r.loads += added.size(), r.evictions += removed.size();
    for (const std::uint32_t s : added) r.reloads += everEvicted.count(s);
    r.loaded.insert(r.loaded.end(), added.begin(), added.end());
    everEvicted.insert(removed.begin(), removed.end());
    before = after;
    std::this_thread::sleep_until(frameStart + kFramePeriod);
  }
  r.frames = cameras.size();
  for (const std::uint32_t s : wanted) r.allWanted += pager.index().slices()[s].rawBytes;
  r.convergeSeconds = convergeView(pager, cameras.back(), render, timeout).seconds;
  return r;
}

std::vector<std::string> rowOf(const std::string& budget, const std::string& kind, const SequenceResult& r,
                               double timeout) {
  char thrash[32], worst[32], p99[32], converge[32];
  std::snprintf(thrash, sizeof thrash, "%.1f%%", r.loads ? 100.0 * double(r.reloads) / double(r.loads) : 0.0);
  std::snprintf(worst, sizeof worst, "%.1f ms", *std::max_element(r.frameMs.begin(), r.frameMs.end()));
  std::snprintf(p99, sizeof p99, "%.1f ms", percentile(r.frameMs, 0.99));
  if (r.convergeSeconds >= 0.0)
    std::snprintf(converge, sizeof converge, "%.2f s", r.convergeSeconds);
  else
    std::snprintf(converge, sizeof converge, "> %.0f s", timeout);
  return {budget,
          kind,
          std::to_string(r.frames),
          formatBytes(r.peakWanted),
          formatBytes(r.allWanted),
          std::to_string(r.loads),
          std::to_string(r.evictions),
          std::to_string(r.cancelled),
          std::to_string(r.reloads),
          thrash,
          worst,
          p99,
          formatBytes(r.maxResident),
          converge,
          std::to_string(r.failed)};
}

const std::vector<std::string> kKinds = {"teleport", "zoom", "flight"};

Table stressTable() {
  return Table({"budget", "sequence", "frames", "wanted (view)", "wanted (all)", "loads", "evictions",
                "cancelled", "re-loads", "thrash", "worst frame", "p99 frame", "max resident", "converge",
                "failed"});
}

PagerOptions pagerOptionsFor(std::size_t budget, const StressArgs& args) {
  PagerOptions options;
  options.budgetBytes = budget;
  options.fetchThreads = fetchThreadsFor(args.input);
  options.attributes = args.attributes;
  options.layout = args.layout;
  return options;
}

void runStress(const StressArgs& args) {
  keepFreedMemoryForReuse();
  Table table = stressTable();
  bool violated = false;
  std::vector<std::string> unstressed, trunkBound;
  std::uint64_t storeDecoded = 0;
  RenderOptions render;
  render.lodPixels = args.lodPixels;
  // Opened once: a store that cannot be read fails the command; each budget's pager starts cold all the same.
  const std::shared_ptr<const SliceSource> source =
      openSliceSource(args.input, remoteOptions(args.token, args.rangeOnly));
  for (const std::size_t budget : args.budgets) {
    const std::string text = formatBytes(budget);
    std::unique_ptr<Pager> pager;
    try {
      pager = std::make_unique<Pager>(source, pagerOptionsFor(budget, args));
    } catch (const std::runtime_error& e) {
      table.addRow({text, "-", "-", "-", "-", "-", "-", "-", "-", "-", "-", "-", "-", "-", e.what()});
      continue;
    }
    storeDecoded = footprintOf(pager->index().slices()).decodedBytes;
    const std::size_t trunkBytes = pager->residentBytes();
    std::mt19937 rng(args.seed);
    const std::vector<SurfacePoint> surface = surfacePoints(*pager, rng);
    const double finest = finestDistance(*pager, args.size, args.lodPixels);
    std::set<std::uint32_t> everEvicted, everLoaded;
    std::uint64_t evictions = 0;
    for (const std::string& kind : kKinds) {
      const std::vector<Camera> cameras =
          sequence(kind, surface, pager->transform(), finest, args.frames, args.size, rng);
      const SequenceResult r =
          runSequence(*pager, cameras, render, args.timeout, everEvicted, text + ", " + kind);
      violated |= r.violated;
      evictions += r.evictions;
      everLoaded.insert(r.loaded.begin(), r.loaded.end());
      if (!r.violated) table.addRow(rowOf(text, kind, r, args.timeout));
    }
    // Eviction needs two blocks beside the trunk that want the room in turn: with at most one slice ever
    // loaded, the budget held nothing else the views wanted.
    if (budget < storeDecoded && evictions == 0)
      (everLoaded.size() <= 1 ? trunkBound : unstressed)
          .push_back(text + " (trunk " + formatBytes(trunkBytes) + ")");
  }
  printTitle("svo stress " + args.input + " (" + std::to_string(args.size) + "^2 frames, LOD " +
             fmt::format("{:g}", args.lodPixels) + " px; store decoded " + formatBytes(storeDecoded) + ")");
  table.print();
  std::printf(
      "wanted (view): decoded bytes of the slices the most demanding frame wanted; wanted (all): of every "
      "slice some frame wanted;\nre-loads: slices loaded again after an eviction (thrash: per load); every "
      "frame checked resident <= budget and the pool invariants\n");
  for (const std::string& budget : trunkBound)
    std::printf("budget %s: beside the trunk it held at most one more slice: nothing to evict\n",
                budget.c_str());
  if (violated) throw std::runtime_error("stress: an invariant was violated (see above)");
  for (const std::string& budget : unstressed)
    throw std::runtime_error("stress: budget " + budget + " is below the store's decoded size (" +
                             formatBytes(storeDecoded) + ") but no sequence evicted anything");
}

// --minutes: the sequences again and again, each budget for its share of the time, with the process's
// resident memory after every sequence.
void runSoak(const StressArgs& args) {
  keepFreedMemoryForReuse();
  std::filesystem::create_directories(args.output);
  const std::filesystem::path csvPath = std::filesystem::path(args.output) / "soak.csv";
  std::ofstream csv(csvPath);
  csv << "seconds,budget,sequence,loads,evictions,cancelled,reloads,max_resident,rss_bytes\n";
  Table table = stressTable();
  RenderOptions render;
  render.lodPixels = args.lodPixels;
  const auto start = std::chrono::steady_clock::now();
  const double perBudget = args.minutes * 60.0 / double(args.budgets.size());
  std::vector<plot::Series> curves;
  std::vector<std::string> leaks;
  const std::shared_ptr<const SliceSource> source =
      openSliceSource(args.input, remoteOptions(args.token, args.rangeOnly));
  for (const std::size_t budget : args.budgets) {
    const std::string text = formatBytes(budget);
    Pager pager(source, pagerOptionsFor(budget, args));
    std::mt19937 rng(args.seed);
    const std::vector<SurfacePoint> surface = surfacePoints(pager, rng);
    const double finest = finestDistance(pager, args.size, args.lodPixels);
    std::set<std::uint32_t> everEvicted;
    plot::Series curve{text, {}};
    const auto budgetStart = std::chrono::steady_clock::now();
    std::vector<std::uint64_t> rss;
    for (std::size_t round = 0;; ++round) {
      const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - budgetStart).count();
      if (t >= perBudget && round > 0) break;
      const std::string& kind = kKinds[round % kKinds.size()];
      const std::vector<Camera> cameras =
          sequence(kind, surface, pager.transform(), finest, args.frames, args.size, rng);
      const SequenceResult r =
          runSequence(pager, cameras, render, args.timeout, everEvicted, text + ", " + kind);
      if (r.violated) throw std::runtime_error("stress: an invariant was violated (see above)");
      rss.push_back(residentBytes());
      const double now = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      curve.points.push_back({now, double(rss.back()) / double(1 << 20)});
      csv << now << ',' << budget << ',' << kind << ',' << r.loads << ',' << r.evictions << ',' << r.cancelled
          << ',' << r.reloads << ',' << r.maxResident << ',' << rss.back() << '\n';
      table.addRow(rowOf(text, kind, r, args.timeout));
      spdlog::info("{:.0f} s: {} {}: {} loads, {} evictions, resident set {}", now, text, kind, r.loads,
                   r.evictions, formatBytes(rss.back()));
    }
    // Flat: the second half's peak within the allowance of the first half's.
    const std::size_t half = rss.size() / 2;
    const std::uint64_t first = *std::max_element(rss.begin(), rss.begin() + std::max<std::size_t>(half, 1));
    const std::uint64_t second = *std::max_element(rss.begin() + half, rss.end());
    if (double(second) > double(first) * (1.0 + kSoakGrowthShare) + double(kSoakGrowthBytes))
      leaks.push_back(text + ": resident set grew from " + formatBytes(first) + " to " + formatBytes(second));
    curves.push_back(std::move(curve));
  }
  csv.close();
  if (!csv) throw std::runtime_error(csvPath.string() + ": cannot write");
  const std::filesystem::path plotPath = std::filesystem::path(args.output) / "soak_rss.png";
  plot::writePlot(plotPath, {{"resident set of the process during the soak, per budget", curves}}, "seconds",
                  "resident set (MiB)", plot::Scale::Linear, plot::Scale::Linear, 1000, 700);
  printTitle("svo stress " + args.input + " soak, " + fmt::format("{:g}", args.minutes) + " minutes");
  table.print();
  std::printf("wrote %s and %s\n", csvPath.c_str(), plotPath.c_str());
  for (const std::string& leak : leaks) throw std::runtime_error("stress soak: " + leak);
}

}  // namespace

void addStressCommand(CLI::App& app) {
  auto args = std::make_shared<StressArgs>();
  auto* cmd =
      app.add_subcommand("stress", "memory-budget stress test: hostile camera sequences against budgets");
  cmd->add_option("input", args->input, "a .svo store: a file, or its http(s):// URL on a static server")
      ->required()
      ->check(storeLocator());
  addTokenOption(cmd, args->token);
  addRangeOnlyFlag(cmd, args->rangeOnly);
  cmd->add_option("--budgets", args->budgets, "pool budgets, e.g. 4M,64M (default 4M,64M)")
      ->delimiter(',')
      ->transform(CLI::AsSizeValue(false));
  cmd->add_option("--frames", args->frames, "frames per sequence")
      ->check(CLI::Range(2, 100000))
      ->capture_default_str();
  cmd->add_option("--size", args->size, "frame width and height")
      ->check(CLI::Range(8, 4096))
      ->capture_default_str();
  cmd->add_option("--seed", args->seed, "random sequence seed")->capture_default_str();
  cmd->add_option("--lod-pixels", args->lodPixels, "target voxel size in pixels")
      ->check(finiteRange(0.01, 64.0))
      ->capture_default_str();
  cmd->add_option("--timeout", args->timeout, "seconds the final view may take to converge")
      ->check(finitePositive())
      ->capture_default_str();
  cmd->add_option("--minutes", args->minutes,
                  "soak: repeat the sequences this long, recording the resident set (must stay flat)")
      ->check(finitePositive());
  addAttributeLayoutFlag(*cmd, args->attributes);
  addPoolLayoutFlag(*cmd, args->layout);
  cmd->add_option("-o,--output", args->output, "with --minutes: folder for soak.csv and soak_rss.png")
      ->capture_default_str();
  cmd->callback([args] { args->minutes > 0.0 ? runSoak(*args) : runStress(*args); });
}

}  // namespace svo::tools
