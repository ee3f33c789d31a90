// `svo bench accel`: every triangle acceleration structure of builder/accel (binned analytic-SAH and exact
// SAH kd-trees, ORG / UG / RG / RG-2 grids, OAVM and classic octrees) on meshes and generated stress scenes:
// cells, references, pointers, build time, primary-ray render time, next to Embree 3 measured in the same
// run; the papers' claims checked on the numbers; a Markdown report and a PNG plot of build time per
// triangle against N.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "bench_common.hpp"
#include "bench_embree.hpp"
#include "plot.hpp"
#include "svo/accel/accel.hpp"
#include "svo/accel/scenes.hpp"
#include "svo/client/render.hpp"
#include "text_file.hpp"

namespace svo::tools::bench {

namespace {

using accel::Accel;

// Generated scene sizes (10^4 ... 2·10^6), trimmed by --max-n.
constexpr const char* kDefaultSizes = "10000,100000,1000000,2000000";
constexpr const char* kDefaultScenes = "thin,field,huge-tiny,sphere";
// Meshes used when no --mesh is given and they exist: the bunny of tools/scripts/fetch-data.sh and two
// Debian assimp-testmodels.
constexpr const char* kDefaultMeshes[] = {"build/data/bunny.ply", "/usr/share/assimp/models/PLY/Wuson.ply",
                                          "/usr/share/assimp/models/OBJ/spider.obj"};
// Papers' numbers checked below.
constexpr double kKdBuildSpeedup = 2.0;  // kd paper Sec. 3.1: binned ≈ 2× faster than exact SAH
constexpr double kKdRenderBand = 0.10;   // kd paper Tables 1-2: traversal within about ±10%
constexpr double kOrgCellsLo = 1.0, kOrgCellsHi = 2.0;  // ORG Sec. 3.1: rc in [1, 2]
constexpr double kOrgRefsLo = 3.0, kOrgRefsHi = 5.0;    // ORG Sec. 3.1: rp mostly in [3, 5]
constexpr double kOrgRenderVsKd = 1.5;      // ORG Sec. 3.2: sr vs kd-tree 0.6 ... 2.1; goal: within 1.5×
constexpr double kOavmPointerRatio = 0.55;  // OAVM abstract: 54.45% fewer pointers
constexpr double kOavmTimeRatio = 0.6;      // OAVM abstract: 52.37% less intersection time
constexpr double kEmbreeBar = 0.5;          // goal: best of kd-tree, ORG, OAVM ≥ 0.5× Embree's Mrays/s

struct AccelArgs {
  std::vector<std::string> meshes;
  std::string sizes = kDefaultSizes;
  std::string scenes = kDefaultScenes;
  std::string structures;  // empty: all
  std::int64_t maxN = 2000000;
  int size = 1024;
  int runs = 1;
  int threads = 1;
  std::string view = defaultViewText();
  std::string markdown = "accel-bench.md";
  std::string plotPath = "accel-bench.png";
  std::uint64_t seed = 1;
};

struct Row {
  std::string structure;
  accel::Stats stats;
  double buildSeconds = 0, renderSeconds = 0;
  std::uint64_t hits = 0,
                mismatches = 0;  // mismatches: pixels whose triangle differs from the first structure
  bool peer = false;
};

struct SceneResult {
  std::string name, kind;  // kind: generated scene kind, or "mesh"
  std::size_t triangles = 0;
  double rays = 0;
  std::vector<Row> rows;
  const Row* find(const std::string& s) const {
    for (const Row& r : rows)
      if (r.structure == s) return &r;
    return nullptr;
  }
};

std::vector<std::string> splitList(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream ss(text);
  for (std::string item; std::getline(ss, item, ',');)
    if (!item.empty()) out.push_back(item);
  return out;
}

// Pixel rays of `camera` through the structure: triangle id per pixel.
std::vector<std::uint32_t> renderIds(const Accel& a, const Camera& camera, int threads) {
  std::vector<std::uint32_t> ids(std::size_t(camera.width) * camera.height, accel::kNoTriangle);
  const Camera::Basis basis = camera.basis();
  forEachTile(camera.width, camera.height, kTileSize, threads, [&](const PixelTile& tile) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) {
        accel::Ray ray;
        ray.origin = camera.eye;
        Camera::pixelRay(camera, basis, x, y, ray.direction);
        ids[std::size_t(y) * camera.width + x] = a.closestHit(ray).triangle;
      }
  });
  return ids;
}

accel::Box meshBox(const Mesh& mesh) {
  accel::Box b;
  for (const auto& p : mesh.positions) b.extend(p);
  return b;
}

