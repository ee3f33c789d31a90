// `svo bench raycast MESH...`: primary-ray throughput of the ESVO ray caster against Embree 3 on the source
// triangles, like for like (depth only against rtcIntersect1; shaded against Embree plus the same Phong
// shading), same rays, same thread count, measured in the same run, on a whole-scene camera and a close-up;
// with iterations per ray and the image error against Embree's frame. `--scaling 10k,...,10M`: the same
// on generated scenes of growing triangle count at a fixed voxel resolution, as a table and a plot.
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "bench_raycast.hpp"
#include "pager_flags.hpp"
#include "plot.hpp"
#include "svo/builder/gen.hpp"

namespace svo::tools::bench {

namespace {

// The GPU caster's depths against the CPU caster's: the share of pixels equal to the bit (misses on both
// count as equal), and the largest difference in float ulps where both hit (a miss on one side only counts
// against the share alone). The two casters compute the same float operations, so both should be 100% and 0.
struct DepthAgreement {
  double equalShare = 0.0;
  std::int64_t maxUlps = 0;
};
DepthAgreement depthAgreement(const std::vector<float>& gpu, const std::vector<float>& cpu) {
  const auto ordered = [](float f) {  // floats as integers in their order, so ulps are differences
    const auto i = std::bit_cast<std::int32_t>(f);
    return i < 0 ? std::int64_t(INT32_MIN) - i : std::int64_t(i);
  };
  DepthAgreement a;
  std::size_t equal = 0;
  const std::size_t n = std::min(gpu.size(), cpu.size());
  for (std::size_t i = 0; i < n; ++i) {
    if (std::bit_cast<std::uint32_t>(gpu[i]) == std::bit_cast<std::uint32_t>(cpu[i])) {
      ++equal;
    } else if (std::isfinite(gpu[i]) && std::isfinite(cpu[i])) {
      a.maxUlps = std::max(a.maxUlps, std::abs(ordered(gpu[i]) - ordered(cpu[i])));
    }
  }
  a.equalShare = n ? double(equal) / double(n) : 0.0;
  return a;
}

// Largest image edge accepted, as Camera::validate does.
constexpr int kMaxImageSize = 16384;
// Paper Table 1 (ESVO, compressed attributes), bytes per leaf voxel: hierarchy, contours, DXT color, normal.
constexpr double kPaperHierarchyBytes = 1.0;
constexpr double kPaperContourBytes = 1.0;
constexpr double kPaperColorBytes = 1.0;
constexpr double kPaperNormalBytes = 2.0;

std::string mrays(double rays, const Timed& timed) {
  return fmt::format("{:.2f}", mraysPerSecond(rays, timed.seconds.median));
}
std::string ratio(const Timed& ours, const std::optional<Timed>& peer) {
  return peer ? fmt::format("{:.2f}x", peer->seconds.median / ours.seconds.median)
              : std::string(kPeerNotBuilt);
}
std::string percent(std::uint64_t part, std::uint64_t whole) {
  return fmt::format("{:.1f}%", whole ? 100.0 * double(part) / double(whole) : 0.0);
}

void printMemory(const SceneResult& scene, float exactNormalUnitDegrees) {
  const double leaves = double(std::max<std::uint64_t>(scene.stats.leafVoxels, 1));
  if (!scene.rawLayout || !scene.compressedLayout) {
    printTitle(fmt::format("Octree memory per leaf voxel ({} leaf voxels, paged)",
                           formatCount(scene.stats.leafVoxels)));
    fmt::print(
        "the octree exceeds one block: its blocks in the pool take {:.1f} MB, {:.2f} B per leaf voxel "
        "(parts are split for one block only)\n",
        double(scene.octreeBytes) / (1 << 20), double(scene.octreeBytes) / leaves);
    return;
  }
  const LayoutStats &raw = *scene.rawLayout, &compressed = *scene.compressedLayout;
  const bool hasColor = raw.colorBytes > 0;
  // Paper Table 1 counts bytes per voxel of every level (sec. 5.6: a descriptor per four voxels).
  const double voxels = double(std::max<std::uint64_t>(scene.voxels, 1));
  const double paperTotal =
      kPaperHierarchyBytes + kPaperContourBytes + (hasColor ? kPaperColorBytes : 0.0) + kPaperNormalBytes;
  printTitle(
      fmt::format("Octree memory ({} leaf voxels, {} voxels in all; one block: raw {:.1f} MB, "
                  "compressed {:.1f} MB)",
                  formatCount(scene.stats.leafVoxels), formatCount(scene.voxels),
                  double(raw.totalBytes) / (1 << 20), double(compressed.totalBytes) / (1 << 20)));
  Table table({"part", "raw B/leaf", "compressed B/leaf", "compressed B/voxel", "paper B/voxel"});
  const auto row = [&](std::string name, double rawBytes, double compressedBytes, double paper) {
    table.addRow({std::move(name), fmt::format("{:.2f}", rawBytes / leaves),
                  fmt::format("{:.2f}", compressedBytes / leaves),
                  fmt::format("{:.2f}", compressedBytes / voxels),
                  paper > 0.0 ? fmt::format("~{:.0f}", paper) : std::string("-")});
  };
  row("hierarchy (incl. far pointers, page headers, links)", double(raw.hierarchyBytes),
      double(compressed.hierarchyBytes), kPaperHierarchyBytes);
  row("contours (pointer words and values)", double(raw.contourBytes), double(compressed.contourBytes),
      kPaperContourBytes);
  if (hasColor) row("colors", double(raw.colorBytes), double(compressed.colorBytes), kPaperColorBytes);
  row("normals", double(raw.normalBytes), double(compressed.normalBytes), kPaperNormalBytes);
  row("total (incl. info section, padding)", double(raw.totalBytes), double(compressed.totalBytes),
      paperTotal);
  table.print();
  const AttributeError& e = *scene.compressedError;
  fmt::print(
      "raw: {} colors and {} normals stored, {} and {} inherited; compressed: {} pairs of slots, {:.0f}% of "
      "their halves hold children, {} hold a color unit and {} a normal unit ({} of them exact: their "
      "values, where no grid comes within {:.1f} deg) (the others' children inherit), laid out in {}. "
      "Compressed against raw over {} voxels: color RMSE {:.2f}, max {:.0f} "
      "(8-bit steps); normal mean {:.3f} deg, max {:.2f} deg. Paper Table 1: ~{:.0f} B per voxel of every "
      "level "
      "with compressed attributes{}.\n",
      formatCount(raw.colorValues), formatCount(raw.normalValues), formatCount(raw.inheritedColors),
      formatCount(raw.inheritedNormals), formatCount(compressed.units),
      100.0 * double(compressed.unitHalvesUsed) / double(std::max<std::uint64_t>(2 * compressed.units, 1)),
      formatCount(compressed.colorUnitsKept), formatCount(compressed.normalUnitsKept),
      formatCount(compressed.exactNormalUnits), exactNormalUnitDegrees, formatSeconds(scene.compressSeconds),
      formatCount(e.voxels), e.colorRmse, e.colorMax, e.normalMeanDegrees, e.normalMaxDegrees, paperTotal,
      hasColor ? "" : " (this scene has no color)");
}

void printScenes(const std::vector<SceneResult>& scenes) {
  printTitle("Scenes");
  Table table({"scene", "triangles", "levels", "leaf voxels", "octree", "B/leaf voxel", "ESVO build",
               "Embree build"});
  for (const SceneResult& s : scenes)
    table.addRow(
        {s.name, formatCount(s.triangles), std::to_string(s.levels), formatCount(s.stats.leafVoxels),
         fmt::format("{:.1f} MB{}", double(s.octreeBytes) / (1 << 20), s.paged ? " paged" : ""),
         fmt::format("{:.2f}",
                     double(s.octreeBytes) / double(std::max<std::uint64_t>(s.stats.leafVoxels, 1))),
         formatSeconds(s.esvoBuildSeconds),
         s.embreeBuildSeconds > 0.0 ? formatSeconds(s.embreeBuildSeconds) : std::string(kPeerNotBuilt)});
  table.print();
}

std::string packetLoopName(PacketSimd used) {
  switch (used) {
    case PacketSimd::Avx512:
      return "32-ray AVX-512 packets";
    case PacketSimd::Avx2:
      return "8-ray AVX2 packets";
    default:
      return "one ray at a time";
  }
}

void printComparison(const std::vector<SceneResult>& scenes, const RaycastArgs& args) {
  printTitle(
      fmt::format("Ray casting: ESVO ({}) vs Embree 3, same rays, same threads (Mrays/s, median of {} runs, "
                  "the methods in turn)",
                  packetLoopName(packetSimdUsed(args.simd)), args.runs));
  Table table({"scene", "camera", "thr", "LOD", "hit px", "depth ESVO", "Embree", "ESVO/Embree",
               "shaded ESVO", "Embree", "ESVO/Embree", "iter/ray", "PSNR dB", "depth p99", "silhouette"});
  for (const SceneResult& s : scenes)
    for (const CameraRow& r : s.rows) {
      const bool peer = r.embreeShaded.has_value();
      table.addRow({s.name, r.camera, std::to_string(r.threads), fmt::format("{:g} px", r.lodPixels),
                    percent(r.esvoDepth.last.hits, r.esvoDepth.last.depth.size()), mrays(r.rays, r.esvoDepth),
                    r.embreeDepth ? mrays(r.rays, *r.embreeDepth) : std::string(kPeerNotBuilt),
                    ratio(r.esvoDepth, r.embreeDepth), mrays(r.rays, r.esvoShaded),
                    r.embreeShaded ? mrays(r.rays, *r.embreeShaded) : std::string(kPeerNotBuilt),
                    ratio(r.esvoShaded, r.embreeShaded),
                    fmt::format("{:.1f}", r.esvoDepth.last.meanIterations),
                    peer ? fmt::format("{:.1f}", r.quality.psnr) : "-",
                    peer ? fmt::format("{:.2f} vx", r.quality.depthTailOffEdges) : "-",
                    peer ? fmt::format("{:.2f}%", r.quality.silhouettePercent) : "-"});
    }
  table.print();
  fmt::print(
      "{} px. whole: framed to the model's projected box; close: a surface patch from near enough that every "
      "pixel hits;\n"
      "LOD: ESVO stops at voxels this many pixels wide. depth: ESVO castRay with the beam pass (sec. 6.2, "
      "16x16 tiles), without\n"
      "the hits' paths (which only attribute look-ups read), vs rtcIntersect1; shaded: svo::render vs "
      "rtcIntersect1 plus the same Phong shading with normals (and colors) interpolated from\n"
      "the mesh. ESVO/Embree > 1: ESVO "
      "is faster. iter/ray: ESVO loop iterations per ray, all rays. PSNR, depth p99 (in finest voxels, where "
      "both hit, off edges) and\n"
      "silhouette (pixels hit by exactly one): ESVO's shaded frame against Embree's.\n",
      args.width ? args.width : args.size);
  for (const SceneResult& s : scenes)
    for (const CameraRow& r : s.rows)
      if (r.gpu) {
        const DepthAgreement agreement = depthAgreement(r.gpu->last.depth, r.esvoDepth.last.depth);
        fmt::print(
            "GPU ({}), {} {}: shaded without the beam pass, {:.2f} Mrays/s in the dispatches (GPU timer), "
            "{:.2f} with the frame read back; depths equal to the CPU caster's on {:.3f}% of the pixels "
            "(largest difference {} ulps).\n",
            r.gpuName, s.name, r.camera, mraysPerSecond(r.rays, r.gpu->deviceSeconds),
            mraysPerSecond(r.rays, r.gpu->seconds.median), 100.0 * agreement.equalShare, agreement.maxUlps);
      }
}

// Where ESVO's curve crosses Embree's: the triangle count at which their depth-only ratio passes 1,
// interpolated on log axes between the two counts around it.
std::string crossing(const std::vector<SceneResult>& scenes, const std::string& camera) {
  std::vector<std::pair<double, double>> points;  // (triangles, ESVO/Embree)
  for (const SceneResult& s : scenes)
    for (const CameraRow& r : s.rows)
      if (r.camera == camera && r.embreeDepth && r.threads == s.rows.front().threads)
        points.emplace_back(double(s.triangles), r.embreeDepth->seconds.median / r.esvoDepth.seconds.median);
  if (points.empty()) return "no Embree numbers";
  for (std::size_t i = 1; i < points.size(); ++i) {
    const auto [t0, r0] = points[i - 1];
    const auto [t1, r1] = points[i];
    if ((r0 < 1.0) != (r1 < 1.0)) {
      const double f = std::log(r0) / (std::log(r0) - std::log(r1));
      const double at = std::exp(std::log(t0) + f * (std::log(t1) - std::log(t0)));
      return fmt::format("the curves cross at about {} triangles (ESVO {} beyond)",
                         formatCount(std::uint64_t(at)), r1 >= 1.0 ? "ahead" : "behind");
    }
  }
  return points.front().second >= 1.0 ? "ESVO ahead at every count" : "ESVO behind at every count";
}

void printScaling(const std::vector<SceneResult>& scenes, const RaycastArgs& args) {
  printTitle(fmt::format("Scaling with the triangle count: generated {} at {} levels, {} threads",
                         args.scalingKind, args.levels, scenes.front().rows.front().threads));
  Table table({"triangles", "camera", "depth ESVO", "Embree", "ESVO/Embree", "shaded ESVO", "Embree",
               "ESVO/Embree", "iter/ray", "leaf voxels"});
  std::vector<plot::Panel> panels;
  for (const std::string& camera : args.cameras) {
    plot::Panel panel{fmt::format("{} camera, depth only", camera), {}};
    plot::Series esvo{"ESVO castRay + beam", {}}, embree{"Embree rtcIntersect1", {}};
    for (const SceneResult& s : scenes)
      for (const CameraRow& r : s.rows) {
        if (r.camera != camera) continue;
        table.addRow({formatCount(s.triangles), camera, mrays(r.rays, r.esvoDepth),
                      r.embreeDepth ? mrays(r.rays, *r.embreeDepth) : std::string(kPeerNotBuilt),
                      ratio(r.esvoDepth, r.embreeDepth), mrays(r.rays, r.esvoShaded),
                      r.embreeShaded ? mrays(r.rays, *r.embreeShaded) : std::string(kPeerNotBuilt),
                      ratio(r.esvoShaded, r.embreeShaded),
                      fmt::format("{:.1f}", r.esvoDepth.last.meanIterations),
                      formatCount(s.stats.leafVoxels)});
        esvo.points.emplace_back(double(s.triangles), mraysPerSecond(r.rays, r.esvoDepth.seconds.median));
        if (r.embreeDepth)
          embree.points.emplace_back(double(s.triangles),
                                     mraysPerSecond(r.rays, r.embreeDepth->seconds.median));
      }
    panel.series = {esvo, embree};
    panels.push_back(std::move(panel));
  }
  table.print();
  for (const std::string& camera : args.cameras)
    fmt::print("{} camera: {}.\n", camera, crossing(scenes, camera));
  std::filesystem::create_directories(args.output);
  const std::filesystem::path png = std::filesystem::path(args.output) / "raycast_scaling.png";
  plot::writeLogLogPlot(png, panels, "triangles", "Mrays/s");
  fmt::print("wrote {}\n", png.string());
}

void validate(const RaycastArgs& args) {
  if (args.levels < 1 || args.levels > kMaxLevels)
    throw UsageError(fmt::format("--levels must be in [1, {}] (got {})", kMaxLevels, args.levels));
  if (args.size < 1 || args.size > kMaxImageSize)
    throw UsageError(fmt::format("--size must be in [1, {}] (got {})", kMaxImageSize, args.size));
  requireRuns(args.runs);
  for (float lod : args.lodPixels)
    if (!std::isfinite(lod) || lod < 0.0f)
      throw UsageError(fmt::format("--lod-pixels must be finite numbers >= 0 (got {})", lod));
  parseDirection(args.view, "--view");
  if (args.meshes.empty() == args.scaling.empty())
    throw UsageError("give either meshes or --scaling COUNTS, not both");
  if (!args.scaling.empty() && !parseSceneKind(args.scalingKind))
    throw UsageError(
        fmt::format("--scaling-scene must be one of {} (got '{}')", sceneKindList(), args.scalingKind));
}

// --threads: the counts given, or 1 and every core.
std::vector<int> threadCounts(const RaycastArgs& args) {
  std::vector<int> counts;
  if (args.threads.empty()) {
    counts = {1, resolveThreads(0)};
  } else {
    for (int t : args.threads) counts.push_back(resolveThreads(t));
  }
  std::sort(counts.begin(), counts.end());
  counts.erase(std::unique(counts.begin(), counts.end()), counts.end());
  return counts;
}

// "10k,100k,1M" -> counts within what svo gen accepts.
std::vector<std::uint64_t> scalingCounts(const std::string& text) {
  std::vector<std::uint64_t> counts;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t end = std::min(text.find(',', start), text.size());
    const std::string word = text.substr(start, end - start);
    const std::optional<std::uint64_t> count = parseCount(word);
    if (!count || *count < kMinGenTriangles || *count > kMaxGenTriangles)
      throw UsageError(fmt::format("--scaling: '{}' is not a triangle count in [{}, {}]", word,
                                   formatCount(kMinGenTriangles), formatCount(kMaxGenTriangles)));
    counts.push_back(*count);
    start = end + 1;
  }
  std::sort(counts.begin(), counts.end());
  return counts;
}

void runRaycastBench(const RaycastArgs& args) {
  validate(args);
  const std::vector<int> threads = threadCounts(args);
  std::vector<SceneResult> scenes;
  if (!args.scaling.empty()) {
    // One thread count (the largest) and one LOD (the first): the sweep is about the triangle count.
    const std::vector<int> sweepThreads{threads.back()};
    RaycastArgs sweep = args;
    sweep.lodPixels.resize(1);
    for (std::uint64_t count : scalingCounts(args.scaling)) {
      GenOptions gen;
      gen.kind = *parseSceneKind(args.scalingKind);
      gen.triangles = count;
      spdlog::info("generating {} with {} triangles ...", args.scalingKind, formatCount(count));
      const Mesh mesh = generateScene(gen);
      scenes.push_back(
          benchScene(mesh, fmt::format("{} {}", args.scalingKind, formatCount(count)), sweep, sweepThreads));
    }
    printScenes(scenes);
    printScaling(scenes, sweep);
    return;
  }
  for (const std::string& path : args.meshes) {
    const Mesh mesh = loadBenchMesh(path);
    scenes.push_back(benchScene(mesh, std::filesystem::path(path).stem().string(), args, threads));
  }
  printScenes(scenes);
  printComparison(scenes, args);
  for (const SceneResult& scene : scenes) printMemory(scene, args.attributes.exactNormalUnitDegrees);
}

}  // namespace

