// libFuzzer target over the streaming binary PLY reader (openTriangleSource; DESIGN.md: fuzz the parsers).
// Any bytes given as a .ply file must end in a clean exception or triangles that read twice alike: never a
// crash, a hang or a sanitizer report. Files the streaming reader declines go to loadMesh, stubbed here to
// throw, so that the target needs neither assimp nor the rest of the builder.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <stdexcept>
#include <string>

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
  // The reader takes a path: one scratch file per fuzzing process, in memory where /dev/shm exists.
  static const std::filesystem::path path =
      (std::filesystem::is_directory("/dev/shm") ? std::filesystem::path("/dev/shm")
                                                 : std::filesystem::temp_directory_path()) /
      ("svo_fuzz_ply_" + std::to_string(::getpid()) + ".ply");
  if (std::FILE* f = std::fopen(path.c_str(), "wb")) {
    const bool written = size == 0 || std::fwrite(data, 1, size, f) == size;
    std::fclose(f);
    if (!written) return 0;
  } else {
    return 0;
  }
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