SceneResult runScene(const std::string& name, const std::string& kind, const Mesh& mesh,
                     const std::vector<std::string>& structures, const AccelArgs& args,
                     const glm::dvec3& view) {
  SceneResult result{name, kind, mesh.triangles.size(), 0.0, {}};
  const accel::Box box = meshBox(mesh);
  const glm::dvec3 ext = box.extent();
  const double size = std::max({ext.x, ext.y, ext.z, 1e-9});
  const SceneTransform transform{box.lo + 0.5 * ext - 0.5 * size, size};
  const Camera camera = Camera::framing(transform, view, args.size, args.size);
  camera.validate();
  result.rays = double(camera.width) * camera.height;
  std::vector<std::uint32_t> reference;
  for (const std::string& s : structures) {
    spdlog::info("{}: {} build ...", name, s);
    std::unique_ptr<Accel> a;
    Row row;
    row.structure = s;
    row.buildSeconds = timeSeconds([&] { a = accel::buildByName(s, accel::trianglesOf(mesh)); });
    row.stats = a->stats();
    spdlog::info("{}: {} render {}x{} ...", name, s, camera.width, camera.height);
    std::vector<std::uint32_t> ids;
    std::vector<double> samples;
    for (int r = 0; r < args.runs; ++r)
      samples.push_back(timeSeconds([&] { ids = renderIds(*a, camera, args.threads); }));
    row.renderSeconds = summarize(samples).median;
    row.hits = std::uint64_t(
        std::count_if(ids.begin(), ids.end(), [](auto id) { return id != accel::kNoTriangle; }));
    if (reference.empty()) reference = ids;
    for (std::size_t i = 0; i < ids.size(); ++i) row.mismatches += ids[i] != reference[i];
    result.rows.push_back(row);
  }
#ifdef SVO_BENCH_PEERS
  {
    spdlog::info("{}: Embree build and render ...", name);
    Row row;
    row.structure = "embree";
    row.peer = true;
    const EmbreePeer embree(mesh, box.lo + 0.5 * ext);
    row.buildSeconds = embree.buildSeconds();
    TraceResult trace;
    std::vector<double> samples;
    for (int r = 0; r < args.runs; ++r)
      samples.push_back(timeSeconds([&] { trace = embree.trace(camera, args.threads); }));
    row.renderSeconds = summarize(samples).median;
    row.hits = trace.hits;
    if (!reference.empty())
      for (std::size_t i = 0; i < trace.primitive.size(); ++i)
        row.mismatches += trace.primitive[i] != reference[i];
    result.rows.push_back(row);
  }
#endif
  return result;
}

std::string ms(double s) {
  return fmt::format("{:.1f}", s * 1e3);
}
std::string ratio(double a, double b) {
  return b > 0 ? fmt::format("{:.2f}", a / b) : "-";
}

std::vector<std::vector<std::string>> sceneCells(const SceneResult& r) {
  std::vector<std::vector<std::string>> out;
  const double n = double(std::max<std::size_t>(r.triangles, 1));
  for (const Row& row : r.rows) {
    const double mr = r.rays / row.renderSeconds * 1e-6;
    if (row.peer) {
      out.push_back({"Embree 3 (BVH, high)", "-", "-", "-", "-", "-", "-", ms(row.buildSeconds),
                     fmt::format("{:.3f}", row.buildSeconds / n * 1e6), ms(row.renderSeconds),
                     fmt::format("{:.2f}", mr), fmt::format("{:.1f}%", 100.0 * double(row.hits) / r.rays),
                     formatCount(row.mismatches)});
      continue;
    }
    const accel::Stats& s = row.stats;
    out.push_back({row.structure, formatCount(s.cells), ratio(double(s.cells), n), formatCount(s.references),
                   ratio(double(s.references), n), formatCount(s.pointers),
                   fmt::format("{:.1f}", double(s.bytes) / (1 << 20)), ms(row.buildSeconds),
                   fmt::format("{:.3f}", row.buildSeconds / n * 1e6), ms(row.renderSeconds),
                   fmt::format("{:.2f}", mr), fmt::format("{:.1f}%", 100.0 * double(row.hits) / r.rays),
                   formatCount(row.mismatches)});
  }
  return out;
}

const std::vector<std::string> kHeaders = {"structure", "cells",  "cells/N",  "refs",   "refs/N",
                                           "pointers",  "MB",     "build ms", "µs/tri", "render ms",
                                           "Mrays/s",   "hit px", "≠ first"};

