// `svo bench volume MESH`: the octree against OpenVDB on one level set. OpenVDB converts the mesh to a
// narrow-band level set with voxels as wide as the octree's finest (its own conversion, timed); svo builds
// its octree from that level set's file as `svo build x.vdb` does, directly from the field and through
// volumeToMesh (--volume-via-mesh), and from the mesh (all timed); then the same
// camera rays are cast through all three, ESVO's castRay with the beam pass against OpenVDB's
// LevelSetRayIntersector and NanoVDB's HDDA zero crossing (openToNanoVDB of the same grid, on the CPU), on
// each thread count, with the hits compared and the bytes each keeps.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <vector>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>

#ifdef SVO_BENCH_PEERS
#include <openvdb/openvdb.h>
#include <openvdb/tools/MeshToVolume.h>
#include <openvdb/tools/RayIntersector.h>

#include "vdb_peer.hpp"
#endif

#include "bench_common.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/volume.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
#include "svo/store/store_writer.hpp"

namespace svo::tools::bench {
namespace {

namespace fs = std::filesystem;

// Tiles the ESVO rays are cast in (the renderer's beam tile), as `bench raycast` casts them.
constexpr int kVolumeTileSize = 8;
// Percentile of the depth differences reported beside the median (the tail, edges aside).
constexpr double kDepthPercentile = 0.99;

struct VolumeArgs {
  std::string mesh;
  int levels = 9;
  int size = 512;
  int runs = 3;
  std::vector<int> threads;
  std::string view = "-0.35,-0.25,-1";
};

// A frame's depths (world distance, infinity for a miss) and how long it took.
struct DepthFrame {
  std::vector<float> depth;
  Summary seconds;
};

DepthFrame castEsvo(const BlockView& block, const SceneTransform& scene, const Camera& camera, int threads,
                    int runs) {
  DepthFrame frame;
  frame.depth.assign(std::size_t(camera.width) * camera.height, std::numeric_limits<float>::infinity());
  const PixelRays rays(scene, camera, 0.0f);
  frame.seconds = timeRuns(runs, [&] {
    forEachTile(camera.width, camera.height, kVolumeTileSize, threads, [&](const PixelTile& tile) {
      castTile(block, rays, tile, true, CastOptions{.recordPath = false},
               [&](int x, int y, const OctreeRay&, const CastHit& hit) {
                 frame.depth[std::size_t(y) * camera.width + x] = hit.t;
               });
    });
  });
  return frame;
}

// Where both hit: the share of pixels hit by one only, and the depth difference's median and tail.
struct Agreement {
  std::uint64_t hits = 0, peerHits = 0, mismatches = 0;
  double medianDepth = 0.0, tailDepth = 0.0;  // in voxels
};
Agreement compare(const std::vector<float>& a, const std::vector<float>& b, double voxel) {
  Agreement out;
  std::vector<double> differences;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const bool hitA = std::isfinite(a[i]), hitB = std::isfinite(b[i]);
    out.hits += hitA, out.peerHits += hitB;
    if (hitA != hitB) ++out.mismatches;
    if (hitA && hitB) differences.push_back(std::abs(double(a[i]) - double(b[i])) / voxel);
  }
  if (!differences.empty()) {
    std::sort(differences.begin(), differences.end());
    out.medianDepth = differences[differences.size() / 2];
    out.tailDepth = differences[std::size_t(kDepthPercentile * double(differences.size() - 1))];
  }
  return out;
}

#ifdef SVO_BENCH_PEERS
// OpenVDB's level set of the mesh, voxels of `voxelSize` lined up with the octree's cube at `corner`.
openvdb::FloatGrid::Ptr levelSetOf(const Mesh& mesh, glm::dvec3 corner, double voxelSize) {
  const VdbMesh relative = toVdbMesh(mesh, corner);
  openvdb::FloatGrid::Ptr grid = openvdb::tools::meshToLevelSet<openvdb::FloatGrid>(
      *openvdb::math::Transform::createLinearTransform(voxelSize), relative.points, relative.triangles,
      kLevelSetHalfWidth);
  grid->transform().postTranslate(openvdb::Vec3d(corner.x, corner.y, corner.z));
  grid->setName("surface");
  return grid;
}

// Each peer's rays, a task per band of rows: `cast(x, y, eye, direction)` gives the world distance.
template <class Cast>
DepthFrame castRows(const Camera& camera, int runs, const Cast& cast) {
  DepthFrame frame;
  frame.depth.assign(std::size_t(camera.width) * camera.height, std::numeric_limits<float>::infinity());
  const Camera::Basis basis = camera.basis();
  frame.seconds = timeRuns(runs, [&] {
    tbb::parallel_for(tbb::blocked_range<int>(0, camera.height), [&](const tbb::blocked_range<int>& rows) {
      auto ray = cast();  // a caster per task: neither peer's is thread-safe
      for (int y = rows.begin(); y < rows.end(); ++y)
        for (int x = 0; x < camera.width; ++x) {
          glm::dvec3 direction;
          Camera::pixelRay(camera, basis, x, y, direction);
          const double t = ray(camera.eye, direction);
          if (std::isfinite(t)) frame.depth[std::size_t(y) * camera.width + x] = float(t);
        }
    });
  });
  return frame;
}

DepthFrame castOpenVdb(const openvdb::FloatGrid& grid, const Camera& camera, int runs) {
  using Intersector = openvdb::tools::LevelSetRayIntersector<openvdb::FloatGrid>;
  const Intersector prototype(grid);
  return castRows(camera, runs, [&] {
    return [intersector = Intersector(prototype)](const glm::dvec3& eye, const glm::dvec3& d) mutable {
      const openvdb::math::Ray<double> ray(openvdb::Vec3d(eye.x, eye.y, eye.z),
                                           openvdb::Vec3d(d.x, d.y, d.z));
      // The overload with the hit point too: the one with the time alone reads it before the search.
      openvdb::Vec3d hit;
      double t = 0.0;
      return intersector.intersectsWS(ray, hit, t) ? t : std::numeric_limits<double>::infinity();
    };
  });
}

DepthFrame castNanoVdb(const NanoLevelSet& grid, const Camera& camera, int runs) {
  return castRows(camera, runs, [&] {
    return [&grid, accessor = grid.accessor()](const glm::dvec3& eye, const glm::dvec3& d) mutable {
      return grid.intersect(accessor, eye, d);
    };
  });
}
#endif

void runVolumeBench(const VolumeArgs& args) {
#ifndef SVO_BENCH_PEERS
  throw UsageError("svo bench volume compares with OpenVDB: this binary was built without the peers");
#else
  requireRuns(args.runs);
  const std::vector<int> threads =
      args.threads.empty() ? std::vector<int>{1, tbb::info::default_concurrency()} : args.threads;
  const Mesh mesh = loadMesh(args.mesh);
  const SceneTransform cube = fitSceneCube(mesh);
  const double voxel = cube.size / double(1 << args.levels);
  const ScratchPath vdbFile("svo-bench-volume.vdb"), store("svo-bench-volume.svo");

  spdlog::info("OpenVDB: meshToLevelSet, voxels {:.4g} wide ...", voxel);
  const std::optional<LevelSetResult> vdbBuild = openVdbLevelSet(mesh, cube.origin, voxel, args.runs);
  const openvdb::FloatGrid::Ptr grid = levelSetOf(mesh, cube.origin, voxel);
  {
    openvdb::io::File file(vdbFile.path().string());
    file.write({grid});
    file.close();
  }

  spdlog::info(
      "svo: the octree from the level set's file (directly and through volumeToMesh) and from the "
      "mesh ...");
  BuildOptions build;
  build.levels = args.levels;
  Octree direct, viaMesh;
  VoxelTree directTree;  // the last run's, written as the store
  const Summary directBuild = timeRuns(args.runs, [&] {
    SurfaceVolume volume = voxelizeVolumeSurface(vdbFile.path(), {}, build);
    direct.transform = volume.transform;
    direct.block = layoutBlock(volume.tree);
    directTree = std::move(volume.tree);
  });
  BuildStats meshedStats;
  const Summary meshedBuild = timeRuns(args.runs, [&] {
    const Mesh surface = loadVolumeSurface(vdbFile.path(), {});
    viaMesh.transform = fitSceneCube(surface);
    meshedStats = BuildStats{};
    viaMesh.block = layoutBlock(voxelize(surface, viaMesh.transform, build, &meshedStats));
  });
  direct.parameters = viaMesh.parameters = storedParameters(build);
  BuildStats stats;
  const Summary meshBuild = timeRuns(args.runs, [&] { layoutBlock(voxelize(mesh, cube, build, &stats)); });
  const std::vector<SliceInfo> slices =
      writeStore(store.path(), directTree, direct.transform, direct.parameters);
  std::uint64_t leaves = 0;
  for (const SliceInfo& s : slices)
    if (s.voxelLevel == args.levels) leaves += s.voxelCount;

  printTitle(fmt::format("Build: {} ({} triangles), {} levels, voxels {:.4g} wide (median of {} runs)",
                         args.mesh, formatCount(mesh.triangles.size()), args.levels, voxel, args.runs));
  Table builds({"what", "seconds", "voxels"});
  builds.addRow({"OpenVDB meshToLevelSet (mesh -> narrow-band level set)",
                 formatSeconds(vdbBuild->seconds.median), formatCount(vdbBuild->activeVoxels)});
  builds.addRow({"svo from the level set, directly (.vdb -> octree)", formatSeconds(directBuild.median),
                 formatCount(leaves) + " leaves"});
  builds.addRow({"svo from the level set, --volume-via-mesh (.vdb -> volumeToMesh -> octree)",
                 formatSeconds(meshedBuild.median), formatCount(meshedStats.leafVoxels) + " leaves"});
  builds.addRow({"svo from the mesh (mesh -> octree)", formatSeconds(meshBuild.median),
                 formatCount(stats.leafVoxels) + " leaves"});
  builds.print();

  const Camera camera =
      Camera::framingBox(direct.transform.toWorld(glm::dvec3(1.0)), direct.transform.toWorld(glm::dvec3(2.0)),
                         parseDirection(args.view, "--view"), args.size, args.size);
  printTitle(
      fmt::format("Ray casting the same level set: {}x{} rays, Mrays/s (median of {} runs); agreement "
                  "with OpenVDB's intersector and with ESVO on the direct octree",
                  args.size, args.size, args.runs));
  const NanoLevelSet nano(*grid);
  Table rays({"threads", "caster", "Mrays/s", "ESVO speed-up", "hit px", "vs OpenVDB: hit by one only",
              "depth diff median", "p99", "vs ESVO: hit by one only", "depth diff median"});
  const double pixels = double(camera.width) * camera.height;
  for (const int t : threads) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, std::size_t(t));
    const DepthFrame esvo = castEsvo(direct.block.view(), direct.transform, camera, t, args.runs);
    const DepthFrame esvoViaMesh = castEsvo(viaMesh.block.view(), viaMesh.transform, camera, t, args.runs);
    const DepthFrame vdb = castOpenVdb(*grid, camera, args.runs);
    const DepthFrame nanoFrame = castNanoVdb(nano, camera, args.runs);
    const double esvoRate = pixels / esvo.seconds.median * 1e-6;
    const auto addCaster = [&](const char* name, const DepthFrame& frame) {
      const Agreement withVdb = compare(frame.depth, vdb.depth, voxel);
      const Agreement withEsvo = compare(frame.depth, esvo.depth, voxel);
      const double rate = pixels / frame.seconds.median * 1e-6;
      const auto percent = [&](std::uint64_t n) {
        return fmt::format("{:.2f}%", 100.0 * double(n) / pixels);
      };
      const bool isVdb = &frame == &vdb, isEsvo = &frame == &esvo;
      rays.addRow({std::to_string(t), name, fmt::format("{:.2f}", rate),
                   fmt::format("{:.2f}x", esvoRate / rate), percent(withVdb.hits),
                   isVdb ? "" : percent(withVdb.mismatches),
                   isVdb ? "" : fmt::format("{:.2f} vx", withVdb.medianDepth),
                   isVdb ? "" : fmt::format("{:.2f} vx", withVdb.tailDepth),
                   isEsvo ? "" : percent(withEsvo.mismatches),
                   isEsvo ? "" : fmt::format("{:.2f} vx", withEsvo.medianDepth)});
    };
    addCaster("ESVO castRay, octree built directly", esvo);
    addCaster("ESVO castRay, octree built via volumeToMesh", esvoViaMesh);
    addCaster("OpenVDB LevelSetRayIntersector", vdb);
    addCaster("NanoVDB HDDA ZeroCrossing (CPU)", nanoFrame);
  }
  rays.print();

  const double perLeaf = 1.0 / double(std::max<std::uint64_t>(leaves, 1));
  printTitle(fmt::format("Bytes ({} leaf voxels of the octree, {} active voxels of the level set)",
                         formatCount(leaves), formatCount(grid->activeVoxelCount())));
  Table bytes({"what", "MiB", "B per octree leaf voxel"});
  const auto row = [&](std::string what, std::uint64_t n) {
    bytes.addRow({std::move(what), fmt::format("{:.2f}", double(n) / (1 << 20)),
                  fmt::format("{:.2f}", double(n) * perLeaf)});
  };
  row("OpenVDB file (.vdb, its default compression)", fs::file_size(vdbFile.path()));
  row("OpenVDB grid in memory (memUsage)", grid->memUsage());
  row("NanoVDB buffer (openToNanoVDB, float values)", nano.bytes());
  row("svo store (.svo)", fs::file_size(store.path()));
  row("svo octree in memory (one block, raw attributes)", direct.block.bytes().size());
  bytes.print();
  std::printf(
      "ESVO casts the octree built from OpenVDB's level set at the same voxel width; depth differences are "
      "in "
      "those voxels, where both hit. OpenVDB's intersector refines its hit to the interpolated zero "
      "crossing; "
      "NanoVDB's ZeroCrossing stops on the face of the first voxel past the sign change, within a voxel of "
      "the "
      "surface and further along grazing rays.\n");
#endif
}

}  // namespace

void addVolumeBench(CLI::App& bench) {
  auto args = std::make_shared<VolumeArgs>();
  auto* cmd = bench.add_subcommand(
      "volume", "the octree against OpenVDB on one level set: build times, ray casting, bytes");
  cmd->add_option("mesh", args->mesh, "triangle mesh that OpenVDB turns into a level set")->required();
  cmd->add_option("--levels", args->levels,
                  "octree depth; the level set's voxels are the finest voxels' width")
      ->check(CLI::Range(2, 14))
      ->capture_default_str();
  cmd->add_option("--size", args->size, "image width and height in pixels")
      ->check(CLI::Range(16, 4096))
      ->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per method (after one warm-up); the median is reported")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "thread counts to measure (default: 1 and all cores)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--view", args->view, "view direction x,y,z")->capture_default_str();
  cmd->callback([args] { runVolumeBench(*args); });
}

}  // namespace svo::tools::bench
