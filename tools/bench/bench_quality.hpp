// `svo bench quality`'s shared pieces: the exact triangle reference, the errors of a voxel image against it,
// and the octree depths it builds. The sweep of every knob is bench_quality.cpp; --stream, the errors while a
// store streams in, is bench_quality_stream.cpp.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <glm/vec3.hpp>

#include "bench_common.hpp"
#include "svo/accel/accel.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/render.hpp"

namespace svo::tools::bench {

struct QualityArgs {
  std::string mesh;
  std::string levels = "8,9,10";
  std::vector<float> contourCuts{BuildOptions{}.leafContourMinReduction};
  std::vector<float> filterRadii{kPostFilterRadiusPerVoxel};
  std::vector<float> exactNormals{kExactNormalUnitDegrees};  // compressed attributes' exact-unit angles
  int size = 512;
  int runs = 3;
  std::string view = defaultViewText();
  double zoom = 1.0;
  int threads = 0;
  std::string out = "out/quality";
  bool stream = false;
  std::vector<std::size_t> budgets{std::size_t(4) << 20, std::size_t(64) << 20};
  double timeout = 300.0;
  std::vector<std::string> sources{"local"};  // words of kStreamSources
  double linkDelayMs = 0.0;                   // one-way delay a relay adds in front of the HTTP sources
  double linkRate = 0.0;                      // bits per second of that relay's link (0: unbounded)
};

// --stream's sources by their --sources word, with their names in curves and tables: the store file read in
// place; svo serve's view stream (range requests for the rest); svo serve by range requests only; nginx by
// range requests.
inline const std::vector<std::pair<std::string, std::string>> kStreamSources = {
    {"local", "local file"},
    {"serve", "svo serve stream"},
    {"serve-range", "svo serve ranges"},
    {"nginx", "nginx ranges"}};

struct Image {
  int width = 0, height = 0;
  std::vector<glm::vec3> color;
  std::vector<float> depth;  // world distance, infinity for a miss
};

// The kd-tree the reference casts its rays through.
std::unique_ptr<accel::Accel> buildReference(const Mesh& mesh);
// The mesh ray cast through the kd-tree, shaded like svo::render with interpolated normals and colors.
Image renderReference(const Mesh& mesh, const accel::Accel& kd, const Camera& camera,
                      const RenderOptions& options, int threads);
// The frame's color (linear RGB) and depth.
Image imageOf(Frame&& frame);
// Writes the image as an sRGB PNG; throws std::runtime_error naming the path on failure.
void writePng(const std::filesystem::path& path, const Image& image);

struct Setting {
  int levels = 0;
  float contourCut = 0.0f;  // the build's leafContourMinReduction; renders with contours only
  float lod = 1.0f;
  bool contours = true;
  int beam = 8;
  AttributeOptions attributes;
  float filterRadius = 0.0f;  // the post-process filter's (sec. 6.3) radius per voxel width; 0: off
  std::string family() const {
    return fmt::format("{}, {}{}{}", contours ? fmt::format("contours cut {}", contourCut) : "cubes",
                       beam ? "beam" : "no beam", attributes.compressed() ? ", " + knobName() : "",
                       filterRadius > 0.0f ? fmt::format(", filter {}", filterRadius) : "");
  }
  std::string knobName() const {  // the knob a setting turns on: compressed attributes or the filter
    if (attributes.compressed())
      return fmt::format("compressed attributes, exact normals {} deg", attributes.exactNormalUnitDegrees);
    return fmt::format("post-process filter {}", filterRadius);
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
  std::size_t poolBytes = 0;  // the octree rendered, in memory (WholeScene::bytes)
  Image image;
};

// Fills m's errors of `voxels` against `reference`: color RMSE and PSNR (OpenImageIO's
// ImageBufAlgo::compare, linear RGB), depth error where both hit (mean and tail of |dt| in finest voxels,
// and that tail off the reference's edges) and silhouette mismatch (pixels hit by exactly one).
void compare(const Image& reference, const Image& voxels, double finestVoxel, Measured& m);

// The errors plotted against time, with their panel titles.
inline const std::vector<std::pair<std::string, double Measured::*>> kPlottedErrors = {
    {"color RMSE", &Measured::rmse},
    {"depth p99 (finest voxels)", &Measured::depthTail},
    {"silhouette mismatch (%)", &Measured::silhouettePercent}};

// One swept depth: built in core and written as a store (its size goes in the table), with a root to render
// from: one block when the octree fits one, else the store through a pager holding all of it (the same
// frames bit for bit: test_pager), which has no single block's 24-bit reach.
struct LevelScene {
  std::filesystem::path store;
  std::uint64_t storeBytes = 0;
  double buildSeconds = 0.0;  // voxelize + layout
  SceneTransform transform;
  std::optional<WholeScene> scene;  // with its root: every depth, one block or paged
  // The same with compressed attributes, by exact-unit angle (where the scene has attributes).
  std::vector<std::pair<float, WholeScene>> compressed;
  LevelScene() = default;
  LevelScene(const LevelScene&) = delete;
  ~LevelScene() {
    scene.reset();
    std::error_code ignored;
    if (!store.empty()) std::filesystem::remove(store, ignored);
  }
};

// Builds `build.levels` levels in core and writes them as a store in `out` (removed with the scene); with
// `withRoot`, also lays it out to render from (that time counts as build time), and with compressed
// attributes at each of `exactNormals`' angles.
void buildLevel(const Mesh& mesh, const BuildOptions& build, const std::filesystem::path& out, bool withRoot,
                LevelScene& s, const std::vector<float>& exactNormals = {});

// --stream's flags checked before any work: throws UsageError for a source listed twice, or a link with no
// source over HTTP.
void checkStreamArgs(const QualityArgs& args);
// --stream: error against elapsed time while the store of `levels` levels streams in from a cold start, one
// curve per source and budget.
void runStreamingQuality(const QualityArgs& args, const Mesh& mesh, int threads, int levels);

}  // namespace svo::tools::bench
