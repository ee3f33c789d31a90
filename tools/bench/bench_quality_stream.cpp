// `svo bench quality MESH --stream`: the store of the deepest --levels streams in from a cold start through a
// block pool of each --budgets size, from each of --sources: the file read in place, svo serve (in process)
// by its view stream or by range requests only, nginx by range requests; the servers on loopback, behind a
// relay adding --link-delay and --link-rate when given. The errors of the frames against the triangle
// reference are plotted against the elapsed time from opening the store, one curve per source and budget
// (stream.md, stream.csv, error-vs-time-streaming.png).
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <optional>
#include <string_view>

#include <spdlog/spdlog.h>

#include "bench_quality.hpp"
#include "link_flags.hpp"
#include "measure.hpp"
#include "nginx_peer.hpp"
#include "plot.hpp"
#include "remote.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/stream_source.hpp"
#include "svo/client/streaming.hpp"
#include "svo/server/server.hpp"
#include "text_file.hpp"

namespace svo::tools::bench {
namespace {

namespace fs = std::filesystem;

// --stream keeps a frame for comparison when it comes this many times later than the last one kept (and
// always the first and the converged one): even steps on the log time axis, bounded memory.
constexpr double kStreamKeepRatio = 1.1;
// --stream looks at the surface from this fraction of the scene size: near enough to want the finest levels
// of an 11-level store at 512 pixels, far enough to keep silhouettes in view.
constexpr double kStreamViewDistance = 0.3;
// The nginx binary the nginx source runs (Debian's nginx-light puts it on PATH).
constexpr const char* kNginx = "nginx";

const std::string& nameOf(const std::string& word) {
  return std::find_if(kStreamSources.begin(), kStreamSources.end(),
                      [&](const auto& s) { return s.first == word; })
      ->second;
}

// What every run looks at: the store, the close-up and its triangle reference.
struct StreamScene {
  fs::path store;
  Camera camera;
  RenderOptions options;
  Image reference;
  double finestVoxel = 0.0;
};

// One source started for one run, from a cold start: its own server (svo serve with an empty slice cache,
// or nginx), the relay in front of it when there is a link, and the store's locator through them; the local
// file is read in place.
struct Source {
  std::unique_ptr<server::Server> serve;
  std::unique_ptr<Child> nginx;
  std::unique_ptr<LinkDelay> link;  // after the servers: stops first
  std::string locator;
  RemoteOptions remote;
};

Source startSource(const std::string& word, const QualityArgs& args, const ScratchFolder& scratch,
                   const fs::path& store, int threads) {
  Source s;
  s.locator = store.string();
  if (word == "local") return s;
  const fs::path root = scratch.path / "root";
  const std::string name = store.stem().string();
  if (word == "nginx") {
    const std::uint16_t port = freePort();
    s.nginx = startNginx(kNginx, scratch.path, root, port, threads);
    waitUntilListening(*s.nginx, port, kNginx);
    s.locator = fmt::format("http://127.0.0.1:{}/{}", port, urlSegment(name + ".svo"));
  } else {
    server::ServerOptions options;
    options.root = root;
    options.threads = unsigned(threads);
    options.logRequests = false;
    options.logSink = [](std::string_view) {};
    s.serve = std::make_unique<server::Server>(options);
    s.serve->start();
    s.locator = s.serve->url() + "/" + urlSegment(name);
  }
  s.remote.viewStream = word == "serve";
  s.link = delayLink(s.locator, args.linkDelayMs, args.linkRate);
  return s;
}

// One source at one budget from a cold start: each kept frame's error against the reference, by elapsed
// time since the store was opened; the bytes the pager read; for the view stream, what came by it.
struct Run {
  std::vector<Measured> series;
  std::uint64_t bytesRead = 0;
  std::optional<StreamStats> stream;
};

Run streamRun(const QualityArgs& args, const StreamScene& scene, const Source& source, std::size_t budget,
              const fs::path& image) {
  PagerOptions pagerOptions;
  pagerOptions.budgetBytes = budget;
  pagerOptions.fetchThreads = fetchThreadsFor(source.locator);
  dropFileCache(scene.store);
  const auto opened = std::chrono::steady_clock::now();
  const auto since = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - opened).count();
  };
  const std::shared_ptr<SliceSource> slices = openSliceSource(source.locator, source.remote);
  Pager pager(slices, pagerOptions);
  std::vector<std::pair<double, Frame>> kept;
  StreamedFrame last;
  const Convergence converged =
      convergeView(pager, scene.camera, scene.options, args.timeout, &last, [&](double, StreamedFrame& step) {
        const double t = since();
        if (kept.empty() || t >= kStreamKeepRatio * kept.back().first) kept.push_back({t, step.frame});
      });
  if (!converged.converged())
    throw std::runtime_error(fmt::format("{}: the view did not converge within {} s at a {} budget",
                                         source.locator, args.timeout, formatBytes(budget)));
  kept.push_back({since(), std::move(last.frame)});
  writePng(image, imageOf(Frame(kept.back().second)));
  Run run;
  run.bytesRead = pager.bytesRead();
  if (const auto* stream = dynamic_cast<const ViewStreamSource*>(slices.get())) run.stream = stream->stats();
  for (auto& [t, frame] : kept) {
    Measured m;
    m.seconds = t;
    m.image = imageOf(std::move(frame));
    compare(scene.reference, m.image, scene.finestVoxel, m);
    m.image = {};
    run.series.push_back(std::move(m));
  }
  return run;
}

