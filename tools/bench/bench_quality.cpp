// `svo bench quality MESH`: error against run time for every quality knob. The exact reference is the
// triangle mesh ray cast with our kd-tree (svo::accel) under the renderer's own Phong model, with normals
// and colors interpolated from the mesh; each voxel setting (octree levels, level of detail, contours on/off,
// beam on/off) is timed (median of runs) and compared with it (bench_quality.hpp: compare). Writes a
// Markdown report, PNG plots of each error against time with the Pareto front marked, the reference image
// and difference images of the best and worst settings. --stream: bench_quality_stream.cpp.
#include <algorithm>
#include <cassert>
#include <filesystem>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <glm/common.hpp>

#include "bench_quality.hpp"
#include "link_flags.hpp"
#include "number_checks.hpp"
#include "plot.hpp"
#include "text_file.hpp"

namespace svo::tools::bench {
namespace {

// Level-of-detail settings swept (0.5, 1, 2, 4 pixels).
constexpr float kLodSweep[] = {0.5f, 1.0f, 2.0f, 4.0f};
// Beam settings swept: the paper's 8x8 tile, and off.
constexpr int kBeamSweep[] = {8, 0};
// Difference images are scaled by this so small errors are visible.
constexpr float kDifferenceGain = 4.0f;
// Goals at 1 voxel per pixel with contours: silhouette mismatch and depth p99.
constexpr double kGoalSilhouettePercent = 1.0;
constexpr double kGoalDepthVoxels = 1.0;

bool faster(const Measured* a, const Measured* b) {
  return a->seconds < b->seconds;
}

std::vector<const Measured*> sortedByTime(const std::vector<Measured>& all) {
  std::vector<const Measured*> byTime;
  for (const Measured& m : all) byTime.push_back(&m);
  std::sort(byTime.begin(), byTime.end(), faster);
  return byTime;
}

// Settings no other setting beats in both time and the error `of`.
std::vector<const Measured*> paretoFront(const std::vector<Measured>& all, double Measured::*of) {
  std::vector<const Measured*> front;
  for (const Measured& m : all) {
    const bool dominated = std::any_of(all.begin(), all.end(), [&](const Measured& o) {
      return &o != &m && o.seconds <= m.seconds && o.*of <= m.*of && (o.seconds < m.seconds || o.*of < m.*of);
    });
    if (!dominated) front.push_back(&m);
  }
  std::sort(front.begin(), front.end(), faster);
  return front;
}

// "8,9,10" as the resolutions 256,512,1024 for the shared validator (powers of two, no duplicates).
std::vector<int> parseLevels(const std::string& text) {
  std::string resolutions;
  std::stringstream list(text);
  for (std::string part; std::getline(list, part, ',');) {
    int level = 0;
    try {
      level = std::stoi(part);
    } catch (const std::exception&) {
      throw UsageError(fmt::format("--levels: '{}' is not a number", part));
    }
    if (level < 1 || level > kMaxLevels)
      throw UsageError(fmt::format("--levels: {} is not in [1, {}]", level, kMaxLevels));
    resolutions += (resolutions.empty() ? "" : ",") + std::to_string(std::int64_t(1) << level);
  }
  std::vector<int> levels;
  for (const std::int64_t r : parseResolutions(resolutions, "--levels"))
    levels.push_back(levelsOfResolution(r, "--levels"));
  return levels;
}

// The settings swept at one depth and contour cut: level of detail and beam, with contours and (for the
// first cut only: cube renders ignore contours) without; and with contours and the beam, each level of
// detail with compressed attributes (at each exact-unit angle) and with the post-process filter.
std::vector<Setting> settingsOf(int levels, float cut, bool firstCut, const LevelScene& level,
                                const std::vector<float>& filterRadii) {
  std::vector<Setting> settings;
  const auto setting = [&](float contourCut, float lod, bool contours, int beam) {
    Setting s;  // the knobs' members keep their defaults (off)
    s.levels = levels, s.contourCut = contourCut, s.lod = lod, s.contours = contours, s.beam = beam;
    return s;
  };
  for (const bool contours : {true, false}) {
    if (!contours && !firstCut) continue;
    for (const float lod : kLodSweep)
      for (const int beam : kBeamSweep)
        settings.push_back(setting(contours ? cut : 0.0f, lod, contours, beam));
  }
  for (const float lod : kLodSweep) {
    const Setting plain = setting(cut, lod, true, kBeamSweep[0]);
    for (const auto& [degrees, scene] : level.compressed) {
      Setting compressed = plain;
      compressed.attributes = {AttributeLayout::Compressed, degrees};
      settings.push_back(compressed);
    }
    for (const float radius : filterRadii) {
      Setting filtered = plain;
      filtered.filterRadius = radius;
      settings.push_back(filtered);
    }
  }
  return settings;
}

// The level's octree laid out as `attributes` says.
const WholeScene& sceneFor(const LevelScene& level, const AttributeOptions& attributes) {
  if (!attributes.compressed()) return *level.scene;
  for (const auto& [degrees, scene] : level.compressed)
    if (degrees == attributes.exactNormalUnitDegrees) return scene;
  assert(false && "settingsOf lists only the compressed scenes the level has");
  return *level.scene;
}

// Every setting of every swept depth and contour cut, timed and compared with the reference.
std::vector<Measured> measureSettings(const QualityArgs& args, const Mesh& mesh,
                                      const std::vector<int>& levelList, const Camera& camera,
                                      const RenderOptions& base, const Image& reference) {
  const SceneTransform scene = fitSceneCube(mesh);
  std::vector<Measured> all;
  for (const int levels : levelList)
    for (const float cut : args.contourCuts) {
      LevelScene level;
      BuildOptions build;
      build.levels = levels;
      build.leafContourMinReduction = cut;
      buildLevel(mesh, build, args.out, true, level, args.exactNormals);
      const double finestVoxel = scene.size / double(std::int64_t(1) << levels);
      for (const Setting& setting :
           settingsOf(levels, cut, cut == args.contourCuts.front(), level, args.filterRadii)) {
        Measured m;
        m.setting = setting;
        m.buildSeconds = level.buildSeconds, m.storeBytes = level.storeBytes;
        RenderOptions options = base;
        options.lodPixels = setting.lod;
        options.cast.contours = setting.contours;
        options.beamTile = setting.beam;
        options.filter = setting.filterRadius > 0.0f;
        options.filterRadius = setting.filterRadius;
        const WholeScene& from = sceneFor(level, setting.attributes);
        m.poolBytes = from.bytes();
        Frame frame;
        m.seconds = timeRuns(args.runs, [&] { frame = render(from.root(), scene, camera, options); }).median;
        m.image = imageOf(std::move(frame));
        compare(reference, m.image, finestVoxel, m);
        all.push_back(std::move(m));
      }
    }
  return all;
}

// The table of every setting, sorted by time, printed; returns its Markdown rows.
std::string printSettings(const std::vector<Measured>& all) {
  const std::vector<const Measured*> byTime = sortedByTime(all);
  const auto front = paretoFront(all, &Measured::rmse);
  const auto onFront = [&](const Measured* m) {
    return std::find(front.begin(), front.end(), m) != front.end();
  };
  Table table({"setting", "render", "RMSE", "PSNR dB", "depth mean", "depth p99", "p99 off edges",
               "silhouette", "build", "store MB", "Pareto"});
  std::string markdown;
  for (const Measured* m : byTime) {
    table.addRow({m->setting.name(), formatSeconds(m->seconds), fmt::format("{:.4f}", m->rmse),
                  fmt::format("{:.2f}", m->psnr), fmt::format("{:.3f}", m->depthMean),
                  fmt::format("{:.3f}", m->depthTail), fmt::format("{:.3f}", m->depthTailOffEdges),
                  fmt::format("{:.3f}%", m->silhouettePercent), formatSeconds(m->buildSeconds),
                  fmt::format("{:.2f}", double(m->storeBytes) / (1 << 20)), onFront(m) ? "*" : ""});
    markdown += fmt::format(
        "| {} | {:.2f} | {:.4f} | {:.2f} | {:.3f} | {:.3f} | {:.3f} | {:.3f} | {:.2f} | {:.2f} | {} |\n",
        m->setting.name(), 1e3 * m->seconds, m->rmse, m->psnr, m->depthMean, m->depthTail,
        m->depthTailOffEdges, m->silhouettePercent, m->buildSeconds, double(m->storeBytes) / (1 << 20),
        onFront(m) ? "yes" : "");
  }
  printTitle("Error against render time (reference: kd-tree ray cast of the mesh)");
  table.print();
  return markdown;
}

// Goals at 1 voxel per pixel with contours, and whether the contour front dominates the cube renders.
std::string goalsOf(const std::vector<Measured>& all) {
  std::string goals = "\n## Goals (1 voxel per pixel, contours, beam)\n\n";
  for (const Measured& m : all) {
    if (m.setting.lod != 1.0f || !m.setting.contours || m.setting.beam == 0) continue;
    goals += fmt::format(
        "- {} levels, contour cut {}: silhouette mismatch {:.3f}% (goal <= {}%: {}), depth p99 {:.3f} voxels "
        "(goal <= {}: {}; {:.3f} off edges), store {:.2f} MB\n",
        m.setting.levels, m.setting.contourCut, m.silhouettePercent, kGoalSilhouettePercent,
        m.silhouettePercent <= kGoalSilhouettePercent ? "met" : "missed", m.depthTail, kGoalDepthVoxels,
        m.depthTail <= kGoalDepthVoxels ? "met" : "missed", m.depthTailOffEdges,
        double(m.storeBytes) / (1 << 20));
  }
  std::size_t cubes = 0, dominatedCubes = 0;
  for (const Measured& c : all) {
    if (c.setting.contours) continue;
    ++cubes;
    dominatedCubes += std::any_of(all.begin(), all.end(), [&](const Measured& o) {
      return o.setting.contours && o.seconds <= c.seconds && o.rmse <= c.rmse;
    });
  }
  return goals +
         fmt::format("- cube-voxel renders matched or beaten (time and RMSE) by a contour render: {} of {}\n",
                     dominatedCubes, cubes);
}

// Each error against time, one series per knob family, and the Pareto front.
void plotErrors(const std::filesystem::path& path, const std::vector<Measured>& all) {
  const std::vector<const Measured*> byTime = sortedByTime(all);
  std::vector<plot::Panel> panels;
  for (const auto& [title, metric] : kPlottedErrors) {
    plot::Panel panel{title, {}};
    std::map<std::string, plot::Series> families;
    for (const Measured* m : byTime) {
      plot::Series& s = families[m->setting.family()];
      s.name = m->setting.family();
      s.points.push_back({1e3 * m->seconds, std::max((*m).*metric, kSmallestPlottedError)});
    }
    for (auto& [name, s] : families) panel.series.push_back(std::move(s));
    plot::Series pareto{"Pareto front", {}};
    for (const Measured* m : paretoFront(all, metric))
      pareto.points.push_back({1e3 * m->seconds, std::max((*m).*metric, kSmallestPlottedError)});
    panel.series.push_back(std::move(pareto));
    panels.push_back(std::move(panel));
  }
  plot::writeLogLogPlot(path, panels, "render time (ms)", "error (log)");
}

// The images of the best and worst settings by RMSE and their differences to the reference; returns the
// report's lines about them.
std::string writeBestAndWorst(const std::filesystem::path& out, const std::vector<Measured>& all,
                              const Image& reference) {
  std::string markdown;
  const auto [best, worst] = std::minmax_element(
      all.begin(), all.end(), [](const Measured& a, const Measured& b) { return a.rmse < b.rmse; });
  for (const auto& [label, m] : {std::pair{"best", &*best}, std::pair{"worst", &*worst}}) {
    Image diff = m->image;
    for (std::size_t i = 0; i < diff.color.size(); ++i)
      diff.color[i] =
          glm::min(glm::abs(m->image.color[i] - reference.color[i]) * kDifferenceGain, glm::vec3(1.0f));
    writePng(out / fmt::format("{}.png", label), m->image);
    writePng(out / fmt::format("{}-difference.png", label), diff);
    markdown += fmt::format("\n{} setting by RMSE: {} (RMSE {:.4f}); difference x{}: `{}-difference.png`\n",
                            label, m->setting.name(), m->rmse, kDifferenceGain, label);
  }
  return markdown;
}

// Each setting with a knob on (compressed attributes, the filter) against the same setting without it: the
// change in PSNR and render time, printed and as the report's lines; the filter's frames before and after are
// written as PNGs for each level of detail of the deepest level.
std::string knobEffects(const std::filesystem::path& out, const std::vector<Measured>& all) {
  const auto plainOf = [&](const Setting& s) -> const Measured* {
    for (const Measured& m : all)
      if (m.setting.levels == s.levels && m.setting.contourCut == s.contourCut && m.setting.lod == s.lod &&
          m.setting.contours && m.setting.beam == s.beam && !m.setting.attributes.compressed() &&
          m.setting.filterRadius == 0.0f)
        return &m;
    return nullptr;
  };
  const int deepest = std::max_element(all.begin(), all.end(), [](const Measured& a, const Measured& b) {
                        return a.setting.levels < b.setting.levels;
                      })->setting.levels;
  Table table({"knob", "setting", "PSNR off dB", "PSNR on dB", "render off", "render on", "knob costs",
               "memory off MB", "memory on MB"});
  std::string markdown =
      "\n## Knobs against the same setting without them\n\n| knob | setting | PSNR off | PSNR on | render "
      "off ms | render on ms | memory off MB | memory on MB |\n|---|---|---|---|---|---|---|---|\n";
  std::string images;
  for (const Measured& m : all) {
    const bool filter = m.setting.filterRadius > 0.0f;
    const bool compressed = m.setting.attributes.compressed();
    if (!filter && !compressed) continue;
    const Measured* plain = plainOf(m.setting);
    if (!plain) continue;
    const std::string knob = m.setting.knobName();
    const auto megabytes = [](const Measured& x) { return double(x.poolBytes) / (1 << 20); };
    const std::string setting =
        fmt::format("L{} lod {} cut {}", m.setting.levels, m.setting.lod, m.setting.contourCut);
    table.addRow({knob, setting, fmt::format("{:.2f}", plain->psnr), fmt::format("{:.2f}", m.psnr),
                  formatSeconds(plain->seconds), formatSeconds(m.seconds),
                  fmt::format("{:+.1f} ms", 1e3 * (m.seconds - plain->seconds)),
                  fmt::format("{:.2f}", megabytes(*plain)), fmt::format("{:.2f}", megabytes(m))});
    markdown += fmt::format("| {} | {} | {:.2f} | {:.2f} | {:.2f} | {:.2f} | {:.2f} | {:.2f} |\n", knob,
                            setting, plain->psnr, m.psnr, 1e3 * plain->seconds, 1e3 * m.seconds,
                            megabytes(*plain), megabytes(m));
    if (filter && m.setting.levels == deepest && m.setting.contourCut == all.front().setting.contourCut) {
      const std::string before = fmt::format("lod{}-no-filter.png", m.setting.lod);
      const std::string after = fmt::format("lod{}-filter{}.png", m.setting.lod, m.setting.filterRadius);
      writePng(out / before, plain->image);
      writePng(out / after, m.image);
      images += fmt::format("- `{}` / `{}`: L{} lod {} without and with the filter of radius {}\n", before,
                            after, m.setting.levels, m.setting.lod, m.setting.filterRadius);
    }
  }
  printTitle("Knobs against the same setting without them");
  table.print();
  return markdown + (images.empty() ? "" : "\n" + images);
}

// Throws UsageError naming `flag` where a value is listed twice.
void requireDistinct(const std::vector<float>& values, const char* flag) {
  for (std::size_t i = 0; i < values.size(); ++i)
    if (std::count(values.begin(), values.begin() + i, values[i]))
      throw UsageError(fmt::format("{}: {} is listed twice", flag, values[i]));
}

void runQualityBench(const QualityArgs& args) {
  requireRuns(args.runs);
  if (args.size < 16 || args.size > 8192)
    throw UsageError(fmt::format("--size must be in [16, 8192] (got {})", args.size));
  const std::vector<int> levelList = parseLevels(args.levels);
  requireDistinct(args.contourCuts, "--leaf-contour-cuts");
  requireDistinct(args.exactNormals, "--exact-normals");
  const glm::dvec3 view = parseDirection(args.view, "--view");
  const int threads = resolveThreads(args.threads);
  const std::filesystem::path out = args.out;
  std::filesystem::create_directories(out);

  if (args.stream) checkStreamArgs(args);
  const Mesh mesh = loadBenchMesh(args.mesh);
  if (args.stream)
    return runStreamingQuality(args, mesh, threads, *std::max_element(levelList.begin(), levelList.end()));
  Camera camera = Camera::framing(fitSceneCube(mesh), view, args.size, args.size);
  camera.eye = camera.target + (camera.eye - camera.target) / args.zoom;
  const std::unique_ptr<accel::Accel> kd = buildReference(mesh);
  RenderOptions base;
  base.threads = threads;
  Image reference;
  const Summary referenceTime =
      timeRuns(args.runs, [&] { reference = renderReference(mesh, *kd, camera, base, threads); });
  writePng(out / "reference.png", reference);

  const std::vector<Measured> all = measureSettings(args, mesh, levelList, camera, base, reference);
  std::string markdown = fmt::format(
      "# svo bench quality: {}\n\n{} triangles, {}x{} pixels, camera zoom {}, {} threads, median of {} runs. "
      "Reference: kd-tree ray cast of the mesh, same camera and Phong shading, normals and colors "
      "interpolated from the mesh; its render takes {}.\n\n| setting | render ms | RMSE | PSNR dB | depth "
      "mean (vox) | depth p99 (vox) | p99 off edges (vox) | silhouette % | build s | store MB | Pareto "
      "(RMSE) "
      "|\n|---|---|---|---|---|---|---|---|---|---|---|\n",
      args.mesh, mesh.triangles.size(), args.size, args.size, args.zoom, threads, args.runs,
      formatSeconds(referenceTime.median));
  markdown += printSettings(all);
  const std::string goals = goalsOf(all);
  fmt::print("{}", goals);
  markdown += goals;
  plotErrors(out / "error-vs-time.png", all);
  markdown += knobEffects(out, all);
  markdown += writeBestAndWorst(out, all, reference);
  markdown += "\n![error against time](error-vs-time.png)\n";
  writeTextFile(out / "quality.md", markdown);
  fmt::print("report: {}, plot: {}, images: reference.png, best/worst(-difference).png in {}\n",
             (out / "quality.md").string(), (out / "error-vs-time.png").string(), out.string());
}

}  // namespace

void addQualityBench(CLI::App& bench) {
  auto args = std::make_shared<QualityArgs>();
  CLI::App* cmd = bench.add_subcommand(
      "quality", "error against render time for every quality knob, vs the exact triangle reference");
  cmd->add_option("mesh", args->mesh, "triangle mesh")->required();
  cmd->add_option("--levels", args->levels, "octree depths to build, comma-separated")->capture_default_str();
  cmd->add_option("--leaf-contour-cuts", args->contourCuts,
                  "finest voxels' contour thresholds to build each depth with (svo build "
                  "--leaf-contour-min-reduction), comma-separated; --stream builds with the first")
      ->delimiter(',')
      ->check(finiteRange(0.0, 2.0))
      ->capture_default_str();
  cmd->add_option(
         "--filter-radius", args->filterRadii,
         "post-process filter radii per voxel width to sweep at each level of detail (contours, beam), "
         "comma-separated")
      ->delimiter(',')
      ->check(finiteRange(0.05, 8.0))
      ->capture_default_str();
  cmd->add_option(
         "--exact-normals", args->exactNormals,
         "compressed attributes' exact-unit angles (svo render --exact-normals) to sweep at each level "
         "of detail (contours, beam), comma-separated")
      ->delimiter(',')
      ->check(finiteRange(0.0, kMaxExactNormalUnitDegrees))
      ->capture_default_str();
  cmd->add_option("--size", args->size, "image width and height")->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per setting; the median is reported")
      ->capture_default_str();
  cmd->add_option("--view", args->view, "view direction x,y,z for Camera::framing")->capture_default_str();
  cmd->add_option("--zoom", args->zoom,
                  "camera this many times closer to the scene's centre than the framing view (a city's "
                  "buildings wider than a pixel)")
      ->check(finiteRange(1.0, 1000.0))
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "threads (0 = all cores)")->capture_default_str();
  cmd->add_option("-o,--output", args->out, "folder for the report, plots and images")->capture_default_str();
  CLI::Option* stream = cmd->add_flag(
      "--stream", args->stream,
      "instead of the sweep: error against elapsed time while the deepest --levels store streams "
      "in from a cold start, one curve per --sources and --budgets");
  cmd->add_option("--budgets", args->budgets, "with --stream: pool budgets, e.g. 4M,64M (default 4M,64M)")
      ->delimiter(',')
      ->transform(CLI::AsSizeValue(false))
      ->needs(stream);
  cmd->add_option("--timeout", args->timeout, "with --stream: seconds the view may take to converge")
      ->check(finitePositive())
      ->capture_default_str()
      ->needs(stream);
  std::vector<std::string> sourceWords;
  for (const auto& [word, name] : kStreamSources) sourceWords.push_back(word);
  cmd->add_option(
         "--sources", args->sources,
         "with --stream: where the store streams from, one curve each: local (the file), serve (svo "
         "serve's view stream), serve-range (svo serve by range requests), nginx (by range requests); "
         "comma-separated")
      ->delimiter(',')
      ->check(CLI::IsMember(sourceWords))
      ->capture_default_str()
      ->needs(stream);
  const auto [linkDelay, linkRate] =
      addLinkFlags(*cmd, args->linkDelayMs, args->linkRate, "with --stream, for the sources over HTTP");
  linkDelay->needs(stream);
  linkRate->needs(stream);
  cmd->callback([args] { runQualityBench(*args); });
}

}  // namespace svo::tools::bench
