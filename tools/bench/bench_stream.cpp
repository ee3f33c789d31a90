// `svo bench stream IN.svo`: the paging client's numbers, each against its reference in the same
// run:
//   - open to first complete coarse image (cold file), goal < 100 ms;
//   - a close-up view from a cold start until nothing inside its frustum is left to load, against reading the
//     slices resident then sequentially from the cold file, goal <= 1.5x; then until the slices around it
//     (wanted for turns) are in too; with the error of every frame against the converged one over time, one
//     curve per budget (error_vs_time.png);
//   - frame time while streaming a camera path, p99, against the same path with everything resident, goal
//     <= 1.5x;
//   - where the pager workers' CPU time goes during the close-up (read, assemble, decode, layout);
//   - what the view / seq goal asks of this machine: the same slices only read and decompressed by as many
//     threads as the pager has workers (the part of a load no decode or layout work can remove), and the
//     cores the workers' CPU until the view converged would need to finish within 1.5x the sequential read.
// IN.svo may be an http(s):// URL: the pager then reads by range requests, and the sequential reference
// reads the same slices over the same link, one request after another (the server's cache stays warm);
// --link-delay puts a relay adding a one-way delay in front of an http:// server (link_delay.hpp).
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <thread>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <glm/geometric.hpp>

#include "bench_common.hpp"
#include "link_flags.hpp"
#include "measure.hpp"
#include "number_checks.hpp"
#include "pager_flags.hpp"
#include "plot.hpp"
#include "remote.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/stream_source.hpp"
#include "svo/client/streaming.hpp"

namespace svo::tools::bench {
namespace {

struct StreamArgs {
  std::string input, output = "stream-report", token;
  bool rangeOnly = false;
  std::vector<std::size_t> budgets{std::size_t(32) << 20, std::size_t(256) << 20};
  int size = 512, runs = 3, pathFrames = 120;
  PagerOptions pager;        // threads; the budget is set per measurement
  int backgroundLoad = 0;    // busy threads at normal priority beside the bench
  double linkDelayMs = 0.0;  // one-way delay a relay adds in front of an http:// input
  double linkRate = 0.0;     // bits per second of that relay's link (0: unbounded)
  float lodPixels = 1.0f;
  double timeout = 300.0;
};

// `threads` threads that keep a core busy each at normal priority until destroyed: other programs on the
// machine, as a viewer on a desktop always has them.
class BackgroundLoad {
 public:
  explicit BackgroundLoad(int threads) {
    for (int i = 0; i < threads; ++i)
      threads_.emplace_back([](std::stop_token stop) {
        volatile std::uint64_t sink = 0;
        while (!stop.stop_requested())
          for (int k = 0; k < 100000; ++k) sink = sink * 6364136223846793005u + 1442695040888963407u;
      });
  }

 private:
  std::vector<std::jthread> threads_;
};

double since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

std::vector<std::uint32_t> inFileOrder(const StoreReader& store, std::vector<std::uint32_t> slices) {
  std::sort(slices.begin(), slices.end(), [&](std::uint32_t a, std::uint32_t b) {
    return store.slices()[a].offset < store.slices()[b].offset;
  });
  return slices;
}

// Reads the slices' compressed bytes in file order with one thread from the cold file (pread), or over the
// link one request after another: the sequential reference.
double readSequentially(const StoreReader& store, const std::vector<std::uint32_t>& slices) {
  const std::vector<std::uint32_t> order = inFileOrder(store, slices);
  dropFileCache(store.path());
  std::vector<std::byte> buffer;
  const auto start = std::chrono::steady_clock::now();
  for (const std::uint32_t s : order) {
    const SliceInfo& info = store.slices()[s];
    buffer.resize(info.compressedBytes);
    if (store.source().read(info.offset, buffer) != buffer.size())
      throw std::runtime_error(store.path().string() + ": slice " + std::to_string(s) + " is truncated");
  }
  return since(start);
}

// The slices read, checksummed and decompressed as the pager's workers do (StoreReader::readSlice), by
// `threads` threads in file order from the cold file: a load's floor, before any decode or layout.
double readAndDecompress(const StoreReader& store, const std::vector<std::uint32_t>& slices, int threads) {
  const std::vector<std::uint32_t> order = inFileOrder(store, slices);
  dropFileCache(store.path());
  const auto start = std::chrono::steady_clock::now();
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, order.size(), 1),
                      [&](const tbb::blocked_range<std::size_t>& range) {
                        for (std::size_t i = range.begin(); i != range.end(); ++i)
                          (void)store.readSlice(order[i]);
                      });
  });
  return since(start);
}

