// `svo bench raycast MESH`: primary-ray throughput of the ESVO ray caster against Embree 3 on the source
// triangles, same camera rays, same thread count, measured in the same run; plus the octree's bytes per leaf
// voxel next to the paper's Table 1 and a pixel-by-pixel agreement check between the two.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "bench_common.hpp"
#include "bench_embree.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
#include "svo/gpu/headless_gpu.hpp"

namespace svo::tools::bench {

namespace {

// Largest image edge accepted, as Camera::validate does.
constexpr int kMaxImageSize = 16384;
// Paper Table 1 (ESVO, compressed attributes), bytes per leaf voxel: hierarchy, contours, DXT color, normal.
constexpr double kPaperHierarchyBytes = 1.0;
constexpr double kPaperContourBytes = 1.0;
constexpr double kPaperColorBytes = 1.0;
constexpr double kPaperNormalBytes = 2.0;

struct RaycastArgs {
  std::string mesh;
  int levels = 10;
  int size = 1024;
  int runs = 5;
  float lodPixels = 1.0f;
  std::string view = defaultViewText();
  int threads = 0;
  int width = 0, height = 0;  // 0: --size
  std::string device = "cpu";
};

// ESVO without shading: PixelRays + castRay per pixel over the renderer's tiles, depth written like the
// Embree peer does; with `beam`, each tile first runs the beam pass (sec. 6.2).
TraceResult traceEsvo(const WholeScene& scene, const Camera& camera, const RenderOptions& options,
                      int threads, bool beam) {
  TraceResult result;
  result.depth.assign(std::size_t(camera.width) * camera.height, kInfinity);
  const BlockView block = scene.root();
  // Per-frame ray constants computed once, as svo::render does.
  const PixelRays rays(scene.transform(), camera, options.lodPixels);
  std::atomic<std::uint64_t> iterations{0};
  forEachTile(camera.width, camera.height, kTileSize, threads, [&](const PixelTile& tile) {
    iterations.fetch_add(castTile(block, rays, tile, beam, options.cast,
                                  [&](int x, int y, const OctreeRay&, const CastHit& hit) {
                                    result.depth[std::size_t(y) * camera.width + x] = hit.t;
                                  }),
                         std::memory_order_relaxed);
  });
  result.hits = countHits(result.depth);
  result.meanIterations = double(iterations.load()) / double(result.depth.size());
  return result;
}

struct Timed {
  Summary seconds;
  TraceResult last;  // the result of the last run
};

std::string mrays(double rays, double seconds) {
  return fmt::format("{:.2f}", rays / seconds * 1e-6);
}
std::string percent(std::uint64_t part, std::uint64_t whole) {
  return fmt::format("{:.2f}%", whole ? 100.0 * double(part) / double(whole) : 0.0);
}

void addMethodRow(Table& table, const std::string& name, const Timed& timed, double rays, bool iterations,
                  std::optional<double> peerMedianSeconds) {
  table.addRow({name, mrays(rays, timed.seconds.median),
                fmt::format("{} / {}", mrays(rays, timed.seconds.max), mrays(rays, timed.seconds.min)),
                formatSeconds(timed.seconds.median), percent(timed.last.hits, timed.last.depth.size()),
                iterations ? fmt::format("{:.1f}", timed.last.meanIterations) : std::string("-"),
                peerMedianSeconds ? fmt::format("{:.3f}x", *peerMedianSeconds / timed.seconds.median)
                                  : std::string(kPeerNotBuilt)});
}

void printMemory(const BuildStats& stats, const WholeScene& scene) {
  const LayoutStats& layout = stats.layout;
  const double leaves = double(std::max<std::uint64_t>(stats.leafVoxels, 1));
  if (scene.isPaged()) {
    printTitle(
        fmt::format("Octree memory per leaf voxel ({} leaf voxels, paged)", formatCount(stats.leafVoxels)));
    fmt::print(
        "the octree exceeds one block: its blocks in the pool take {:.1f} MB, {:.2f} B per leaf voxel "
        "(parts are split for one block only)\n",
        double(scene.bytes()) / (1 << 20), double(scene.bytes()) / leaves);
    return;
  }
  const bool hasColor = layout.colorValues > 0 || layout.inheritedColors > 0;
  const double paperAttributes = (hasColor ? kPaperColorBytes : 0.0) + kPaperNormalBytes;
  const double paperTotal = kPaperHierarchyBytes + kPaperContourBytes + paperAttributes;
  const double hierarchy = double(layout.hierarchyBytes) / leaves;
  const double contours = double(layout.contourBytes) / leaves;
  const double attributes = double(layout.attributeBytes) / leaves;
  const double total = double(layout.totalBytes) / leaves;

  printTitle(fmt::format("Octree memory per leaf voxel ({} leaf voxels, block {:.1f} MB)",
                         formatCount(stats.leafVoxels), double(scene.bytes()) / (1 << 20)));
  Table table({"part", "ESVO B/voxel", "paper B/voxel", "ESVO/paper"});
  const auto row = [&](std::string name, double ours, double paper) {
    table.addRow({std::move(name), fmt::format("{:.2f}", ours), fmt::format("~{:.0f}", paper),
                  fmt::format("{:.2f}x", ours / paper)});
  };
  row("hierarchy (incl. far pointers, page headers)", hierarchy, kPaperHierarchyBytes);
  row("contours", contours, kPaperContourBytes);
  row(hasColor ? "attributes (color + normal, uncompressed)" : "attributes (normal only, uncompressed)",
      attributes, paperAttributes);
  row("total (incl. info section, padding)", total, paperTotal);
  table.print();
  fmt::print("attribute values stored: {} colors ({} inherited), {} normals ({} inherited); {} contours\n",
             formatCount(layout.colorValues), formatCount(layout.inheritedColors),
             formatCount(layout.normalValues), formatCount(layout.inheritedNormals),
             formatCount(stats.contours));
  const double paperWithColor =
      kPaperHierarchyBytes + kPaperContourBytes + kPaperColorBytes + kPaperNormalBytes;
  fmt::print(
      "paper Table 1: ~{:.0f} B/voxel with compressed attributes (hierarchy ~{:.0f}, contours ~{:.0f}, "
      "color {:.0f}, normal {:.0f}){}.\n",
      paperWithColor, kPaperHierarchyBytes, kPaperContourBytes, kPaperColorBytes, kPaperNormalBytes,
      hasColor ? std::string()
               : fmt::format("; this scene has no color, so ~{:.0f} is the comparable figure", paperTotal));
  fmt::print(
      "uncompressed attributes here: {:.2f} B/voxel, {:.2f}x the paper's compressed {:.0f} ({:+.2f}); "
      "total {:.2f} B/voxel, {:.2f}x the paper's ~{:.0f} ({:+.2f}).\n",
      attributes, attributes / paperAttributes, paperAttributes, attributes - paperAttributes, total,
      total / paperTotal, paperTotal, total - paperTotal);
}

void printAgreement([[maybe_unused]] const std::vector<float>& esvo, [[maybe_unused]] const TraceResult* peer,
                    [[maybe_unused]] double finestVoxel) {
  printTitle("Agreement, ESVO svo::render vs Embree (same camera rays)");
  if (!peer) {
    fmt::print("{}\n", kPeerNotBuilt);
    return;
  }
  std::uint64_t both = 0, onlyEsvo = 0, onlyPeer = 0;
  std::vector<double> difference;
  for (std::size_t i = 0; i < esvo.size(); ++i) {
    const bool a = std::isfinite(esvo[i]), b = std::isfinite(peer->depth[i]);
    if (a && b) {
      ++both;
      difference.push_back(std::abs(double(esvo[i]) - double(peer->depth[i])) / finestVoxel);
    } else if (a) {
      ++onlyEsvo;
    } else if (b) {
      ++onlyPeer;
    }
  }
  const std::uint64_t pixels = esvo.size();
  Table table({"pixels", "count", "fraction"});
  table.addRow({"both hit", formatCount(both), percent(both, pixels)});
  table.addRow({"exactly one hits (silhouette mismatch)", formatCount(onlyEsvo + onlyPeer),
                percent(onlyEsvo + onlyPeer, pixels)});
  table.addRow({"  ESVO only", formatCount(onlyEsvo), percent(onlyEsvo, pixels)});
  table.addRow({"  Embree only", formatCount(onlyPeer), percent(onlyPeer, pixels)});
  table.addRow({"neither", formatCount(pixels - both - onlyEsvo - onlyPeer),
                percent(pixels - both - onlyEsvo - onlyPeer, pixels)});
  table.print();
  if (difference.empty()) {
    fmt::print("no pixel hit by both: no depth comparison\n");
    return;
  }
  // 95th percentile of the depth difference: the tail beside the median.
  constexpr double kTailQuantile = 0.95;
  std::sort(difference.begin(), difference.end());
  const double median = summarize(difference).median;
  const double tail =
      difference[std::min(difference.size() - 1, std::size_t(kTailQuantile * difference.size()))];
  fmt::print(
      "|depth difference| where both hit, in finest voxels ({:.4g} world units): median {:.3f}, "
      "95th percentile {:.3f}, max {:.3f}\n",
      finestVoxel, median, tail, difference.back());
}

// The GPU caster's shaded frames of the same camera (--device gpu): the octree uploaded once (a paged one
// through the pool's mirror), then timed like the CPU methods. `name` receives the device's name.
Timed timeGpu(const WholeScene& scene, const Camera& camera, const RenderOptions& options, int runs,
              std::string& name) {
  std::unique_ptr<gpu::HeadlessGpu> device;
  try {
    device = std::make_unique<gpu::HeadlessGpu>();
  } catch (const gpu::GpuUnavailable& e) {
    throw std::runtime_error(std::string("--device gpu: ") + e.what());
  }
  name = device->renderer();
  gpu::GpuCaster& caster = device->caster();
  std::unique_ptr<gpu::GpuPool> pool;
  const BlockView root = scene.root();
  std::uint32_t rootSlot = root.info().rootSlot;
  if (scene.isPaged()) {
    pool = std::make_unique<gpu::GpuPool>(caster, *scene.pager());
    pool->sync();
    rootSlot = scene.pager()->takePoolChanges().rootSlot;
  } else {
    caster.reserve(root.size());
    caster.upload(0, std::span<const std::byte>(root.base(), root.size()));
  }
  const bool colors = root.attachment(AttachmentType::Color) != nullptr;
  const bool normals = root.attachment(AttachmentType::Normal) != nullptr;
  spdlog::info("ESVO on the GPU ({}): 1 warm-up + {} runs ...", name, runs);
  Timed timed;
  Frame frame;
  timed.seconds = timeRuns(
      runs, [&] { frame = caster.render(rootSlot, colors, normals, scene.transform(), camera, options); });
  timed.last.depth = std::move(frame.depth);
  timed.last.hits = countHits(timed.last.depth);
  timed.last.meanIterations = frame.meanIterations;
  return timed;
}

void runRaycastBench(const RaycastArgs& args) {
  if (args.levels < 1 || args.levels > kMaxLevels)
    throw UsageError(fmt::format("--levels must be in [1, {}] (got {})", kMaxLevels, args.levels));
  if (args.size < 1 || args.size > kMaxImageSize)
    throw UsageError(fmt::format("--size must be in [1, {}] (got {})", kMaxImageSize, args.size));
  requireRuns(args.runs);
  if (!std::isfinite(args.lodPixels) || args.lodPixels < 0.0f)
    throw UsageError(fmt::format("--lod-pixels must be a finite number >= 0 (got {})", args.lodPixels));
  const glm::dvec3 view = parseDirection(args.view, "--view");
  const int threads = resolveThreads(args.threads);

  const Mesh mesh = loadBenchMesh(args.mesh);
  BuildOptions buildOptions;
  buildOptions.levels = args.levels;
  BuildStats stats;
  spdlog::info("building the octree, {} levels ...", args.levels);
  const SceneTransform transform = fitSceneCube(mesh);
  const BuildParameters parameters = storedParameters(buildOptions);
  // Where the octree exceeds one block it is paged whole from a scratch store, removed however this ends.
  const ScratchPath scratch("svo-bench-raycast.svo");
  std::optional<WholeScene> scene;
  const double esvoBuildSeconds = timeSeconds([&] {
    const VoxelTree tree = voxelize(mesh, transform, buildOptions, &stats);
    scene.emplace(wholeSceneOf(tree, transform, parameters, scratch.path(), &stats.layout));
  });
  const Camera camera = Camera::framing(transform, view, args.width ? args.width : args.size,
                                        args.height ? args.height : args.size);
  camera.validate();
  const double rays = double(camera.width) * camera.height;
  const double finestVoxel = transform.size / double(std::int64_t(1) << args.levels);

  RenderOptions renderOptions;
  renderOptions.lodPixels = args.lodPixels;
  renderOptions.threads = threads;

  spdlog::info("ESVO svo::render: 1 warm-up + {} runs ...", args.runs);
  Timed shaded;
  {
    Frame frame;
    shaded.seconds =
        timeRuns(args.runs, [&] { frame = render(scene->root(), transform, camera, renderOptions); });
    shaded.last.depth = std::move(frame.depth);
    shaded.last.hits = countHits(shaded.last.depth);
    shaded.last.meanIterations = frame.meanIterations;
  }
  spdlog::info("ESVO castRay only: 1 warm-up + {} runs ...", args.runs);
  Timed cast;
  cast.seconds =
      timeRuns(args.runs, [&] { cast.last = traceEsvo(*scene, camera, renderOptions, threads, false); });
  spdlog::info("ESVO castRay with the beam pass: 1 warm-up + {} runs ...", args.runs);
  Timed beamed;
  beamed.seconds =
      timeRuns(args.runs, [&] { beamed.last = traceEsvo(*scene, camera, renderOptions, threads, true); });

  std::optional<Timed> onGpu, onGpuBeam;
  std::string gpuName;
  if (args.device == "gpu") {
    RenderOptions noBeam = renderOptions;
    noBeam.beamTile = 0;
    onGpu = timeGpu(*scene, camera, noBeam, args.runs, gpuName);
    onGpuBeam = timeGpu(*scene, camera, renderOptions, args.runs, gpuName);
  }

  std::optional<double> peerSeconds;
  std::optional<Timed> peer;
  [[maybe_unused]] double peerBuildSeconds = 0.0;
#ifdef SVO_BENCH_PEERS
  spdlog::info("Embree: building the BVH (quality high) ...");
  const EmbreePeer embree(mesh, transform.toWorld(glm::dvec3(1.5)));
  peerBuildSeconds = embree.buildSeconds();
  spdlog::info("Embree rtcIntersect1: 1 warm-up + {} runs ...", args.runs);
  peer.emplace();
  peer->seconds = timeRuns(args.runs, [&] { peer->last = embree.trace(camera, threads); });
  peerSeconds = peer->seconds.median;
#endif

  printTitle("Ray casting: ESVO vs Embree 3, same camera rays");
  fmt::print("{}: {} triangles; {}x{} primary rays; {} levels; lod {} px; {} threads; median of {} runs\n",
             args.mesh, formatCount(mesh.triangles.size()), camera.width, camera.height, args.levels,
             args.lodPixels, threads, args.runs);
  Table table({"method", "Mrays/s", "min/max", "time", "hit px", "iter/ray", "vs Embree"});
  addMethodRow(table, "ESVO svo::render (shaded)", shaded, rays, true, peerSeconds);
  addMethodRow(table, "ESVO castRay (depth only)", cast, rays, true, peerSeconds);
  addMethodRow(table, "ESVO castRay + beam (depth only)", beamed, rays, true, peerSeconds);
  if (onGpu) {
    addMethodRow(table, "ESVO OpenGL compute (shaded, GPU)", *onGpu, rays, true, peerSeconds);
    addMethodRow(table, "ESVO OpenGL compute + beam (GPU)", *onGpuBeam, rays, true, peerSeconds);
  }
  if (peer) {
    addMethodRow(table, "Embree 3 rtcIntersect1", *peer, rays, false, peerSeconds);
  } else {
    table.addRow({"Embree 3 rtcIntersect1", std::string(kPeerNotBuilt)});
  }
  table.print();
  fmt::print(
      "Mrays/s: median, min/max over the runs; time: median wall time of one frame; iter/ray: ESVO loop\n"
      "iterations per ray, all rays; vs Embree: throughput ratio (> 1: faster than Embree). svo::render\n"
      "uses the beam pass (sec. 6.2, {}x{} tiles); castRay rows without and with it; every method traces "
      "the\n"
      "same 8x8 pixel tiles.\n"
      "Build: ESVO octree {}, Embree BVH {}.\n",
      renderOptions.beamTile, renderOptions.beamTile, formatSeconds(esvoBuildSeconds),
      peer ? formatSeconds(peerBuildSeconds) : std::string(kPeerNotBuilt));
  // The beam pass must not change any ray's result: count the pixels where it does.
  std::uint64_t beamChanged = 0;
  for (std::size_t i = 0; i < cast.last.depth.size(); ++i)
    beamChanged += !(cast.last.depth[i] == beamed.last.depth[i] ||
                     (std::isinf(cast.last.depth[i]) && std::isinf(beamed.last.depth[i])));
  fmt::print("beam pass vs none: {} of {} pixels differ in depth.\n", formatCount(beamChanged),
             formatCount(cast.last.depth.size()));

  if (onGpu) {
    // The beam pass changes no ray's result: the GPU's depths should equal castRay's bit for bit.
    std::uint64_t same = 0;
    for (std::size_t i = 0; i < cast.last.depth.size(); ++i)
      same += cast.last.depth[i] == onGpu->last.depth[i] ||
              (std::isinf(cast.last.depth[i]) && std::isinf(onGpu->last.depth[i]));
    fmt::print(
        "GPU: {}; {:.2f}x the CPU svo::render on this machine ({} threads); depth equal to castRay's on "
        "{} of {} pixels. Its time includes reading the frame back.\n",
        gpuName, shaded.seconds.median / onGpu->seconds.median, threads, formatCount(same),
        formatCount(cast.last.depth.size()));
  }
  printMemory(stats, *scene);
  printAgreement(shaded.last.depth, peer ? &peer->last : nullptr, finestVoxel);
}

}  // namespace

void addRaycastBench(CLI::App& bench) {
  auto args = std::make_shared<RaycastArgs>();
  CLI::App* cmd = bench.add_subcommand(
      "raycast", "ESVO ray caster vs Embree 3 on the source triangles: Mrays/s, bytes/voxel, agreement");
  cmd->add_option("mesh", args->mesh, "triangle mesh (OBJ, PLY, STL, glTF, ...)")->required();
  cmd->add_option("--levels", args->levels, "octree depth")->capture_default_str();
  cmd->add_option("--size", args->size, "image width and height in pixels")->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per method (after one warm-up); the median is reported")
      ->capture_default_str();
  cmd->add_option("--lod-pixels", args->lodPixels,
                  "ESVO level of detail: stop at voxels this many pixels wide")
      ->capture_default_str();
  cmd->add_option("--view", args->view, "view direction x,y,z for Camera::framing")->capture_default_str();
  cmd->add_option("--threads", args->threads, "threads for every method (0 = all cores)")
      ->capture_default_str();
  cmd->add_option("--width", args->width, "image width (default: --size)")
      ->check(CLI::Range(1, kMaxImageSize));
  cmd->add_option("--height", args->height, "image height (default: --size)")
      ->check(CLI::Range(1, kMaxImageSize));
  cmd->add_option("--device", args->device,
                  "gpu adds the OpenGL 4.5 compute caster (headless EGL; Mesa's llvmpipe without a GPU)")
      ->check(CLI::IsMember({"cpu", "gpu"}))
      ->capture_default_str();
  cmd->callback([args] { runRaycastBench(*args); });
}

}  // namespace svo::tools::bench
