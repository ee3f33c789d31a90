// One scene of `svo bench raycast` (bench_raycast.hpp): the octree and Embree's BVH built from the same
// mesh, the two cameras, and every method timed on the same rays at each thread count.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <stdexcept>

#include <spdlog/spdlog.h>
#include <glm/geometric.hpp>

#include "bench_raycast.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
#include "svo/gpu/headless_gpu.hpp"

namespace svo::tools::bench {
namespace {

// The close-up's target is the hit pixel of the whole view with the most hits within this many pixels on
// each side (a patch of surface, not an edge), searched on a grid of kTargetStep pixels; the best
// kCloseUpCandidates are tried in turn (a window full of hits may still centre on a city block's edge).
constexpr int kTargetWindow = 32;
constexpr int kTargetStep = 8;
constexpr std::size_t kCloseUpCandidates = 32;
// Pixels between the depth samples that estimate the surface normal at the target.
constexpr int kNormalSpan = 2;
// The close-up looks along -normal + kCloseUpTilt * (the whole view's ray): neither head-on (axis-aligned on
// a terrain or a city) nor grazing.
constexpr double kCloseUpTilt = 0.5;
// The close-up starts at this fraction of the target's distance in the whole view and halves until every
// probe ray (kCloseUpProbe per image edge) hits, at most kCloseUpHalvings times.
constexpr double kCloseUpStart = 0.25;
constexpr int kCloseUpProbe = 64;
constexpr int kCloseUpHalvings = 24;

// ESVO without shading: PixelRays + castRay per pixel over the renderer's tiles with the beam pass, without
// the hits' paths (no attribute is read), depth written as the Embree peer writes it, on options.threads
// threads, into `result` (its storage reused, as the peer's and the shaded frame's are).
void traceEsvo(const WholeScene& scene, const Camera& camera, const RenderOptions& options,
               TraceResult& result) {
  // Each pixel is written once, in its tile's task, as the Embree peer writes them.
  result.depth.resize(std::size_t(camera.width) * camera.height);
  const BlockView block = scene.root();
  const PixelRays rays(scene.transform(), camera, options.lodPixels);
  CastOptions cast = options.cast;
  cast.recordPath = false;  // depth alone: no attribute is looked up
  std::atomic<std::uint64_t> iterations{0};
  forEachTile(camera.width, camera.height, renderTileSize(options), options.threads,
              [&](const PixelTile& tile) {
                int raysCast = 0;
                const auto write = [&](int x, int y, float depth) {
                  result.depth[std::size_t(y) * camera.width + x] = depth;
                  ++raysCast;
                };
                iterations.fetch_add(
                    castTile(
                        block, rays, tile, options.beamTile > 0, cast,
                        [&](int x, int y, const OctreeRay&, const CastHit& hit) { write(x, y, hit.t); },
                        [&](int x, int y, const CastHit&) { write(x, y, kInfinity); }),
                    std::memory_order_relaxed);
                // A tile the beam pass skipped casts no ray: all misses.
                for (int y = tile.y0; y < tile.y1 && raysCast == 0; ++y)
                  for (int x = tile.x0; x < tile.x1; ++x)
                    result.depth[std::size_t(y) * camera.width + x] = kInfinity;
              });
  result.hits = countHits(result.depth);
  result.meanIterations = double(iterations.load()) / double(result.depth.size());
}

// Whether every probe ray of `camera` (the same view at kCloseUpProbe pixels across) hits the octree.
bool hitsEverywhere(const WholeScene& scene, Camera camera, const RenderOptions& options) {
  const double aspect = double(camera.width) / double(camera.height);
  camera.width = kCloseUpProbe;
  camera.height = std::max(1, int(std::lround(kCloseUpProbe / aspect)));
  const PixelRays rays(scene.transform(), camera, options.lodPixels);
  const BlockView block = scene.root();
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x)
      if (!castRay(block, rays(x, y), options.cast).hit) return false;
  return true;
}

std::optional<Camera> closeUpAt(const WholeScene& scene, const Camera& whole, const std::vector<float>& depth,
                                int bestX, int bestY, const RenderOptions& options);

// A close-up of a surface patch the whole view sees, from near enough that every pixel hits; nullopt when
// the whole view hits nothing or no distance makes every pixel hit.
std::optional<Camera> closeUpCamera(const WholeScene& scene, const Camera& whole,
                                    const std::vector<float>& depth, const RenderOptions& options) {
  const int w = whole.width, h = whole.height;
  // Summed-area table of hits: the hit count of any window in four look-ups.
  std::vector<std::uint32_t> sum(std::size_t(w + 1) * (h + 1), 0);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      sum[std::size_t(y + 1) * (w + 1) + x + 1] =
          sum[std::size_t(y) * (w + 1) + x + 1] + sum[std::size_t(y + 1) * (w + 1) + x] -
          sum[std::size_t(y) * (w + 1) + x] + std::isfinite(depth[std::size_t(y) * w + x]);
  const auto hitsIn = [&](int x0, int y0, int x1, int y1) {  // [x0, x1) x [y0, y1), clamped
    x0 = std::clamp(x0, 0, w), x1 = std::clamp(x1, 0, w), y0 = std::clamp(y0, 0, h),
    y1 = std::clamp(y1, 0, h);
    return sum[std::size_t(y1) * (w + 1) + x1] - sum[std::size_t(y0) * (w + 1) + x1] -
           sum[std::size_t(y1) * (w + 1) + x0] + sum[std::size_t(y0) * (w + 1) + x0];
  };
  // Candidates: hit pixels with the most hits around first; among equals, nearest the image centre.
  struct Candidate {
    std::int64_t score;
    int x, y;
  };
  std::vector<Candidate> candidates;
  for (int y = kNormalSpan; y < h - kNormalSpan; y += kTargetStep)
    for (int x = kNormalSpan; x < w - kNormalSpan; x += kTargetStep) {
      if (!std::isfinite(depth[std::size_t(y) * w + x])) continue;
      const std::int64_t centre = std::int64_t(std::abs(2 * x - w)) + std::abs(2 * y - h);
      const std::int64_t around =
          hitsIn(x - kTargetWindow, y - kTargetWindow, x + kTargetWindow + 1, y + kTargetWindow + 1);
      candidates.push_back({around * 4 * (w + h) - centre, x, y});
    }
  std::sort(candidates.begin(), candidates.end(),
            [](const Candidate& a, const Candidate& b) { return a.score > b.score; });
  if (candidates.size() > kCloseUpCandidates) candidates.resize(kCloseUpCandidates);
  for (const Candidate& c : candidates)
    if (auto camera = closeUpAt(scene, whole, depth, c.x, c.y, options)) return camera;
  return std::nullopt;
}

// The close-up of the surface the whole view's pixel (x, y) hits, or nullopt when no distance makes every
// pixel hit (an edge, or a surface too small).
std::optional<Camera> closeUpAt(const WholeScene& scene, const Camera& whole, const std::vector<float>& depth,
                                int bestX, int bestY, const RenderOptions& options) {
  const int w = whole.width;
  const Camera::Basis basis = whole.basis();
  const auto pointAt = [&](int x, int y) -> std::optional<glm::dvec3> {
    const float d = depth[std::size_t(y) * w + x];
    if (!std::isfinite(d)) return std::nullopt;
    glm::dvec3 direction;
    Camera::pixelRay(whole, basis, x, y, direction);
    return whole.eye + double(d) * direction;
  };
  glm::dvec3 ray;
  Camera::pixelRay(whole, basis, bestX, bestY, ray);
  const glm::dvec3 target = *pointAt(bestX, bestY);
  glm::dvec3 forward = ray;
  const auto left = pointAt(bestX - kNormalSpan, bestY), right = pointAt(bestX + kNormalSpan, bestY);
  const auto up = pointAt(bestX, bestY - kNormalSpan), down = pointAt(bestX, bestY + kNormalSpan);
  if (left && right && up && down) {
    glm::dvec3 normal = glm::cross(*right - *left, *up - *down);
    if (glm::length(normal) > 0.0) {
      normal = glm::normalize(normal);
      if (glm::dot(normal, ray) > 0.0) normal = -normal;  // facing the eye
      forward = glm::normalize(-normal + kCloseUpTilt * ray);
    }
  }
  Camera close = whole;
  close.target = target;
  close.up = std::abs(forward.y) > 0.999 ? glm::dvec3(0.0, 0.0, -1.0) : glm::dvec3(0.0, 1.0, 0.0);
  double distance = kCloseUpStart * glm::length(target - whole.eye);
  for (int i = 0; i < kCloseUpHalvings; ++i, distance *= 0.5) {
    close.eye = target - forward * distance;
    if (hitsEverywhere(scene, close, options)) return close;
  }
  return std::nullopt;
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
  const bool colors = root.hasColors();
  const bool normals = root.hasNormals();
  spdlog::info("ESVO on the GPU ({}): 1 warm-up + {} runs ...", name, runs);
  Timed timed;
  Frame frame;
  std::vector<double> dispatchSeconds;
  timed.seconds = timeRuns(runs, [&] {
    frame = caster.render(rootSlot, colors, normals, scene.transform(), camera, options);
    dispatchSeconds.push_back(frame.deviceSeconds);
  });
  dispatchSeconds.erase(dispatchSeconds.begin());  // timeRuns' warm-up
  timed.deviceSeconds = summarize(std::move(dispatchSeconds)).median;
  timed.last.depth = std::move(frame.depth);
  timed.last.hits = countHits(timed.last.depth);
  timed.last.meanIterations = frame.meanIterations;
  return timed;
}

// Embree's frame of a row's camera on the row's threads, shaded by the MeshShading when given one; empty in a
// binary without the peers.
using PeerTrace = std::function<void(const MeshShading*, TraceResult&)>;

// ESVO's depth-only and shaded frames of `camera` and Embree's (when `peer`), timed in turn over the same
// runs into `row`, with the shaded frame's errors against Embree's; images named `imageStem` (when not empty)
// go to the output folder.
void measureRow(const WholeScene& scene, const PeerTrace& peer, const MeshShading& shading,
                const Camera& camera, const RenderOptions& options, const RaycastArgs& args,
                double finestVoxel, CameraRow& row, const std::string& imageStem) {
  row.rays = double(camera.width) * camera.height;
  Frame frame;
  const auto esvoDepth = [&] { traceEsvo(scene, camera, options, row.esvoDepth.last); };
  RenderOptions shadedOptions = options;
  shadedOptions.prefetchAttributes = attributePrefetchPays(scene.bytes());
  const auto esvoShaded = [&] { render(scene.root(), scene.transform(), camera, shadedOptions, frame); };
  if (peer) {
    row.embreeDepth.emplace(), row.embreeShaded.emplace();
    const auto seconds = timeInterleaved(
        args.runs, esvoDepth, esvoShaded, [&] { peer(nullptr, row.embreeDepth->last); },
        [&] { peer(&shading, row.embreeShaded->last); });
    row.esvoDepth.seconds = seconds[0], row.esvoShaded.seconds = seconds[1];
    row.embreeDepth->seconds = seconds[2], row.embreeShaded->seconds = seconds[3];
  } else {
    const auto seconds = timeInterleaved(args.runs, esvoDepth, esvoShaded);
    row.esvoDepth.seconds = seconds[0], row.esvoShaded.seconds = seconds[1];
  }
  row.esvoShaded.last.meanIterations = frame.meanIterations;
  const Image voxels = imageOf(std::move(frame));
  row.esvoShaded.last.hits = countHits(voxels.depth);
  const std::filesystem::path folder(args.output);
  if (!imageStem.empty()) {
    std::filesystem::create_directories(folder);
    writePng(folder / (imageStem + "-esvo.png"), voxels);
  }
  if (!row.embreeShaded) return;
  Image reference;
  reference.width = camera.width, reference.height = camera.height;
  reference.color = row.embreeShaded->last.color;
  reference.depth = row.embreeShaded->last.depth;
  compare(reference, voxels, finestVoxel, row.quality);
  if (!imageStem.empty()) writePng(folder / (imageStem + "-embree.png"), reference);
}

// The octree in both attribute layouts, where each fits one block: bytes by part, and the compressed
// values' error against the raw ones. The timed scene's block is reused when it is the raw one.
void compareLayouts(const VoxelTree& tree, const WholeScene& scene, const AttributeOptions& timed,
                    SceneResult& result) {
  if (!tree.hasColors && !tree.hasNormals) return;
  try {
    LayoutStats raw, compressed;
    std::optional<Block> rawBlock;
    if (!timed.compressed() && scene.octree()) {
      raw = result.stats.layout;
    } else {
      rawBlock.emplace(layoutBlock(tree, {}, &raw));
    }
    LayoutOptions options;
    AttributeOptions{AttributeLayout::Compressed, timed.exactNormalUnitDegrees}.applyTo(options);
    Block compressedBlock;
    result.compressSeconds = timeSeconds([&] { compressedBlock = layoutBlock(tree, options, &compressed); });
    result.compressedError =
        attributeError(rawBlock ? rawBlock->view() : scene.octree()->block.view(), compressedBlock.view());
    result.rawLayout = raw, result.compressedLayout = compressed;
  } catch (const BlockTooLarge&) {
    spdlog::info("{}: the octree exceeds one block in a layout: no comparison of the layouts", result.name);
  }
}

}  // namespace