// The goal for a cold close-up: the view converged within this many times the sequential read of its slices.
constexpr double kViewOverSequentialGoal = 1.5;

// The workers' goal in CPU time: every stage together at most 10 ns per voxel added to the pool, what keeps
// a core's loads at a disk's sequential rate on the stores measured; where the disk outruns even zstd, the
// goal that is left.
constexpr double kVoxelsPerCoreSecondGoal = 100e6;

// The close-up stands this fraction of the scene size from the surface: near enough that a 256-512 pixel
// frame wants the bunny's finest levels.
constexpr double kCloseUpDistance = 0.04;

std::vector<Camera> orbitPath(const SceneTransform& scene, int frames, int size) {
  const glm::dvec3 centre = scene.origin + 0.5 * scene.size;
  std::vector<Camera> out;
  for (int i = 0; i < frames; ++i) {
    const double s = double(i) / std::max(1, frames - 1), a = 2.0 * s;
    Camera c;
    c.width = c.height = size;
    c.fovYDegrees = 40.0;
    c.target = centre;
    const double d = scene.size * (1.6 - 1.1 * s);
    c.eye = centre + glm::dvec3(d * std::sin(a), 0.3 * scene.size, d * std::cos(a));
    out.push_back(c);
  }
  return out;
}

PagerOptions pagerOptionsOf(const StreamArgs& args, std::size_t budget) {
  PagerOptions options = args.pager;
  options.budgetBytes = budget;
  options.fetchThreads = resolvedFetchThreads(options.fetchThreads, args.input);
  return options;
}

// Seconds from opening the cold store to the first coarse image, per run.
std::vector<double> measureFirstImage(const StreamArgs& args, const PagerOptions& pagerOptions,
                                      const RenderOptions& options) {
  std::vector<double> firstImage;
  for (int run = 0; run < args.runs; ++run) {
    dropFileCache(args.input);
    const auto start = std::chrono::steady_clock::now();
    Pager pager(openSliceSource(args.input, remoteOptions(args.token, args.rangeOnly)), pagerOptions);
    const Camera framing = Camera::framing(pager.transform(), kDefaultViewDirection, args.size, args.size);
    render(pager, framing, options);
    firstImage.push_back(since(start));
  }
  return firstImage;
}

// The close-up from a cold start, per run: until the view converges (nothing inside the frustum left to
// load), the bytes read by then and the same bytes read sequentially; then until everything around it is
// in too; the workers' CPU; and the first run's error against the converged frame over time.
struct CloseUp {
  std::vector<double> viewConverge, converge, imageFinal, sequential, decompressed, viewCpu,
      bytesPerCpuSecond;
  std::vector<double> requests,
      retries;  // over HTTP: attempts until all converged, and the retries among them
  std::vector<WorkerCpu> cpu;
  std::vector<StreamStats> stream;  // from svo serve's view stream
  std::uint64_t viewBytes = 0, bytes = 0;
  plot::Series errorCurve;
};
CloseUp measureCloseUp(const StreamArgs& args, const PagerOptions& pagerOptions,
                       const RenderOptions& options) {
  CloseUp r;
  r.errorCurve.name = formatBytes(pagerOptions.budgetBytes);
  for (int run = 0; run < args.runs; ++run) {
    dropFileCache(args.input);
    const RemoteOptions remote = remoteOptions(args.token, args.rangeOnly);
    const std::shared_ptr<const ByteSource> bytes = openByteSource(args.input, remote);
    const std::shared_ptr<const SliceSource> source = sliceSourceOver(bytes, args.input, remote);
    Pager pager(source, pagerOptions);
    const Camera camera = closeUp(TrunkBlock(pager).view(), pager.transform(), args.size, kCloseUpDistance);
    std::vector<std::pair<double, Frame>> frames;
    const Convergence c =
        convergeView(pager, camera, options, args.timeout, nullptr, [&](double t, StreamedFrame& step) {
          if (run == 0) frames.push_back({t, std::move(step.frame)});
        });
    if (!c.converged())
      throw std::runtime_error(args.input + ": the close-up did not converge within the timeout");
    r.viewConverge.push_back(c.viewSeconds);
    r.converge.push_back(c.seconds);
    r.imageFinal.push_back(c.imageFinalSeconds);
    r.viewBytes = c.viewBytesRead;
    r.bytes = pager.bytesRead();
    r.cpu.push_back(pager.workerCpu());
    r.bytesPerCpuSecond.push_back(double(r.bytes) / std::max(1e-9, r.cpu.back().seconds()));
    const StoreReader store(openByteSource(args.input, remote));
    r.sequential.push_back(readSequentially(store, c.viewResidentSlices));
    r.decompressed.push_back(readAndDecompress(store, c.viewResidentSlices, args.pager.decodeThreads));
    r.viewCpu.push_back(c.viewWorkerCpu.seconds());
    if (const auto* http = dynamic_cast<const HttpByteSource*>(bytes.get())) {
      r.requests.push_back(double(http->stats().requests));
      r.retries.push_back(double(http->stats().retries));
    }
    if (const auto* stream = dynamic_cast<const ViewStreamSource*>(source.get()))
      r.stream.push_back(stream->stats());
    if (run == 0)
      for (const auto& [t, frame] : frames)
        r.errorCurve.points.push_back(
            {t, std::max(kSmallestPlottedError, frameError(frame, frames.back().second).rmse)});
  }
  return r;
}

