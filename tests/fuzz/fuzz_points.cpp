// libFuzzer target over the point-cloud readers (loadPointCloud: PLY, ASCII and binary, and .xyz).
// The first byte picks the format, the rest is the file. Any bytes must end in a clean exception or a cloud
// whose positions and normals are finite and whose normals and colors match them in number: never a crash, a
// hang or a sanitizer report. Draco files are the Draco library's to decode, so its entry points are stubbed
// here, as is the color conversion, and the target needs glm alone.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <stdexcept>
#include <string>

#include "point_cloud_draco.hpp"
#include "scratch_file.hpp"
#include "svo/builder/points.hpp"

namespace svo::detail {
bool isDracoPointCloud(const std::filesystem::path&) {
  return false;
}
PointCloud loadDracoPoints(const std::filesystem::path& path) {
  throw std::runtime_error(path.string() + ": Draco is not part of the fuzz target");
}
glm::vec4 displayToLinear(glm::vec4 c) {
  return c;
}
}  // namespace svo::detail

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path ply = svofuzz::scratchPath("svo_fuzz_points_", ".ply");
  static const std::filesystem::path xyz = svofuzz::scratchPath("svo_fuzz_points_", ".xyz");
  if (size == 0) return 0;
  const std::filesystem::path& path = (data[0] & 1) ? xyz : ply;
  if (!svofuzz::writeScratch(path, data + 1, size - 1)) return 0;
  try {
    const svo::PointCloud cloud = svo::loadPointCloud(path);
    (void)svo::isPointCloudFile(path);
    if (cloud.positions.empty()) __builtin_trap();  // an empty cloud is an error, not a result
    if (!cloud.normals.empty() && cloud.normals.size() != cloud.positions.size()) __builtin_trap();
    if (!cloud.colors.empty() && cloud.colors.size() != cloud.positions.size()) __builtin_trap();
    for (const glm::dvec3& p : cloud.positions)
      if (!std::isfinite(p.x + p.y + p.z)) __builtin_trap();
    for (const glm::vec3& n : cloud.normals)  // unit length, or zero where unknown
      if (!std::isfinite(n.x + n.y + n.z)) __builtin_trap();
  } catch (const std::exception&) {
    // Rejected cleanly: what the reader must do with bad input.
  }
  return 0;
}