std::string markdownTable(const std::vector<std::string>& headers,
                          const std::vector<std::vector<std::string>>& rows) {
  std::string s = "|";
  for (const auto& h : headers) s += " " + h + " |";
  s += "\n|";
  for (std::size_t i = 0; i < headers.size(); ++i) s += i ? " ---: |" : " --- |";
  s += "\n";
  for (const auto& row : rows) {
    s += "|";
    for (const auto& c : row) s += " " + c + " |";
    s += "\n";
  }
  return s;
}

// One line per claim and scene: the measured value and whether it holds.
struct Claim {
  std::string claim, scene, value;
  bool holds;
};

std::vector<Claim> checkClaims(const std::vector<SceneResult>& results) {
  std::vector<Claim> claims;
  for (const SceneResult& r : results) {
    const double n = double(std::max<std::size_t>(r.triangles, 1));
    const Row *kb = r.find("kd-binned"), *ks = r.find("kd-sah"), *org = r.find("org"), *rg = r.find("rg"),
              *oct = r.find("octree"), *oavm = r.find("oavm"), *embree = r.find("embree");
    if (kb && ks) {
      const double sp = ks->buildSeconds / kb->buildSeconds;
      claims.push_back({"kd: binned build ≥ 2× faster than exact SAH", r.name, fmt::format("{:.2f}×", sp),
                        sp >= kKdBuildSpeedup});
      const double tr = kb->renderSeconds / ks->renderSeconds;
      claims.push_back({"kd: binned traversal within ±10% of exact SAH", r.name, fmt::format("{:.2f}", tr),
                        std::abs(tr - 1.0) <= kKdRenderBand});
    }
    if (org) {
      const double rc = double(org->stats.cells) / n, rp = double(org->stats.references) / n;
      claims.push_back({"ORG: cells/N in [1, 2]", r.name, fmt::format("{:.2f}", rc),
                        rc >= kOrgCellsLo && rc <= kOrgCellsHi});
      claims.push_back(
          {"ORG: refs/N in [3, 5]", r.name, fmt::format("{:.2f}", rp), rp >= kOrgRefsLo && rp <= kOrgRefsHi});
      if (kb) {
        const double sr = org->renderSeconds / kb->renderSeconds;
        claims.push_back({"ORG: render within 1.5× of kd-tree (binned)", r.name, fmt::format("{:.2f}", sr),
                          sr <= kOrgRenderVsKd});
      }
      if (rg && (r.kind == "field" || r.kind == "thin")) {
        const double a = double(org->stats.cells + org->stats.references),
                     b = double(rg->stats.cells + rg->stats.references);
        claims.push_back({"ORG: fewer cells+refs than RG on flat/thin scenes", r.name,
                          fmt::format("{:.2f}", a / b), a < b});
      }
    }
    if (oct && oavm) {
      const double pr = double(oavm->stats.pointers) / double(oct->stats.pointers);
      claims.push_back({"OAVM: ≤ 0.55× the classic octree's pointers", r.name, fmt::format("{:.2f}", pr),
                        pr <= kOavmPointerRatio});
      const double tr = oavm->renderSeconds / oct->renderSeconds;
      claims.push_back({"OAVM: ≤ 0.6× the classic octree's ray time", r.name, fmt::format("{:.2f}", tr),
                        tr <= kOavmTimeRatio});
    }
    if (embree) {
      // The three structures of the goal (the kd-tree with either build, ORG, OAVM); UG, RG and RG-2 are only
      // the ORG paper's comparison structures.
      double best = 1e300;
      std::string who;
      for (const char* ours : {"kd-binned", "kd-sah", "org", "oavm"})
        if (const Row* row = r.find(ours); row && row->renderSeconds < best)
          best = row->renderSeconds, who = row->structure;
      if (!who.empty()) {
        const double q = embree->renderSeconds / best;
        claims.push_back({"ours: best of kd-tree, ORG, OAVM ≥ 0.5× Embree Mrays/s", r.name,
                          fmt::format("{:.2f} ({})", q, who), q >= kEmbreeBar});
      }
    }
  }
  // ORG linear build: µs per triangle over N, per generated kind (flat when max/min stays small).
  std::map<std::string, std::vector<std::pair<double, double>>> perKind;
  for (const SceneResult& r : results)
    if (const Row* org = r.find("org"); org && r.kind != "mesh")
      perKind[r.kind].push_back({double(r.triangles), org->buildSeconds / double(r.triangles) * 1e6});
  for (auto& [kind, pts] : perKind) {
    if (pts.size() < 2) continue;
    std::sort(pts.begin(), pts.end());
    std::string value;
    for (auto [nn, us] : pts) value += fmt::format("{}{:.3f}@{:.0e}", value.empty() ? "" : ", ", us, nn);
    // "Flat": the largest N costs at most 2× per triangle what the smallest does (cache effects allowed).
    claims.push_back({"ORG: build time per triangle flat in N (≤ 2× growth)", kind, value,
                      pts.back().second <= 2.0 * pts.front().second});
  }
  return claims;
}