// A frame's linear RGB at 8 bits per channel: a path's streaming frames wait in this form (3 bytes a pixel
// instead of 16) until the resident ones are rendered.
using CompactColors = std::vector<std::array<std::uint8_t, 3>>;
CompactColors compactColors(const Frame& frame) {
  CompactColors out(frame.color.size());
  for (std::size_t i = 0; i < out.size(); ++i)
    for (int c = 0; c < 3; ++c)
      out[i][c] = std::uint8_t(std::lround(255.0f * std::clamp(frame.color[i][c], 0.0f, 1.0f)));
  return out;
}
// Both compacted alike, so that equal frames differ by nothing.
double compactRmse(const CompactColors& a, const CompactColors& b) {
  double squares = 0.0;
  for (std::size_t i = 0; i < a.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      const double d = (double(a[i][c]) - double(b[i][c])) / 255.0;
      squares += d * d;
    }
  return std::sqrt(squares / double(3 * std::max<std::size_t>(1, a.size())));
}

// A camera path streaming from a cold file, against the same path with everything each frame wants
// resident; per run, as one stall decides a p99. What the streaming frames lack, against the resident ones,
// is the price of keeping their times.
struct PathTimes {
  std::vector<double> streamP99s, residentP99s, p99Ratios;
  std::vector<double> meanRmses;  // per run: the streaming frames' RMSE against the resident ones, mean
  std::size_t maxResident = 0;
};
PathTimes measurePath(const StreamArgs& args, const PagerOptions& pagerOptions,
                      const RenderOptions& options) {
  PathTimes r;
  for (int run = 0; run < args.runs; ++run) {
    dropFileCache(args.input);
    Pager pager(openSliceSource(args.input, remoteOptions(args.token, args.rangeOnly)), pagerOptions);
    std::vector<double> streaming, resident;
    std::vector<CompactColors> streamed;
    for (const Camera& c : orbitPath(pager.transform(), args.pathFrames, args.size)) {
      const StreamedFrame step = streamFrame(pager, c, options);
      streaming.push_back(step.seconds());
      r.maxResident = std::max(r.maxResident, step.stats.residentBytes);
      streamed.push_back(compactColors(step.frame));
    }
    double rmseSum = 0.0;
    for (const Camera& c : orbitPath(pager.transform(), args.pathFrames, args.size)) {
      convergeView(pager, c, options, args.timeout);
      const StreamedFrame step = streamFrame(pager, c, options);
      resident.push_back(step.seconds());
      rmseSum += compactRmse(streamed[resident.size() - 1], compactColors(step.frame));
    }
    r.streamP99s.push_back(percentile(streaming, 0.99));
    r.residentP99s.push_back(percentile(resident, 0.99));
    r.p99Ratios.push_back(r.streamP99s.back() / r.residentP99s.back());
    r.meanRmses.push_back(rmseSum / double(resident.size()));
  }
  return r;
}

