// The `.svo` file. Until the slice store exists this holds one block: a fixed-size header at offset 0
// (magic, version, scene transform, levels, attachment types, build parameters, block location, checksums),
// then the block compressed with zstd. Written to a temporary name and renamed only when complete.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>

#include <glm/vec3.hpp>

#include "svo/store/block.hpp"

namespace svo {

inline constexpr char kFileMagic[8] = {'S', 'V', 'O', 'S', 'T', 'R', 'M', '\0'};
inline constexpr std::uint32_t kFileVersion = 1;

// Maps world space to the octree's [1, 2]^3: world = origin + (p - 1) * size.
struct SceneTransform {
  glm::dvec3 origin{0.0};
  double size = 1.0;
  glm::dvec3 toOctree(glm::dvec3 world) const { return (world - origin) / size + 1.0; }
  glm::dvec3 toWorld(glm::dvec3 p) const { return origin + (p - 1.0) * size; }
};

struct BuildParameters {
  std::int32_t levels = 0;
  float geometryError = 0.0f;  // finest-voxel units; 0 = refine everywhere
  float colorError = 0.0f;     // 8-bit steps
  float normalError = 0.0f;    // degrees
  std::uint32_t contours = 1;  // 0 when built without contours
};

struct Octree {
  SceneTransform transform;
  BuildParameters parameters;
  Block block;
};

// Writes atomically: `path` either keeps its old content or gets the complete new file.
void writeOctree(const std::filesystem::path& path, const Octree& octree);
// Throws std::runtime_error naming the file and what is wrong (missing, foreign, truncated, bad checksum,
// unsupported version).
Octree readOctree(const std::filesystem::path& path);

}  // namespace svo
