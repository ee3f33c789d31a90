// `svo bench quality MESH`: error against run time for every quality knob. The exact reference is the
// triangle mesh ray cast with our kd-tree (builder/accel) under the renderer's own Phong model, with normals
// and colors interpolated from the mesh; each voxel setting (octree levels, level of detail, contours on/off,
// beam on/off) is timed (median of runs) and compared with it: color RMSE and PSNR (OpenImageIO's
// ImageBufAlgo::compare, linear RGB), depth error where both hit (mean and 99th percentile of |dt| in finest
// voxels, and that tail off the reference's edges) and silhouette mismatch (pixels hit by exactly one).
// Writes a Markdown report, PNG plots of each error against time with the Pareto front marked, the reference
// image and difference images of the best and worst settings.
//
// With --stream the store of the deepest --levels streams in from a cold file through a block pool of each
// --budgets size, and the same errors against the triangle reference are plotted against the elapsed time
// from opening the store, one curve per budget (stream.md, stream.csv, error-vs-time-streaming.png).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <glm/geometric.hpp>

#include "bench_common.hpp"
#include "measure.hpp"
#include "plot.hpp"
#include "svo/accel/accel.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/render.hpp"
#include "svo/client/streaming.hpp"

namespace svo::tools::bench {
namespace {

// Level-of-detail settings swept (0.5, 1, 2, 4 pixels).
constexpr float kLodSweep[] = {0.5f, 1.0f, 2.0f, 4.0f};
// Beam settings swept: the paper's 8x8 tile, and off.
constexpr int kBeamSweep[] = {8, 0};
// Difference images are scaled by this so small errors are visible.
constexpr float kDifferenceGain = 4.0f;
// Tail quantile of the depth error.
constexpr double kDepthQuantile = 0.99;
// A reference pixel is on an edge when a 4-neighbour misses or its depth jumps by more than this fraction of
// the pixel's depth: there a voxel and a triangle may hit different surfaces (tower and ground), and the
// depth tail measures the edge, not the surface. 2% still counts surfaces up to ~4 degrees from grazing at
// 512 pixels and 40 degrees as surface.
constexpr double kEdgeDepthJump = 0.02;
// Goals at 1 voxel per pixel with contours: silhouette mismatch and depth p99.
constexpr double kGoalSilhouettePercent = 1.0;
constexpr double kGoalDepthVoxels = 1.0;
// --stream keeps a frame for comparison when it comes this many times later than the last one kept (and
// always the first and the converged one): even steps on the log time axis, bounded memory.
constexpr double kStreamKeepRatio = 1.1;
// --stream looks at the surface from this fraction of the scene size: near enough to want the finest levels
// of an 11-level store at 512 pixels, far enough to keep silhouettes in view.
constexpr double kStreamViewDistance = 0.3;

struct QualityArgs {
  std::string mesh;
  std::string levels = "8,9,10";
  std::vector<float> contourCuts{BuildOptions{}.leafContourMinReduction};
  int size = 512;
  int runs = 3;
  std::string view = "-0.35,-0.25,-1";
  double zoom = 1.0;
  int threads = 0;
  std::string out = "out/quality";
  bool stream = false;
  std::vector<std::size_t> budgets{std::size_t(4) << 20, std::size_t(64) << 20};
  double timeout = 300.0;
};

struct Image {
  int width = 0, height = 0;
  std::vector<glm::vec3> color;
  std::vector<float> depth;  // world distance, infinity for a miss
};

// The mesh ray cast through the kd-tree, shaded like svo::render with interpolated normals and colors.
Image renderReference(const Mesh& mesh, const accel::Accel& kd, const Camera& camera,
                      const RenderOptions& options, int threads) {
  std::vector<glm::dvec3> normals(mesh.positions.size(), glm::dvec3(0.0));
  for (const glm::uvec3& t : mesh.triangles) {
    // Area-weighted: the unnormalized cross product is twice the area times the unit normal.
    const glm::dvec3 n =
        glm::cross(mesh.positions[t.y] - mesh.positions[t.x], mesh.positions[t.z] - mesh.positions[t.x]);
    for (int k = 0; k < 3; ++k) normals[t[k]] += n;
  }
  const bool hasColor = mesh.hasColor();
  const glm::vec3 light = glm::normalize(options.lightDirection);
  Image image;
  image.width = camera.width, image.height = camera.height;
  image.color.assign(std::size_t(camera.width) * camera.height, options.background);
  image.depth.assign(image.color.size(), std::numeric_limits<float>::infinity());
  const Camera::Basis basis = camera.basis();
  forEachTile(camera.width, camera.height, 8, threads, [&](const PixelTile& tile) {
    for (int y = tile.y0; y < tile.y1; ++y)
      for (int x = tile.x0; x < tile.x1; ++x) {
        accel::Ray ray;
        ray.origin = camera.eye;
        Camera::pixelRay(camera, basis, x, y, ray.direction);
        const accel::Hit hit = kd.closestHit(ray);
        if (!hit.hit()) continue;
        const glm::uvec3 t = mesh.triangles[hit.triangle];
        const double w0 = 1.0 - hit.u - hit.v;
        glm::dvec3 n = w0 * normals[t.x] + hit.u * normals[t.y] + hit.v * normals[t.z];
        if (!(glm::length(n) > 0.0))
          n = glm::cross(mesh.positions[t.y] - mesh.positions[t.x],
                         mesh.positions[t.z] - mesh.positions[t.x]);
        glm::vec3 albedo(kNeutralGreyAlbedo);
        if (hasColor) {
          glm::vec4 c = mesh.materialOf(hit.triangle).baseColor;
          if (!mesh.colors.empty())
            c *= float(w0) * mesh.colors[t.x] + float(hit.u) * mesh.colors[t.y] +
                 float(hit.v) * mesh.colors[t.z];
          albedo = glm::vec3(c);
        }
        const std::size_t i = std::size_t(y) * camera.width + x;
        image.color[i] = shadePhong(albedo, glm::vec3(glm::normalize(n)), glm::vec3(ray.direction), light);
        image.depth[i] = float(hit.t);
      }
  });
  return image;
}

OIIO::ImageBuf toImageBuf(const Image& image) {
  OIIO::ImageBuf buf(OIIO::ImageSpec(image.width, image.height, 3, OIIO::TypeDesc::FLOAT));
  std::vector<float> pixels(image.color.size() * 3);
  for (std::size_t i = 0; i < image.color.size(); ++i)
    for (int c = 0; c < 3; ++c) pixels[3 * i + c] = std::clamp(image.color[i][c], 0.0f, 1.0f);
  buf.set_pixels(OIIO::ROI::All(), OIIO::TypeDesc::FLOAT, pixels.data());
  return buf;
}

void writePng(const std::filesystem::path& path, const OIIO::ImageBuf& linear) {
  OIIO::ImageBuf srgb = OIIO::ImageBufAlgo::colorconvert(linear, "linear", "sRGB");
  if (!srgb.write(path.string(), OIIO::TypeDesc::UINT8))
    throw std::runtime_error(path.string() + ": cannot write (" + srgb.geterror() + ")");
}

Image imageOf(Frame&& frame) {
  Image image;
  image.width = frame.width, image.height = frame.height;
  image.color.resize(frame.color.size());
  for (std::size_t i = 0; i < frame.color.size(); ++i) image.color[i] = glm::vec3(frame.color[i]);
  image.depth = std::move(frame.depth);
  return image;
}

struct Setting {
  int levels = 0;
  float contourCut = 0.0f;  // the build's leafContourMinReduction; renders with contours only
  float lod = 1.0f;
  bool contours = true;
  int beam = 8;
  std::string family() const {
    return fmt::format("{}, {}", contours ? fmt::format("contours cut {}", contourCut) : "cubes",
                       beam ? "beam" : "no beam");
  }
  std::string name() const { return fmt::format("L{} lod {} {}", levels, lod, family()); }
};

struct Measured {
  Setting setting;
  double seconds = 0.0;
  double rmse = 0.0, psnr = 0.0;
  double depthMean = 0.0, depthTail = 0.0;  // finest voxels
  double depthTailOffEdges = 0.0;           // the same tail where the reference has no edge next door
  double silhouettePercent = 0.0;
  double buildSeconds = 0.0;
  std::uint64_t storeBytes = 0;
  Image image;
};

void compare(const Image& reference, const Image& voxels, double finestVoxel, Measured& m) {
  const OIIO::ImageBufAlgo::CompareResults r =
      OIIO::ImageBufAlgo::compare(toImageBuf(voxels), toImageBuf(reference), 1.0f, 1.0f);
  m.rmse = r.rms_error;
  m.psnr = r.PSNR;
  const auto onEdge = [&](int x, int y) {
    const float d = reference.depth[std::size_t(y) * std::size_t(reference.width) + std::size_t(x)];
    for (const auto& [dx, dy] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
      const int nx = x + dx, ny = y + dy;
      if (nx < 0 || ny < 0 || nx >= reference.width || ny >= reference.height) continue;
      const float n = reference.depth[std::size_t(ny) * std::size_t(reference.width) + std::size_t(nx)];
      if (!std::isfinite(n) || std::abs(double(n) - double(d)) > kEdgeDepthJump * double(d)) return true;
    }
    return false;
  };
  std::vector<double> depth, offEdges;
  std::size_t mismatch = 0;
  for (int y = 0; y < reference.height; ++y)
    for (int x = 0; x < reference.width; ++x) {
      const std::size_t i = std::size_t(y) * std::size_t(reference.width) + std::size_t(x);
      const bool a = std::isfinite(reference.depth[i]), b = std::isfinite(voxels.depth[i]);
      mismatch += a != b;
      if (!a || !b) continue;
      depth.push_back(std::abs(double(voxels.depth[i]) - double(reference.depth[i])) / finestVoxel);
      if (!onEdge(x, y)) offEdges.push_back(depth.back());
    }
  m.silhouettePercent = 100.0 * double(mismatch) / double(reference.depth.size());
  const auto tail = [](std::vector<double>& v) {
    std::sort(v.begin(), v.end());
    return v[std::min(v.size() - 1, std::size_t(kDepthQuantile * double(v.size())))];
  };
  if (!depth.empty()) {
    double sum = 0.0;
    for (const double d : depth) sum += d;
    m.depthMean = sum / double(depth.size());
    m.depthTail = tail(depth);
  }
  if (!offEdges.empty()) m.depthTailOffEdges = tail(offEdges);
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
  std::sort(front.begin(), front.end(),
            [](const Measured* a, const Measured* b) { return a->seconds < b->seconds; });
  return front;
}

// One swept depth: built in core and written as a store (its size goes in the table), with a root to render
// from: one block when the octree fits one, else the store through a pager holding all of it (the same
// frames bit for bit: test_pager), which has no single block's 24-bit reach.
struct LevelScene {
  std::filesystem::path store;
  std::uint64_t storeBytes = 0;
  double buildSeconds = 0.0;  // voxelize + layout
  SceneTransform transform;
  std::optional<WholeScene> scene;  // with its root: every depth, one block or paged
  LevelScene() = default;
  LevelScene(const LevelScene&) = delete;
  ~LevelScene() {
    scene.reset();
    std::error_code ignored;
    if (!store.empty()) std::filesystem::remove(store, ignored);
  }
};

void buildLevel(const Mesh& mesh, const BuildOptions& build, const std::filesystem::path& out, bool withRoot,
                LevelScene& s) {
  const int levels = build.levels;
  spdlog::info("building {} levels, contour cut {} ...", levels, build.leafContourMinReduction);
  s.transform = fitSceneCube(mesh);
  VoxelTree tree;
  s.buildSeconds = timeSeconds([&] { tree = voxelize(mesh, s.transform, build); });
  s.store = out / fmt::format("L{}-cut{}.svo", levels, build.leafContourMinReduction);
  const BuildParameters parameters{levels, build.geometryError, build.colorError, build.normalError,
                                   std::uint32_t(build.contours)};
  writeStore(s.store, tree, s.transform, parameters);
  s.storeBytes = std::filesystem::file_size(s.store);
  if (withRoot)
    s.buildSeconds +=
        timeSeconds([&] { s.scene.emplace(wholeSceneOf(tree, s.transform, parameters, s.store)); });
}

// --stream: from a cold store, frames of one camera while the store streams in; each kept frame's error
// against the triangle reference, by elapsed time since the store was opened.
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
  spdlog::info("reference: kd-tree over {} triangles ...", mesh.triangles.size());
  const std::unique_ptr<accel::Accel> kd = accel::buildByName("kd-binned", accel::trianglesOf(mesh));
  const Image reference = renderReference(mesh, *kd, camera, options, threads);
  writePng(out / "stream-reference.png", toImageBuf(reference));