// The median over the runs of a worker-CPU figure.
template <class Field>
double medianCpu(const CloseUp& closeUp, Field field) {
  std::vector<double> values;
  for (const WorkerCpu& c : closeUp.cpu) values.push_back(double(field(c)));
  return summarize(values).median;
}

double voxelsPerCoreSecond(const CloseUp& closeUp) {
  return medianCpu(closeUp, [](const WorkerCpu& c) { return c.voxelsDecoded; }) /
         std::max(1e-9, medianCpu(closeUp, [](const WorkerCpu& c) { return c.seconds(); }));
}

// Where the workers' time went until the close-up had converged (medians per stage over the runs).
void addCpuRow(Table& table, std::size_t budget, const CloseUp& closeUp) {
  const auto median = [&](auto field) { return medianCpu(closeUp, field); };
  const double cpuSeconds = median([](const WorkerCpu& c) { return c.seconds(); });
  const double decoded = median([](const WorkerCpu& c) { return c.voxelsDecoded; });
  char nanosPerVoxel[32], perCore[32], bytesPerCpu[32], busy[32];
  std::snprintf(nanosPerVoxel, sizeof nanosPerVoxel, "%.0f ns", 1e9 * cpuSeconds / std::max(1.0, decoded));
  std::snprintf(perCore, sizeof perCore, "%.0f M", decoded / std::max(1e-9, cpuSeconds) / 1e6);
  std::snprintf(bytesPerCpu, sizeof bytesPerCpu, "%.0f MB/s",
                summarize(closeUp.bytesPerCpuSecond).median / 1e6);
  std::snprintf(busy, sizeof busy, "%.2f", cpuSeconds / std::max(1e-9, summarize(closeUp.converge).median));
  table.addRow({formatBytes(budget), formatSeconds(median([](const WorkerCpu& c) { return c.readSeconds; })),
                formatSeconds(median([](const WorkerCpu& c) { return c.assembleSeconds; })),
                formatSeconds(median([](const WorkerCpu& c) { return c.decodeSeconds; })),
                formatSeconds(median([](const WorkerCpu& c) { return c.layoutSeconds; })),
                formatSeconds(median([](const WorkerCpu& c) { return c.poolPagesSeconds; })),
                formatSeconds(cpuSeconds), busy, formatCount(std::uint64_t(decoded)),
                formatCount(std::uint64_t(median([](const WorkerCpu& c) { return c.voxelsLaidOut; }))),
                nanosPerVoxel, perCore, bytesPerCpu});
}