// The runs' curves, table rows and per-frame CSV lines, as they come.
struct Report {
  std::vector<plot::Panel> panels;
  Table table{{"source", "budget", "first frame", "converged", "read", "first RMSE", "first silhouette",
               "final RMSE", "final depth p99", "final silhouette"}};
  std::string csv = "source,budget_bytes,seconds,rmse,psnr_db,depth_mean_vox,depth_p99_vox,silhouette_pct\n";
  std::vector<std::string> notes;
  Report() {
    for (const auto& [title, metric] : kPlottedErrors) panels.push_back({title, {}});
  }
};

void addRun(Report& report, const std::string& word, std::size_t budget, const Run& run) {
  const std::string curve = fmt::format("{}, {}", nameOf(word), formatBytes(budget));
  for (const Measured& m : run.series)
    report.csv += fmt::format("{},{},{:.6f},{:.6f},{:.3f},{:.4f},{:.4f},{:.4f}\n", word, budget, m.seconds,
                              m.rmse, m.psnr, m.depthMean, m.depthTail, m.silhouettePercent);
  for (std::size_t k = 0; k < kPlottedErrors.size(); ++k) {
    plot::Series series{curve, {}};
    for (const Measured& m : run.series)
      series.points.push_back({m.seconds, std::max(m.*kPlottedErrors[k].second, kSmallestPlottedError)});
    report.panels[k].series.push_back(std::move(series));
  }
  const Measured &first = run.series.front(), &final = run.series.back();
  report.table.addRow({nameOf(word), formatBytes(budget), formatSeconds(first.seconds),
                       formatSeconds(final.seconds), formatBytes(run.bytesRead),
                       fmt::format("{:.4f}", first.rmse), fmt::format("{:.2f}%", first.silhouettePercent),
                       fmt::format("{:.4f}", final.rmse), fmt::format("{:.3f}", final.depthTail),
                       fmt::format("{:.2f}%", final.silhouettePercent)});
  if (run.stream)
    report.notes.push_back(
        run.stream->declined
            ? curve + ": the server declined the view stream (range requests only)"
            : fmt::format(
                  "{}: {} slices pushed by the view stream ({} of them used), {} read by range request",
                  curve, run.stream->pushed, run.stream->usedPushed, run.stream->pulled));
}

bool overHttp(const QualityArgs& args) {
  return std::any_of(args.sources.begin(), args.sources.end(),
                     [](const std::string& s) { return s != "local"; });
}

// The close-up, its reference, and the store every source serves.
StreamScene streamScene(const QualityArgs& args, const Mesh& mesh, int threads, int levels,
                        LevelScene& level) {
  BuildOptions build;
  build.levels = levels;
  build.leafContourMinReduction = args.contourCuts.front();
  buildLevel(mesh, build, args.out, false, level);
  StreamScene scene;
  scene.store = level.store;
  scene.finestVoxel = level.transform.size / double(std::int64_t(1) << levels);
  scene.options.threads = threads;
  scene.options.lodPixels = 1.0f;
  // A close-up, so the view wants the finest levels and the curve has somewhere to go.
  scene.camera = closeUp(Pager(scene.store).trunk(), level.transform, args.size, kStreamViewDistance);
  const std::unique_ptr<accel::Accel> kd = buildReference(mesh);
  scene.reference = renderReference(mesh, *kd, scene.camera, scene.options, threads);
  writePng(fs::path(args.out) / "stream-reference.png", scene.reference);
  return scene;
}

