// libFuzzer target over the streaming binary PLY reader (openTriangleSource).
// Any bytes given as a .ply file must end in a clean exception or triangles that read twice alike: never a
// crash, a hang or a sanitizer report. Files the streaming reader declines go to loadMesh, stubbed here to
// throw, so that the target needs neither assimp nor the rest of the builder.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <stdexcept>
#include <string>

#include "scratch_file.hpp"
#include "svo/builder/mesh.hpp"

namespace svo {
Mesh loadMesh(const std::filesystem::path& path, MeshLoadReport*) {
  throw std::runtime_error(path.string() + ": not streamed (loadMesh is not part of the fuzz target)");
}
namespace detail {
glm::vec4 displayToLinear(glm::vec4 c) {
  return c;
}
}  // namespace detail
}  // namespace svo

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path path = svofuzz::scratchPath("svo_fuzz_ply_", ".ply");
  if (!svofuzz::writeScratch(path, data, size)) return 0;
  try {
    const auto source = svo::openTriangleSource(path);
    std::uint64_t read = 0;
    source->read([&](std::span<const svo::SourceTriangle> batch) { read += batch.size(); });
    if (read != source->triangleCount()) __builtin_trap();  // the second pass must see what the first counted
  } catch (const std::exception&) {
    // Rejected cleanly: what the reader must do with bad input.
  }
  return 0;
}