void runStreamBench(StreamArgs args) {
  const std::string input = args.input;
  const std::unique_ptr<LinkDelay> link = delayLink(args.input, args.linkDelayMs, args.linkRate);
  keepFreedMemoryForReuse();
  requireRuns(args.runs);
  std::filesystem::create_directories(args.output);
  const BackgroundLoad load(args.backgroundLoad);
  RenderOptions options;
  options.lodPixels = args.lodPixels;
  Table table({"budget", "first image", "view converged", "image final", "bytes read", "sequential read",
               "view / seq", "all converged", "all read", "stream p99", "resident p99", "p99 ratio",
               "path RMSE", "max resident"});
  Table cpuTable({"budget", "read + zstd", "assemble", "decode", "layout", "pool pages", "worker CPU",
                  "CPU / wall", "voxels decoded", "voxels laid out", "CPU per voxel", "voxels per core s",
                  "bytes per CPU s"});
  const std::string goal = fmt::format("{:g}x", kViewOverSequentialGoal);
  Table goalTable({"budget", "sequential read", "read + zstd alone", "alone / seq", "worker CPU to view",
                   "cores for " + goal});
  std::vector<plot::Series> curves;
  std::vector<std::string> requestLines;      // over HTTP
  std::vector<std::string> diskOutrunsLines;  // budgets where reading and zstd alone miss the goal
  for (const std::size_t budget : args.budgets) {
    const PagerOptions pagerOptions = pagerOptionsOf(args, budget);
    const std::vector<double> firstImage = measureFirstImage(args, pagerOptions, options);
    const CloseUp closeUp = measureCloseUp(args, pagerOptions, options);
    curves.push_back(closeUp.errorCurve);
    const PathTimes path = measurePath(args, pagerOptions, options);
    const Summary first = summarize(firstImage), view = summarize(closeUp.viewConverge),
                  all = summarize(closeUp.converge), seq = summarize(closeUp.sequential),
                  final = summarize(closeUp.imageFinal);
    const double streamP99 = summarize(path.streamP99s).median,
                 residentP99 = summarize(path.residentP99s).median;
    char ratio[32], p99ratio[32];
    std::snprintf(ratio, sizeof ratio, "%.2fx", view.median / seq.median);
    std::snprintf(p99ratio, sizeof p99ratio, "%.2fx", summarize(path.p99Ratios).median);
    addCpuRow(cpuTable, budget, closeUp);
    const double alone = summarize(closeUp.decompressed).median, toView = summarize(closeUp.viewCpu).median;
    char aloneRatio[32], cores[32];
    std::snprintf(aloneRatio, sizeof aloneRatio, "%.2fx", alone / seq.median);
    std::snprintf(cores, sizeof cores, "%.1f", toView / (kViewOverSequentialGoal * seq.median));
    goalTable.addRow({formatBytes(budget), formatSeconds(seq.median), formatSeconds(alone), aloneRatio,
                      formatSeconds(toView), cores});
    if (alone > kViewOverSequentialGoal * seq.median)
      diskOutrunsLines.push_back(fmt::format(
          "{}: the disk outruns zstd alone ({}) on a store this compact, so no decoder reaches view / seq <= "
          "{}; the goal left is the workers' voxels per core second: {:.0f} M against {:.0f} M",
          formatBytes(budget), aloneRatio, goal, voxelsPerCoreSecond(closeUp) / 1e6,
          kVoxelsPerCoreSecondGoal / 1e6));
    table.addRow({formatBytes(budget), formatSeconds(first.median), formatSeconds(view.median),
                  formatSeconds(final.median), formatBytes(closeUp.viewBytes), formatSeconds(seq.median),
                  ratio, formatSeconds(all.median), formatBytes(closeUp.bytes), formatSeconds(streamP99),
                  formatSeconds(residentP99), p99ratio,
                  fmt::format("{:.4f}", summarize(path.meanRmses).median), formatBytes(path.maxResident)});
    if (!closeUp.requests.empty()) {
      const double requests = summarize(closeUp.requests).median;
      requestLines.push_back(
          fmt::format("{}: {:.0f} requests until all converged ({:.0f} retries), {} per request",
                      formatBytes(budget), requests, summarize(closeUp.retries).median,
                      formatBytes(std::uint64_t(double(closeUp.bytes) / requests))));
    }
    if (!closeUp.stream.empty()) {
      const auto median = [&](auto field) {
        std::vector<double> values;
        for (const StreamStats& s : closeUp.stream) values.push_back(double(field(s)));
        return summarize(values).median;
      };
      requestLines.push_back(
          closeUp.stream.front().declined
              ? formatBytes(budget) + ": the server has no view stream (range requests only)"
              : fmt::format(
                    "{}: view stream: {:.0f} slices pushed ({:.0f} fetched from them), {:.0f} read by "
                    "range, {:.0f} views sent",
                    formatBytes(budget), median([](const StreamStats& s) { return s.pushed; }),
                    median([](const StreamStats& s) { return s.usedPushed; }),
                    median([](const StreamStats& s) { return s.pulled; }),
                    median([](const StreamStats& s) { return s.viewsSent; })));
    }
  }
  const std::filesystem::path plotPath = std::filesystem::path(args.output) / "error_vs_time.png";
  plot::writeLogLogPlot(plotPath, {{"close-up from a cold start: RMSE against the converged frame", curves}},
                        "seconds since the first frame", "RMSE (linear RGB)", 1000, 700);
  printTitle(
      "svo bench stream " + input +
      (link ? " through " + linkDescription(args.linkDelayMs, args.linkRate) : "") + " (" +
      std::to_string(args.size) + "^2, LOD " + std::to_string(args.lodPixels) + " px, median of " +
      std::to_string(args.runs) + " runs, " +
      fmt::format("{} fetch and {} decode threads at nice {}, {} / {} decoding during still / moving frames",
                  pagerOptionsOf(args, 0).fetchThreads, args.pager.decodeThreads, args.pager.workerNice,
                  args.pager.decodersDuringFrames, args.pager.decodersDuringMovingFrames) +
      (args.backgroundLoad ? fmt::format(", background load: {} busy threads", args.backgroundLoad) : "") +
      ")");
  table.print();
  for (const std::string& line : requestLines)
    std::printf("over HTTP, the close-up from a cold start: %s\n", line.c_str());
  std::printf(
      "view converged: nothing inside the close-up's frustum left to load (bytes read: by then); all "
      "converged: also the slices around it, wanted for turns\n"
      "p99 ratio: the median over the runs of each run's streaming p99 / resident p99 (the p99 columns: "
      "medians); path RMSE: each streaming frame of the path against the resident one (linear RGB at 8 "
      "bits), the mean over the path: the detail the frames lack while streaming (median over the runs)\n"
      "goals: first image < 100 ms; view / seq <= 1.5x; streaming p99 <= 1.5x resident p99\n");
  printTitle("pager workers' CPU during the close-up, until all converged (thread CPU time, medians)");
  cpuTable.print();
  std::printf(
      "assemble: the levels a load builds on, read back from the pool (a region's own, or its parent "
      "region's below its cube); layout: voxel tree and block layout; pool pages: the pool's pages mapped on "
      "first use (the first fill only)\n"
      "CPU / wall: cores busy on average; voxels per core s: voxels decoded per worker CPU second (goal: "
      "%.0f M); bytes per CPU s: compressed bytes read per worker CPU second (view / seq <= %s needs the "
      "workers to keep up with the disk: about its sequential rate per busy core)\n",
      kVoxelsPerCoreSecondGoal / 1e6, goal.c_str());
  printTitle("what view / seq <= " + goal + " asks of this machine (medians)");
  goalTable.print();
  std::printf(
      "read + zstd alone: the view's slices read, checksummed and decompressed by %d threads from the cold "
      "file, no decode or layout; cores for %s: the workers' CPU until the view converged / (%g x "
      "sequential read), the cores it would take with perfect parallelism\n",
      args.pager.decodeThreads, goal.c_str(), kViewOverSequentialGoal);
  for (const std::string& line : diskOutrunsLines) std::printf("%s\n", line.c_str());
  std::printf("wrote %s\n", plotPath.c_str());
}

}  // namespace