void writeReport(const QualityArgs& args, int levels, Report& report) {
  const fs::path out = args.out;
  const std::string link = args.linkDelayMs > 0.0 || args.linkRate > 0.0
                               ? "; the servers through " + linkDescription(args.linkDelayMs, args.linkRate)
                               : "";
  const std::string title = fmt::format(
      "Error against elapsed time while streaming {} levels from a cold start (close-up, {}x{}, 1 voxel per "
      "pixel{})",
      levels, args.size, args.size, link);
  printTitle(title);
  report.table.print();
  if (overHttp(args))
    report.notes.push_back(fmt::format(
        "cold start: each run drops the store's pages from the page cache and starts its server afresh (svo "
        "serve with an empty slice cache) on loopback; the local file is read in place; the pager fetches "
        "with {} threads over HTTP, {} from the file",
        kRemoteFetchThreads, PagerOptions{}.fetchThreads));
  for (const std::string& note : report.notes) fmt::print("{}\n", note);
  plot::writeLogLogPlot(out / "error-vs-time-streaming.png", report.panels,
                        "seconds since the store was opened", "error against the triangle reference (log)");
  writeTextFile(out / "stream.csv", report.csv);
  std::string notes;
  for (const std::string& note : report.notes) notes += "- " + note + "\n";
  writeTextFile(
      out / "stream.md",
      fmt::format("# svo bench quality --stream: {}\n\n{}. Reference: kd-tree ray cast of the mesh. "
                  "Frames kept when {}x later than the last kept one.\n\n{}\n![error against elapsed "
                  "time](error-vs-time-streaming.png)\n\n"
                  "Per frame: `stream.csv`.\n",
                  args.mesh, title, kStreamKeepRatio, notes));
  fmt::print("report: {}, plot: {}, per-frame errors: {}\n", (out / "stream.md").string(),
             (out / "error-vs-time-streaming.png").string(), (out / "stream.csv").string());
}

}  // namespace

void checkStreamArgs(const QualityArgs& args) {
  for (std::size_t i = 0; i < args.sources.size(); ++i)
    if (std::count(args.sources.begin(), args.sources.begin() + i, args.sources[i]))
      throw UsageError(fmt::format("--sources: {} is listed twice", args.sources[i]));
  if ((args.linkDelayMs > 0.0 || args.linkRate > 0.0) && !overHttp(args))
    throw UsageError(
        "--link-delay and --link-rate need a source over HTTP (--sources serve, serve-range, nginx)");
}

// From a cold start, frames of one camera while the store streams in from each source at each budget; each
// kept frame's error against the triangle reference, by elapsed time since the store was opened.
void runStreamingQuality(const QualityArgs& args, const Mesh& mesh, int threads, int levels) {
  keepFreedMemoryForReuse();
  LevelScene level;  // the store is scratch: gone however this ends
  const StreamScene scene = streamScene(args, mesh, threads, levels, level);
  // The servers' folder, beside the store so that it is the same file (a hard link) on the same disk.
  const ScratchFolder scratch(fs::path(args.out) / fmt::format("stream-sources-{}", ::getpid()));
  const fs::path served = overHttp(args) ? scratch.serve(scene.store) : fs::path();
  const bool nginx = std::count(args.sources.begin(), args.sources.end(), "nginx") && onPath(kNginx);
  if (const std::string closed = nginx ? closedToNginxWorkers(served) : ""; !closed.empty())
    throw std::runtime_error(fmt::format(
        "{}: nginx's workers cannot read it (started by root, they run as another user): give -o a folder "
        "every user can read",
        closed));
  Report report;
  for (const std::string& word : args.sources) {
    if (word == "nginx" && !onPath(kNginx)) {
      report.notes.push_back(fmt::format("{}: not on PATH, the nginx source is skipped", kNginx));
      fmt::print("{}\n", report.notes.back());
      continue;
    }
    for (const std::size_t budget : args.budgets) {
      spdlog::info("streaming: {}, {} budget ...", nameOf(word), formatBytes(budget));
      const Source source = startSource(word, args, scratch, scene.store, threads);
      const fs::path image = fs::path(args.out) / fmt::format("stream-{}-{}K.png", word, budget >> 10);
      addRun(report, word, budget, streamRun(args, scene, source, budget, image));
    }
  }
  writeReport(args, levels, report);
}

}  // namespace svo::tools::bench
