// Triangle meshes as the builder sees them, and their loading from files (assimp, Draco, OpenImageIO).
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <glm/vec2.hpp>
#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

namespace svo {

// A base-color texture, decoded to linear RGBA floats with a box-filtered mip pyramid.
class TextureImage {
 public:
  virtual ~TextureImage() = default;
  // Average color over the UV polygon (texture averaged over the clipped footprint; UVs wrap).
  virtual glm::vec4 average(std::span<const glm::vec2> uvPolygon) const = 0;
  virtual int width() const = 0;
  virtual int height() const = 0;
};
// Loads an image file with OpenImageIO; throws std::runtime_error naming the file on failure.
std::shared_ptr<const TextureImage> loadTexture(const std::filesystem::path& path);
// Wraps RGBA pixels already in memory (row-major, `width * height` entries).
std::shared_ptr<const TextureImage> makeTexture(int width, int height, std::vector<glm::vec4> pixels);

struct Material {
  glm::vec4 baseColor{1.0f};  // multiplied with the texture and vertex colors
  int texture = -1;           // index into Mesh::textures, or -1
};

struct Mesh {
  std::vector<glm::dvec3> positions;  // world space, double so far-from-origin scenes keep their precision
  std::vector<glm::vec4> colors;      // per vertex RGBA in [0,1]; empty when the source has none
  std::vector<glm::vec2> uvs;         // per vertex; empty when no material has a texture
  std::vector<glm::uvec3> triangles;
  std::vector<std::uint32_t> triangleMaterials;  // per triangle; empty means material 0
  std::vector<Material> materials;               // may be empty: white
  std::vector<std::shared_ptr<const TextureImage>> textures;

  // True when any triangle's color differs from white: vertex colors, textures or non-white materials.
  bool hasColor() const;
  const Material& materialOf(std::size_t triangle) const;
};

struct MeshLoadReport {
  std::size_t droppedDegenerate = 0;  // zero-area or repeated-vertex triangles removed
  std::string format;                 // what the file was read as
};

// Reads OBJ, PLY, STL, glTF/GLB (Draco-compressed too), DAE, FBX and Draco `.drc`. Throws std::runtime_error
// with one line naming the file and the problem: missing file, unknown format, empty mesh, non-finite vertex.
// Degenerate triangles are dropped and counted.
Mesh loadMesh(const std::filesystem::path& path, MeshLoadReport* report = nullptr);

// Checks positions are finite and indices in range, and drops degenerate triangles; throws on the first
// non-finite vertex or bad index. Returns the number of dropped triangles. loadMesh calls it.
std::size_t validateMesh(Mesh& mesh, const std::string& source);

}  // namespace svo