std::vector<std::string> parseStructures(const std::string& text) {
  const std::vector<std::string> known = accel::structureNames();
  if (text.empty()) return known;
  std::string knownList;
  for (const auto& k : known) knownList += (knownList.empty() ? "" : ",") + k;
  const std::vector<std::string> structures = splitList(text);
  for (const auto& s : structures)
    if (std::find(known.begin(), known.end(), s) == known.end())
      throw UsageError("--structures: unknown '" + s + "' (known: " + knownList + ")");
  return structures;
}

// A generated scene kind and the most triangles it may have ("thin:100000": no larger thin scene).
struct SceneSpec {
  accel::SceneKind kind;
  std::int64_t cap = 0;
};
std::vector<SceneSpec> parseScenes(const std::string& text, std::int64_t maxN) {
  std::vector<SceneSpec> specs;
  for (const auto& spec : splitList(text)) {
    const std::string name = spec.substr(0, spec.find(':'));
    std::int64_t cap = maxN;
    if (spec.find(':') != std::string::npos) {
      char* end = nullptr;
      const double v = std::strtod(spec.c_str() + spec.find(':') + 1, &end);
      if (!end || *end || !(v >= 1)) throw UsageError(fmt::format("--scenes: bad size cap in '{}'", spec));
      cap = std::min(cap, std::int64_t(v));
    }
    bool found = false;
    for (auto k : accel::allScenes())
      if (accel::sceneName(k) == name) specs.push_back({k, cap}), found = true;
    if (!found) throw UsageError(fmt::format("--scenes: unknown scene '{}'", name));
  }
  return specs;
}

std::vector<std::int64_t> parseSizes(const std::string& text, std::int64_t maxN) {
  std::vector<std::int64_t> sizes;
  for (const auto& t : splitList(text)) {
    char* end = nullptr;
    const double v = std::strtod(t.c_str(), &end);
    if (!end || *end || !(v >= 1)) throw UsageError(fmt::format("--sizes: '{}' is not a count >= 1", t));
    if (std::int64_t(v) <= maxN) sizes.push_back(std::int64_t(v));
  }
  return sizes;
}

// The meshes named by --mesh (an error when one does not load), else the default meshes that load.
std::vector<SceneResult> runMeshes(const AccelArgs& args, const std::vector<std::string>& structures,
                                   const glm::dvec3& view) {
  std::vector<std::string> meshes = args.meshes;
  if (meshes.empty())
    for (const char* m : kDefaultMeshes)
      if (std::filesystem::exists(m)) meshes.push_back(m);
  std::vector<SceneResult> results;
  for (const auto& path : meshes) {
    Mesh mesh;
    try {
      mesh = loadBenchMesh(path);
    } catch (const std::exception& e) {
      if (!args.meshes.empty()) throw;
      spdlog::warn("skipping default mesh: {}", e.what());
      continue;
    }
    if (std::int64_t(mesh.triangles.size()) > args.maxN) continue;
    results.push_back(
        runScene(std::filesystem::path(path).filename().string(), "mesh", mesh, structures, args, view));
  }
  return results;
}

// Build microseconds per triangle against N, one panel per generated scene kind; returns the report's line.
std::string plotBuildTimes(const std::string& path, const std::vector<SceneSpec>& scenes,
                           const std::vector<SceneResult>& results) {
  std::vector<plot::Panel> panels;
  for (const SceneSpec& scene : scenes) {
    plot::Panel panel{accel::sceneName(scene.kind), {}};
    std::map<std::string, plot::Series> series;
    for (const SceneResult& r : results)
      if (r.kind == accel::sceneName(scene.kind))
        for (const Row& row : r.rows) {
          auto& s = series[row.structure];
          s.name = row.structure;
          s.points.push_back({double(r.triangles), row.buildSeconds / double(r.triangles) * 1e6});
        }
    for (auto& [k, s] : series) panel.series.push_back(s);
    if (!panel.series.empty()) panels.push_back(panel);
  }
  if (panels.empty() || path.empty()) return {};
  plot::writeLogLogPlot(path, panels, "triangles N", "build time per triangle (microseconds)");
  fmt::print("plot: {}\n", path);
  return fmt::format("\n![build time per triangle against N]({})\n",
                     std::filesystem::path(path).filename().string());
}

