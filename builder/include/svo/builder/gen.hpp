// Procedural test scenes (`svo gen`): fractal terrain, a city of boxes, a hairball of thin tubes and a bumpy
// sphere, deterministic from a seed and scaling to tens of millions of triangles; streamed binary PLY or GLB
// output.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include <glm/vec3.hpp>

#include "svo/builder/mesh.hpp"

namespace svo {

enum class SceneKind { Terrain, City, Hairball, Sphere };

// "terrain", "city", "hairball", "sphere"; nullopt for anything else.
std::optional<SceneKind> parseSceneKind(std::string_view name);
std::string_view sceneKindName(SceneKind kind);
// "terrain, city, hairball, sphere": for messages and help text.
std::string sceneKindList();

// Target triangle counts the generators accept. Below the minimum the coarsest shapes cannot get within
// kGenTolerance of the target; the maximum keeps vertex indices in 32 bits with room to spare.
inline constexpr std::uint64_t kMinGenTriangles = 100;
inline constexpr std::uint64_t kMaxGenTriangles = std::uint64_t(1) << 30;
// Promised relative difference between the generated and the target triangle count.
inline constexpr double kGenTolerance = 0.10;

struct GenOptions {
  SceneKind kind = SceneKind::Terrain;
  std::uint64_t triangles = 1'000'000;  // target count, in [kMinGenTriangles, kMaxGenTriangles]
  std::uint64_t seed = 1;
  // Called with the completed fraction in [0, 1] (from worker threads too).
  std::function<void(double)> progress;
};

// Where a kind's vertices lie, y up:
//   terrain:  x, z in [-1, 1] (a full grid), y in [0, kTerrainHeight] with both ends reached;
//   city:     x, z in [-1, 1] (the ground plane), y in [0, kCityMaxHeight], ground at y = 0;
//   hairball: every vertex within the unit ball (|p| <= 1);
//   sphere:   kSphereMinRadius <= |p| <= 1.
inline constexpr double kTerrainHeight = 0.5;    // a quarter of the extent: hilly, not a wall
inline constexpr double kCityMaxHeight = 0.625;  // tallest tower, under a third of the extent, exact in float
inline constexpr double kSphereMinRadius = 0.8;  // bumps reach 20% of the radius inwards
struct GenBounds {
  glm::dvec3 min{0.0}, max{0.0};
};
// The box that contains every vertex of the kind (the ball's box for hairball and sphere).
GenBounds sceneBounds(SceneKind kind);

// Builds the scene: positions are float-exact (what a float PLY stores), every triangle has positive area,
// colors are linear RGBA with alpha 1. Same options, same mesh, whatever the thread count. Throws
// std::invalid_argument when the triangle target is out of range.
Mesh generateScene(const GenOptions& options);

// Writes positions as float, colors (when present) as 8-bit sRGB, triangles as int lists, binary little
// endian. Streams through a small buffer (no copy of the mesh), writes `path` under a temporary name in the
// same folder and renames it when complete. Throws std::runtime_error naming the file on failure; `path`
// keeps its old content then. `comment` goes into the header (one line).
void writePly(const std::filesystem::path& path, const Mesh& mesh, const std::string& comment = {},
              const std::function<void(double)>& progress = {});

// The same as a binary glTF 2.0 (.glb): float positions, linear RGBA8 vertex colors (COLOR_0), uint32
// indices; streamed and renamed into place like writePly. Throws std::runtime_error when the file would
// pass the format's 4 GiB limit (over 150 M triangles). `generator` goes into asset.generator.
void writeGlb(const std::filesystem::path& path, const Mesh& mesh, const std::string& generator = "svo gen",
              const std::function<void(double)>& progress = {});

}  // namespace svo
