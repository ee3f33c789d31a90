// `svo bench quality MESH --stream`: the store of the deepest --levels streams in from a cold file through a
// block pool of each --budgets size; the errors of the frames against the triangle reference are plotted
// against the elapsed time from opening the store, one curve per budget (stream.md, stream.csv,
// error-vs-time-streaming.png).
#include <chrono>
#include <memory>

#include <spdlog/spdlog.h>

#include "bench_quality.hpp"
#include "measure.hpp"
#include "plot.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/streaming.hpp"
#include "text_file.hpp"

namespace svo::tools::bench {
namespace {

// --stream keeps a frame for comparison when it comes this many times later than the last one kept (and
// always the first and the converged one): even steps on the log time axis, bounded memory.
constexpr double kStreamKeepRatio = 1.1;
// --stream looks at the surface from this fraction of the scene size: near enough to want the finest levels
// of an 11-level store at 512 pixels, far enough to keep silhouettes in view.
constexpr double kStreamViewDistance = 0.3;

}  // namespace

// From a cold store, frames of one camera while the store streams in; each kept frame's error against the
// triangle reference, by elapsed time since the store was opened.
void runStreamingQuality(const QualityArgs& args, const Mesh& mesh, int threads, int levels) {
  keepFreedMemoryForReuse();
  const std::filesystem::path out = args.out;
  LevelScene level;  // the store is scratch: gone however this ends
  BuildOptions build;
  build.levels = levels;
  build.leafContourMinReduction = args.contourCuts.front();
  buildLevel(mesh, build, out, false, level);
  const std::filesystem::path& store = level.store;
  const double finestVoxel = level.transform.size / double(std::int64_t(1) << levels);
  RenderOptions options;
  options.threads = threads;
  options.lodPixels = 1.0f;
  // A close-up, so the view wants the finest levels and the curve has somewhere to go.
  const Camera camera = closeUp(Pager(store).trunk(), level.transform, args.size, kStreamViewDistance);
  const std::unique_ptr<accel::Accel> kd = buildReference(mesh);
  const Image reference = renderReference(mesh, *kd, camera, options, threads);
  writePng(out / "stream-reference.png", reference);

  std::vector<plot::Panel> panels;
  for (const auto& [title, metric] : kPlottedErrors) panels.push_back({title, {}});
  Table table({"budget", "first frame", "converged", "read", "first RMSE", "first silhouette", "final RMSE",
               "final depth p99", "final silhouette"});
  std::string csv = "budget_bytes,seconds,rmse,psnr_db,depth_mean_vox,depth_p99_vox,silhouette_pct\n";
  for (const std::size_t budget : args.budgets) {
    PagerOptions pagerOptions;
    pagerOptions.budgetBytes = budget;
    dropFileCache(store);
    const auto opened = std::chrono::steady_clock::now();
    const auto since = [&] {
      return std::chrono::duration<double>(std::chrono::steady_clock::now() - opened).count();
    };
    Pager pager(store, pagerOptions);
    std::vector<std::pair<double, Frame>> kept;
    StreamedFrame last;
    const Convergence converged =
        convergeView(pager, camera, options, args.timeout, &last, [&](double, StreamedFrame& step) {
          const double t = since();
          if (kept.empty() || t >= kStreamKeepRatio * kept.back().first) kept.push_back({t, step.frame});
        });
    if (!converged.converged())
      throw std::runtime_error(fmt::format("{}: the view did not converge within {} s at a {} budget",
                                           store.string(), args.timeout, formatBytes(budget)));
    kept.push_back({since(), std::move(last.frame)});
    writePng(out / fmt::format("stream-{}K.png", budget >> 10), imageOf(Frame(kept.back().second)));
    std::vector<Measured> series;
    for (auto& [t, frame] : kept) {
      Measured m;
      m.seconds = t;
      m.image = imageOf(std::move(frame));
      compare(reference, m.image, finestVoxel, m);
      m.image = {};
      csv += fmt::format("{},{:.6f},{:.6f},{:.3f},{:.4f},{:.4f},{:.4f}\n", budget, t, m.rmse, m.psnr,
                         m.depthMean, m.depthTail, m.silhouettePercent);
      series.push_back(std::move(m));
    }
    for (std::size_t k = 0; k < kPlottedErrors.size(); ++k) {
      plot::Series curve{formatBytes(budget), {}};
      for (const Measured& m : series)
        curve.points.push_back({m.seconds, std::max(m.*kPlottedErrors[k].second, kSmallestPlottedError)});
      panels[k].series.push_back(std::move(curve));
    }
    const Measured &first = series.front(), &final = series.back();
    table.addRow({formatBytes(budget), formatSeconds(first.seconds), formatSeconds(final.seconds),
                  formatBytes(pager.bytesRead()), fmt::format("{:.4f}", first.rmse),
                  fmt::format("{:.2f}%", first.silhouettePercent), fmt::format("{:.4f}", final.rmse),
                  fmt::format("{:.3f}", final.depthTail), fmt::format("{:.2f}%", final.silhouettePercent)});
  }
  const std::string title = fmt::format(
      "Error against elapsed time while streaming {} levels from a cold store (close-up, {}x{}, 1 voxel per "
      "pixel)",
      levels, args.size, args.size);
  printTitle(title);
  table.print();
  plot::writeLogLogPlot(out / "error-vs-time-streaming.png", panels, "seconds since the store was opened",
                        "error against the triangle reference (log)");
  writeTextFile(out / "stream.csv", csv);
  writeTextFile(
      out / "stream.md",
      fmt::format(
          "# svo bench quality --stream: {}\n\n{}. Reference: kd-tree ray cast of the mesh. Frames kept when "
          "{}x later than the last kept one.\n\n![error against elapsed "
          "time](error-vs-time-streaming.png)\n\n"
          "Per frame: `stream.csv`.\n",
          args.mesh, title, kStreamKeepRatio));
  fmt::print("report: {}, plot: {}, per-frame errors: {}\n", (out / "stream.md").string(),
             (out / "error-vs-time-streaming.png").string(), (out / "stream.csv").string());
}

}  // namespace svo::tools::bench