void addRaycastBench(CLI::App& bench) {
  auto args = std::make_shared<RaycastArgs>();
  CLI::App* cmd = bench.add_subcommand(
      "raycast",
      "ESVO ray caster vs Embree 3 on the source triangles, like for like: Mrays/s, iterations, image error");
  cmd->add_option("meshes", args->meshes, "triangle meshes (OBJ, PLY, STL, glTF, ...): one table row each");
  cmd->add_option("--scaling", args->scaling,
                  "instead of meshes: generated scenes of these triangle counts (e.g. 10k,100k,1M,10M), "
                  "a table and raycast_scaling.png");
  cmd->add_option("--scaling-scene", args->scalingKind,
                  "the generated scene of --scaling: " + sceneKindList())
      ->capture_default_str();
  cmd->add_option("--levels", args->levels, "octree depth")->capture_default_str();
  cmd->add_option("--size", args->size, "image width and height in pixels")->capture_default_str();
  cmd->add_option(
         "--runs", args->runs,
         "timed runs per method (after one warm-up each), the methods timed in turn; the median is reported")
      ->capture_default_str();
  cmd->add_option("--lod-pixels", args->lodPixels,
                  "ESVO levels of detail, a row each: stop at voxels this many pixels wide (e.g. 1,2,4)")
      ->delimiter(',')
      ->capture_default_str();
  cmd->add_option("--view", args->view, "view direction x,y,z of the whole-scene camera")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads,
                  "thread counts to measure, e.g. 1,2 (0 = all cores; default: 1 and all cores)")
      ->delimiter(',');
  cmd->add_option("--cameras", args->cameras, "whole (framed to the projected box), close (every pixel hits)")
      ->delimiter(',')
      ->check(CLI::IsMember({"whole", "close"}))
      ->capture_default_str();
  cmd->add_option("--width", args->width, "image width (default: --size)")
      ->check(CLI::Range(1, kMaxImageSize));
  cmd->add_option("--height", args->height, "image height (default: --size)")
      ->check(CLI::Range(1, kMaxImageSize));
  cmd->add_option("--device", args->device,
                  "gpu adds the OpenGL 4.5 compute caster (headless EGL; Mesa's llvmpipe without a GPU)")
      ->check(CLI::IsMember({"cpu", "gpu"}))
      ->capture_default_str();
  cmd->add_option("-o,--output", args->output, "folder for the scaling plot and --images")
      ->capture_default_str();
  cmd->add_flag("--images", args->images, "write each camera's ESVO and Embree frames as PNG");
  addAttributeLayoutFlag(*cmd, args->attributes);
  addPacketSimdFlag(*cmd, args->simd);
  cmd->callback([args] { runRaycastBench(*args); });
}

}  // namespace svo::tools::bench
