// `svo bench raycast`'s shared pieces: one scene measured like for like against Embree 3 (depth only, and
// shaded with the same Phong model), over a whole-scene camera framed to the model's projected box and a
// close-up where every pixel hits, at each thread count. bench_raycast.cpp prints the tables (one scene
// or several, and the triangle-count scaling sweep); bench_raycast_scene.cpp measures.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "bench_embree.hpp"
#include "bench_quality.hpp"
#include "svo/builder/build.hpp"

namespace svo::tools::bench {

struct RaycastArgs {
  std::vector<std::string> meshes;
  int levels = 10;
  int size = 1024;
  int runs = 5;
  std::vector<float> lodPixels{1.0f};
  std::string view = defaultViewText();
  std::vector<int> threads;  // empty: 1 and every core
  std::vector<std::string> cameras{"whole", "close"};
  int width = 0, height = 0;  // 0: --size
  std::string device = "cpu";
  std::string scaling;                    // triangle counts of the scaling sweep ("10k,100k,...")
  std::string scalingKind = "terrain";    // the generated scene of the sweep
  std::string output = "raycast-report";  // folder for the plot and images
  bool images = false;                    // write each camera's ESVO and Embree images as PNG
  AttributeOptions attributes;  // of the timed octree; its angle also the compared compressed layout's
  PacketSimd simd = PacketSimd::Widest;  // ESVO's packet loop
};

// A method's timed frames: the median and spread of its runs and the last run's result.
struct Timed {
  Summary seconds;
  TraceResult last;
  double deviceSeconds = 0.0;  // the GPU caster's: median of its dispatches' GPU time (Frame::deviceSeconds)
};

// One camera at one thread count.
struct CameraRow {
  std::string camera;  // "whole" or "close"
  int threads = 0;
  float lodPixels = 0.0f;
  double rays = 0.0;
  Timed esvoDepth, esvoShaded;                     // castRay + beam; svo::render
  std::optional<Timed> embreeDepth, embreeShaded;  // absent when built without the peers
  std::optional<Timed> gpu;                        // --device gpu, at the first thread count only
  std::string gpuName;
  Measured quality;  // ESVO's shaded frame against Embree's (when built with the peers)
};

struct SceneResult {
  std::string name;
  std::uint64_t triangles = 0;
  int levels = 0;
  BuildStats stats;
  std::size_t octreeBytes = 0;
  bool paged = false;
  // Both attribute layouts of the octree where each fits one block: their parts, and what compression costs.
  std::optional<LayoutStats> rawLayout, compressedLayout;
  std::optional<AttributeError> compressedError;
  double compressSeconds = 0.0;  // laying the compressed block out
  std::uint64_t voxels = 0;      // every voxel below the root, every level
  double esvoBuildSeconds = 0.0, embreeBuildSeconds = 0.0;
  double finestVoxel = 0.0;  // world units
  std::vector<CameraRow> rows;
};

// Builds the octree (one block, or paged through a pool where it exceeds one) and Embree's BVH over `mesh`,
// then times every method on each camera of `args.cameras` at each of `threads`.
SceneResult benchScene(const Mesh& mesh, const std::string& name, const RaycastArgs& args,
                       const std::vector<int>& threads);

// Throughput in Mrays/s of `rays` in `seconds`.
inline double mraysPerSecond(double rays, double seconds) {
  return rays / seconds * 1e-6;
}

}  // namespace svo::tools::bench