SceneResult benchScene(const Mesh& mesh, const std::string& name, const RaycastArgs& args,
                       const std::vector<int>& threads) {
  SceneResult result;
  result.name = name;
  result.triangles = mesh.triangles.size();
  result.levels = args.levels;
  BuildOptions buildOptions;
  buildOptions.levels = args.levels;
  spdlog::info("{}: building the octree, {} levels ...", name, args.levels);
  const SceneTransform transform = fitSceneCube(mesh);
  // Where the octree exceeds one block it is paged whole from a scratch store, removed however this ends.
  const ScratchPath scratch("svo-bench-raycast.svo");
  std::optional<WholeScene> scene;
  VoxelTree tree;
  result.esvoBuildSeconds = timeSeconds([&] {
    tree = voxelize(mesh, transform, buildOptions, &result.stats);
    scene.emplace(wholeSceneOf(tree, transform, storedParameters(buildOptions), scratch.path(),
                               &result.stats.layout, args.attributes));
  });
  result.octreeBytes = scene->bytes();
  result.paged = scene->isPaged();
  result.voxels = tree.voxels.size() - 1;
  compareLayouts(tree, *scene, args.attributes, result);
  tree = VoxelTree();
  result.finestVoxel = transform.size / double(std::int64_t(1) << args.levels);

#ifdef SVO_BENCH_PEERS
  spdlog::info("{}: Embree BVH (quality high) ...", name);
  const EmbreePeer embree(mesh, transform.toWorld(glm::dvec3(1.5)));
  result.embreeBuildSeconds = embree.buildSeconds();
#endif

  RenderOptions options;
  options.cast.simd = args.simd;
  const MeshShading shading(mesh, options);
  const glm::dvec3 view = parseDirection(args.view, "--view");
  glm::dvec3 lo(std::numeric_limits<double>::infinity()), hi(-std::numeric_limits<double>::infinity());
  for (const glm::dvec3& p : mesh.positions) lo = glm::min(lo, p), hi = glm::max(hi, p);
  const Camera whole = Camera::framingBox(lo, hi, view, args.width ? args.width : args.size,
                                          args.height ? args.height : args.size);
  whole.validate();

  std::optional<Camera> close;
  for (const std::string& cameraName : args.cameras) {
    Camera camera = whole;
    if (cameraName == "close") {
      if (!close) {
        RenderOptions probe = options;
        probe.lodPixels = args.lodPixels.front();
        probe.threads = threads.back();
        TraceResult wholeTrace;
        traceEsvo(*scene, whole, probe, wholeTrace);
        close = closeUpCamera(*scene, whole, wholeTrace.depth, probe);
      }
      if (!close) {
        spdlog::warn("{}: no close-up where every pixel hits; the close-up camera is left out", name);
        continue;
      }
      camera = *close;
    }
    for (std::size_t k = 0; k < threads.size(); ++k) {
      spdlog::info("{}, {} camera, {} thread(s): 1 warm-up + {} runs, the methods in turn ...", name,
                   cameraName, threads[k], args.runs);
      PeerTrace peer;
#ifdef SVO_BENCH_PEERS
      peer = [&, threadCount = threads[k]](const MeshShading* shaded, TraceResult& result) {
        embree.trace(camera, threadCount, shaded, result);
      };
#endif
      for (float lod : args.lodPixels) {
        CameraRow row;
        row.camera = cameraName;
        row.threads = threads[k];
        row.lodPixels = lod;
        options.threads = threads[k];
        options.lodPixels = lod;
        const bool first = k == 0 && lod == args.lodPixels.front();
        measureRow(*scene, peer, shading, camera, options, args, result.finestVoxel, row,
                   args.images && first ? fmt::format("{}-{}", name, cameraName) : std::string());
        if (args.device == "gpu" && first) {
          RenderOptions noBeam = options;
          noBeam.beamTile = 0;
          row.gpu = timeGpu(*scene, camera, noBeam, args.runs, row.gpuName);
        }
        result.rows.push_back(std::move(row));
      }
    }
  }
  return result;
}

}  // namespace svo::tools::bench