void runAccelBench(const AccelArgs& args) {
  if (args.size < 1 || args.size > 16384)
    throw UsageError(fmt::format("--size must be in [1, 16384] (got {})", args.size));
  requireRuns(args.runs);
  if (args.maxN < 1) throw UsageError(fmt::format("--max-n must be >= 1 (got {})", args.maxN));
  AccelArgs a = args;
  a.threads = resolveThreads(args.threads);
  const glm::dvec3 view = parseDirection(args.view, "--view");
  const std::vector<std::string> structures = parseStructures(args.structures);
  const std::vector<SceneSpec> scenes = parseScenes(args.scenes, args.maxN);
  const std::vector<std::int64_t> sizes = parseSizes(args.sizes, args.maxN);

  std::vector<SceneResult> results = runMeshes(a, structures, view);
  for (const SceneSpec& scene : scenes)
    for (auto n : sizes) {
      if (n > scene.cap) continue;
      const Mesh mesh = accel::makeScene(scene.kind, std::size_t(n), args.seed);
      results.push_back(
          runScene(fmt::format("{} {}", accel::sceneName(scene.kind), formatCount(mesh.triangles.size())),
                   accel::sceneName(scene.kind), mesh, structures, a, view));
    }

  std::string md = fmt::format(
      "# svo bench accel\n\n{}×{} primary rays per scene, {} thread(s), median of {} render run(s); build "
      "timed once. `≠ first`: pixels whose triangle differs from the first structure's (Embree: float "
      "precision).\n\n",
      args.size, args.size, a.threads, args.runs);
  for (const SceneResult& r : results) {
    printTitle(fmt::format("{}: {} triangles", r.name, formatCount(r.triangles)));
    Table table(kHeaders);
    const auto cells = sceneCells(r);
    for (const auto& row : cells) table.addRow(row);
    table.print();
    md += fmt::format("## {} ({} triangles)\n\n", r.name, formatCount(r.triangles)) +
          markdownTable(kHeaders, cells) + "\n";
  }
  printTitle("Paper claims on these numbers");
  Table ct({"claim", "scene", "measured", "verdict"});
  std::vector<std::vector<std::string>> mdClaims;
  for (const Claim& c : checkClaims(results)) {
    ct.addRow({c.claim, c.scene, c.value, c.holds ? "confirmed" : "refuted"});
    mdClaims.push_back({c.claim, c.scene, c.value, c.holds ? "confirmed" : "refuted"});
  }
  ct.print();
  md += "## Paper claims\n\n" + markdownTable({"claim", "scene", "measured", "verdict"}, mdClaims);
  md += plotBuildTimes(args.plotPath, scenes, results);
  if (!args.markdown.empty()) {
    writeTextFile(args.markdown, md);
    fmt::print("markdown: {}\n", args.markdown);
  }
}

}  // namespace

void addAccelBench(CLI::App& bench) {
  auto args = std::make_shared<AccelArgs>();
  CLI::App* cmd = bench.add_subcommand(
      "accel",
      "kd-trees, ORG/UG/RG/RG-2 grids, OAVM and classic octrees vs Embree 3: cells, refs, build, render");
  cmd->add_option("--mesh", args->meshes,
                  "mesh files (repeatable; default: the bunny and assimp test models found)");
  cmd->add_option("--sizes", args->sizes, "generated scene sizes, comma separated")->capture_default_str();
  cmd->add_option("--max-n", args->maxN, "skip scenes with more triangles than this")->capture_default_str();
  cmd->add_option(
         "--scenes", args->scenes,
         "generated scenes: thin, field, huge-tiny, sphere, soup, each optionally name:maxN (empty: none)")
      ->capture_default_str();
  cmd->add_option("--structures", args->structures, "comma separated subset (default: all)");
  cmd->add_option("--size", args->size, "image width and height")->capture_default_str();
  cmd->add_option("--runs", args->runs, "render runs per structure; the median is reported")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "threads for every method (0 = all cores)")
      ->capture_default_str();
  cmd->add_option("--view", args->view, "view direction x,y,z")->capture_default_str();
  cmd->add_option("--markdown", args->markdown, "Markdown report path (empty: none)")->capture_default_str();
  cmd->add_option("--plot", args->plotPath, "PNG plot path (empty: none)")->capture_default_str();
  cmd->add_option("--seed", args->seed, "generated scene seed")->capture_default_str();
  cmd->callback([args] { runAccelBench(*args); });
}

}  // namespace svo::tools::bench
