// Triangle meshes as the builder sees them, and their loading from files (assimp, Draco, OpenImageIO).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
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
  // A renderer's trilinear lookup at `uv` for a footprint spanned by the UV vectors du and dv: bilinear on
  // the two mip levels whose texels are nearest the footprint's longer side, blended (UVs wrap).
  virtual glm::vec4 trilinear(glm::vec2 uv, glm::vec2 du, glm::vec2 dv) const = 0;
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
  // Per vertex shading normals, the file's where every part of it has them (loadMesh), taken as they are at
  // every corner; empty: cornerNormals derives them.
  std::vector<glm::vec3> normals;
  std::vector<std::uint32_t> triangleMaterials;  // per triangle; empty means material 0
  std::vector<Material> materials;               // may be empty: white
  std::vector<std::shared_ptr<const TextureImage>> textures;

  // True when any triangle's color differs from white: vertex colors, textures or non-white materials.
  bool hasColor() const;
  const Material& materialOf(std::size_t triangle) const;
};

// Material `index` of `materials`, white where there is none (a mesh without materials).
const Material& materialAt(const std::vector<Material>& materials, std::size_t index);

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
// The rule validateMesh drops triangles by: edges from the first corner parallel to within a tiny sine.
bool isDegenerate(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c);

// Shading normals, as the builder voxelizes them and the benches' triangle references interpolate them. A
// vertex's is the mean of its triangles' normals weighted by their angles at it (Thurmer and Wuthrich 1998:
// unlike area weights, the same for any triangulation of the same faces); a triangle's corner takes it where
// it lies within kCreaseAngleDegrees of the triangle's own normal, else the triangle's normal (a crease): a
// tessellated sphere or a terrain turns smooth, a box keeps its flat faces. Between the two: a box's corner
// normal is 54.7 degrees off each of its faces, an icosahedron's 37.4 (a hexagonal tube's 30).
inline constexpr double kCreaseAngleDegrees = 45.0;

// Angle-weighted vertex normal sums, one triangle at a time (a streaming source adds them in input order).
class VertexNormalSums {
 public:
  explicit VertexNormalSums(std::size_t vertices) : sums_(vertices, glm::dvec3(0.0)) {}
  void add(const glm::uvec3& corners, const std::array<glm::dvec3, 3>& positions);
  // Unit per vertex; zero where the triangles' normals cancel or no triangle uses the vertex.
  std::vector<glm::vec3> normals() const;

 private:
  std::vector<glm::dvec3> sums_;
};

// A triangle's corner normals from its corners' vertex normals (unit or zero), by the crease rule above.
std::array<glm::vec3, 3> creasedCorners(const std::array<glm::dvec3, 3>& positions,
                                        const std::array<glm::vec3, 3>& vertexNormals);
// Each triangle's corner normals: `mesh.normals` where given, else the crease rule over the vertex normals.
std::vector<std::array<glm::vec3, 3>> cornerNormals(const Mesh& mesh);

// One triangle as the out-of-core build streams it: what voxelizing it needs, nothing shared with others.
struct SourceTriangle {
  std::array<glm::dvec3, 3> positions;
  std::array<glm::vec3, 3> normals{};  // shading normals at the corners (cornerNormals)
  std::array<glm::vec4, 3> colors{glm::vec4(1.0f), glm::vec4(1.0f), glm::vec4(1.0f)};  // linear RGBA
  std::array<glm::vec2, 3> uvs{};
  std::uint32_t material = 0;
};

// Triangles read in order, batch by batch, as often as asked, so that the out-of-core build never holds the
// whole mesh. Validated as loadMesh validates: degenerate triangles are dropped, a non-finite vertex or a bad
// index is an error naming the source.
class TriangleSource {
 public:
  virtual ~TriangleSource() = default;
  virtual std::uint64_t triangleCount() const = 0;  // after dropping degenerate ones
  virtual std::size_t droppedDegenerate() const = 0;
  virtual const std::string& format() const = 0;
  // Bounds of the triangles' vertices (what fitSceneCube needs).
  virtual glm::dvec3 lower() const = 0;
  virtual glm::dvec3 upper() const = 0;
  virtual bool hasColor() const = 0;         // as Mesh::hasColor
  virtual bool hasVertexColors() const = 0;  // SourceTriangle::colors carry the file's colors
  virtual bool hasUvs() const = 0;           // SourceTriangle::uvs matter (some material has a texture)
  virtual const std::vector<Material>& materials() const = 0;
  virtual const std::vector<std::shared_ptr<const TextureImage>>& textures() const = 0;
  // XXH3-64 of the content: an interrupted build resumes only on the same input.
  virtual std::uint64_t fingerprint() const = 0;
  virtual std::size_t residentBytes() const = 0;  // what the source holds in memory
  // The whole mesh when the source holds it in memory (formats read whole), else null.
  virtual const Mesh* wholeMesh() const { return nullptr; }
  using Batch = std::function<void(std::span<const SourceTriangle>)>;
  // Calls `batch` with consecutive triangles, first to last.
  void read(const Batch& batch) const { readRange(0, triangleCount(), batch); }
  // Calls `batch` with the triangles [first, last) of that order, first to last, reading no more of the
  // input than it must (a process of a distributed build reads only its share).
  virtual void readRange(std::uint64_t first, std::uint64_t last, const Batch& batch) const = 0;
};

// Binary PLY is streamed from the file, holding only its vertices (positions in the file's precision, 8-bit
// colors, and normals: the file's nx, ny, nz, else the first pass's); other formats are loaded whole with
// loadMesh. Errors as loadMesh's.
std::unique_ptr<TriangleSource> openTriangleSource(const std::filesystem::path& path);
// A mesh already in memory (validated), which must outlive the source.
std::unique_ptr<TriangleSource> meshTriangleSource(const Mesh& mesh, std::string name = "mesh");

}  // namespace svo