void addStreamBench(CLI::App& bench) {
  auto args = std::make_shared<StreamArgs>();
  auto* cmd = bench.add_subcommand("stream",
                                   "paging client: first image, cold convergence vs sequential read, "
                                   "streaming frame time vs resident, error over time");
  cmd->add_option("input", args->input, "a .svo store: a file, or its http(s):// URL on a static server")
      ->required()
      ->check(storeLocator());
  addTokenOption(cmd, args->token);
  addRangeOnlyFlag(cmd, args->rangeOnly);
  cmd->add_option("--budgets", args->budgets, "pool budgets, e.g. 32M,256M (default 32M,256M)")
      ->delimiter(',')
      ->transform(CLI::AsSizeValue(false));
  cmd->add_option("-o,--output", args->output, "folder for error_vs_time.png")->capture_default_str();
  cmd->add_option("--size", args->size, "frame width and height")
      ->check(CLI::Range(8, 4096))
      ->capture_default_str();
  cmd->add_option("--runs", args->runs, "cold runs per measurement; the median is reported")
      ->capture_default_str();
  cmd->add_option("--frames", args->pathFrames, "frames of the camera path")
      ->check(CLI::Range(2, 100000))
      ->capture_default_str();
  cmd->add_option("--lod-pixels", args->lodPixels, "target voxel size in pixels")
      ->check(finiteRange(0.01, 64.0))
      ->capture_default_str();
  addPagerThreadFlags(*cmd, args->pager);
  addAttributeLayoutFlag(*cmd, args->pager.attributes);
  addPoolLayoutFlag(*cmd, args->pager.layout);
  cmd->add_option("--background-load", args->backgroundLoad,
                  "busy threads at normal priority running beside the bench: streaming with other programs "
                  "on the cores")
      ->check(CLI::Range(0, 256))
      ->capture_default_str();
  addLinkFlags(*cmd, args->linkDelayMs, args->linkRate, "for an http:// URL");
  cmd->callback([args] { runStreamBench(*args); });
}

}  // namespace svo::tools::bench