  const std::vector<std::pair<std::string, double Measured::*>> metrics = {
      {"color RMSE", &Measured::rmse},
      {"depth p99 (finest voxels)", &Measured::depthTail},
      {"silhouette mismatch (%)", &Measured::silhouettePercent}};
  std::vector<plot::Panel> panels;
  for (const auto& [title, metric] : metrics) panels.push_back({title, {}});
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
    writePng(out / fmt::format("stream-{}K.png", budget >> 10),
             toImageBuf(imageOf(Frame(kept.back().second))));
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
    for (std::size_t k = 0; k < metrics.size(); ++k) {
      plot::Series curve{formatBytes(budget), {}};
      for (const Measured& m : series)
        curve.points.push_back({m.seconds, std::max(m.*metrics[k].second, 1e-4)});
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
  std::ofstream(out / "stream.csv") << csv;
  std::ofstream(out / "stream.md") << fmt::format(
      "# svo bench quality --stream: {}\n\n{}. Reference: kd-tree ray cast of the mesh. Frames kept when "
      "{}x later than the last kept one.\n\n![error against elapsed time](error-vs-time-streaming.png)\n\n"
      "Per frame: `stream.csv`.\n",
      args.mesh, title, kStreamKeepRatio);
  fmt::print("report: {}, plot: {}, per-frame errors: {}\n", (out / "stream.md").string(),
             (out / "error-vs-time-streaming.png").string(), (out / "stream.csv").string());
}

void runQualityBench(const QualityArgs& args) {
  requireRuns(args.runs);
  if (args.size < 16 || args.size > 8192)
    throw UsageError(fmt::format("--size must be in [16, 8192] (got {})", args.size));
  // "8,9,10" as the resolutions 256,512,1024 for the shared validator (powers of two, no duplicates).
  std::vector<int> levelList;
  {
    std::string resolutions;
    std::stringstream list(args.levels);
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
    for (const std::int64_t r : parseResolutions(resolutions, "--levels"))
      levelList.push_back(levelsOfResolution(r, "--levels"));
  }
  for (std::size_t i = 0; i < args.contourCuts.size(); ++i)
    if (std::count(args.contourCuts.begin(), args.contourCuts.begin() + i, args.contourCuts[i]))
      throw UsageError(fmt::format("--leaf-contour-cuts: {} is listed twice", args.contourCuts[i]));
  const glm::dvec3 view = parseDirection(args.view, "--view");
  const int threads = resolveThreads(args.threads);
  const std::filesystem::path out = args.out;
  std::filesystem::create_directories(out);

  const Mesh mesh = loadBenchMesh(args.mesh);
  if (args.stream)
    return runStreamingQuality(args, mesh, threads, *std::max_element(levelList.begin(), levelList.end()));
  const SceneTransform scene = fitSceneCube(mesh);
  Camera camera = Camera::framing(scene, view, args.size, args.size);
  camera.eye = camera.target + (camera.eye - camera.target) / args.zoom;
  spdlog::info("reference: kd-tree over {} triangles ...", mesh.triangles.size());
  const std::unique_ptr<accel::Accel> kd = accel::buildByName("kd-binned", accel::trianglesOf(mesh));
  RenderOptions base;
  base.threads = threads;
  Image reference;
  const Summary referenceTime =
      timeRuns(args.runs, [&] { reference = renderReference(mesh, *kd, camera, base, threads); });
  writePng(out / "reference.png", toImageBuf(reference));

  std::vector<Measured> all;
  for (const int levels : levelList)
    for (const float cut : args.contourCuts) {
      LevelScene level;
      BuildOptions build;
      build.levels = levels;
      build.leafContourMinReduction = cut;
      buildLevel(mesh, build, out, true, level);
      const double buildSeconds = level.buildSeconds;
      const std::uint64_t storeBytes = level.storeBytes;
      const BlockView root = level.scene->root();
      const double finestVoxel = scene.size / double(std::int64_t(1) << levels);
      for (const bool contours : {true, false}) {
        // Cube renders ignore contours: one cut's are every cut's.
        if (!contours && cut != args.contourCuts.front()) continue;
        for (const float lod : kLodSweep)
          for (const int beam : kBeamSweep) {
            Measured m;
            m.setting = {levels, contours ? cut : 0.0f, lod, contours, beam};
            m.buildSeconds = buildSeconds, m.storeBytes = storeBytes;
            RenderOptions options = base;
            options.lodPixels = lod;
            options.cast.contours = contours;
            options.beamTile = beam;
            Frame frame;
            m.seconds = timeRuns(args.runs, [&] { frame = render(root, scene, camera, options); }).median;
            m.image = imageOf(std::move(frame));
            compare(reference, m.image, finestVoxel, m);
            all.push_back(std::move(m));
          }
      }
    }

  // Table, sorted by time.
  std::vector<const Measured*> byTime;
  for (const Measured& m : all) byTime.push_back(&m);
  std::sort(byTime.begin(), byTime.end(),
            [](const Measured* a, const Measured* b) { return a->seconds < b->seconds; });
  const auto front = paretoFront(all, &Measured::rmse);
  const auto onFront = [&](const Measured* m) {
    return std::find(front.begin(), front.end(), m) != front.end();
  };
  Table table({"setting", "render", "RMSE", "PSNR dB", "depth mean", "depth p99", "p99 off edges",
               "silhouette", "build", "store MB", "Pareto"});
  std::string markdown = fmt::format(
      "# svo bench quality: {}\n\n{} triangles, {}x{} pixels, camera zoom {}, {} threads, median of {} runs. "
      "Reference: "
      "kd-tree ray "
      "cast of the mesh, same camera and Phong shading, normals and colors interpolated from the mesh; its "
      "render "
      "takes {}.\n\n| setting | render ms | RMSE | PSNR dB | depth mean (vox) | depth p99 (vox) | p99 off "
      "edges "
      "(vox) | silhouette % | build s | store MB | Pareto (RMSE) "
      "|\n|---|---|---|---|---|---|---|---|---|---|---|\n",
      args.mesh, mesh.triangles.size(), args.size, args.size, args.zoom, threads, args.runs,
      formatSeconds(referenceTime.median));
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

  // Goals at 1 voxel per pixel with contours, and whether the contour front dominates the cube renders.
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
  goals +=
      fmt::format("- cube-voxel renders matched or beaten (time and RMSE) by a contour render: {} of {}\n",
                  dominatedCubes, cubes);
  fmt::print("{}", goals);
  markdown += goals;

  // Plots: each error against time, one series per knob family, and the Pareto front.
  std::vector<plot::Panel> panels;
  const std::vector<std::pair<std::string, double Measured::*>> metrics = {
      {"color RMSE", &Measured::rmse},
      {"depth p99 (finest voxels)", &Measured::depthTail},
      {"silhouette mismatch (%)", &Measured::silhouettePercent}};
  for (const auto& [title, metric] : metrics) {
    plot::Panel panel{title, {}};
    std::map<std::string, plot::Series> families;
    for (const Measured* m : byTime) {
      plot::Series& s = families[m->setting.family()];
      s.name = m->setting.family();
      s.points.push_back({1e3 * m->seconds, std::max((*m).*metric, 1e-4)});
    }
    for (auto& [name, s] : families) panel.series.push_back(std::move(s));
    plot::Series pareto{"Pareto front", {}};
    for (const Measured* m : paretoFront(all, metric))
      pareto.points.push_back({1e3 * m->seconds, std::max((*m).*metric, 1e-4)});
    panel.series.push_back(std::move(pareto));
    panels.push_back(std::move(panel));
  }
  plot::writeLogLogPlot(out / "error-vs-time.png", panels, "render time (ms)", "error (log)");

  // Difference images of the best and worst settings by RMSE.
  const auto [best, worst] = std::minmax_element(
      all.begin(), all.end(), [](const Measured& a, const Measured& b) { return a.rmse < b.rmse; });
  for (const auto& [label, m] : {std::pair{"best", &*best}, std::pair{"worst", &*worst}}) {
    Image diff = m->image;
    for (std::size_t i = 0; i < diff.color.size(); ++i)
      diff.color[i] =
          glm::min(glm::abs(m->image.color[i] - reference.color[i]) * kDifferenceGain, glm::vec3(1.0f));
    writePng(out / fmt::format("{}.png", label), toImageBuf(m->image));
    writePng(out / fmt::format("{}-difference.png", label), toImageBuf(diff));
    markdown += fmt::format("\n{} setting by RMSE: {} (RMSE {:.4f}); difference x{}: `{}-difference.png`\n",
                            label, m->setting.name(), m->rmse, kDifferenceGain, label);
  }
  markdown += "\n![error against time](error-vs-time.png)\n";
  std::ofstream(out / "quality.md") << markdown;
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
      ->check(CLI::Range(0.0f, 2.0f))
      ->capture_default_str();
  cmd->add_option("--size", args->size, "image width and height")->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per setting; the median is reported")
      ->capture_default_str();
  cmd->add_option("--view", args->view, "view direction x,y,z for Camera::framing")->capture_default_str();
  cmd->add_option("--zoom", args->zoom,
                  "camera this many times closer to the scene's centre than the framing view (a city's "
                  "buildings wider than a pixel)")
      ->check(CLI::Range(1.0, 1000.0))
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "threads (0 = all cores)")->capture_default_str();
  cmd->add_option("-o,--output", args->out, "folder for the report, plots and images")->capture_default_str();
  CLI::Option* stream = cmd->add_flag(
      "--stream", args->stream,
      "instead of the sweep: error against elapsed time while the deepest --levels store streams "
      "in from a cold file, one curve per --budgets");
  cmd->add_option("--budgets", args->budgets, "with --stream: pool budgets, e.g. 4M,64M (default 4M,64M)")
      ->delimiter(',')
      ->transform(CLI::AsSizeValue(false))
      ->needs(stream);
  cmd->add_option("--timeout", args->timeout, "with --stream: seconds the view may take to converge")
      ->check(CLI::PositiveNumber)
      ->capture_default_str()
      ->needs(stream);
  cmd->callback([args] { runQualityBench(*args); });
}

}  // namespace svo::tools::bench
