// Mesh queries and the validation every loaded or generated mesh goes through before voxelization.
#include "svo/builder/mesh.hpp"

#include <cmath>
#include <numbers>
#include <stdexcept>
#include <string>

#include <glm/geometric.hpp>

namespace svo {

namespace {

const Material kWhiteMaterial{};

bool isWhite(const glm::vec4& c) {
  return c.r == 1.0f && c.g == 1.0f && c.b == 1.0f && c.a == 1.0f;
}

// A triangle whose edges from its first corner are parallel to within this sine has no area worth voxelizing:
// it is what exactly collinear float input becomes after rounding, with a wide margin.
constexpr double kDegenerateSine = 1e-12;

}  // namespace

bool Mesh::hasColor() const {
  const bool perTriangle = !triangleMaterials.empty();
  for (std::size_t t = 0; t < triangles.size(); ++t) {
    if (!colors.empty()) {
      const glm::uvec3& tri = triangles[t];
      for (int k = 0; k < 3; ++k) {
        if (tri[k] < colors.size() && !isWhite(colors[tri[k]])) return true;
      }
    }
    // Without per-triangle materials every triangle has material 0: one check is enough.
    if (t == 0 || perTriangle) {
      const Material& m = materialOf(t);
      if (m.texture >= 0 || !isWhite(m.baseColor)) return true;
    }
  }
  return false;
}

const Material& materialAt(const std::vector<Material>& materials, std::size_t index) {
  return index < materials.size() ? materials[index] : kWhiteMaterial;
}

const Material& Mesh::materialOf(std::size_t triangle) const {
  const std::size_t index = triangleMaterials.empty() ? 0 : triangleMaterials.at(triangle);
  return materialAt(materials, index);
}

bool isDegenerate(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c) {
  const glm::dvec3 e1 = b - a, e2 = c - a;
  const glm::dvec3 n = glm::cross(e1, e2);
  // |e1 x e2| = |e1||e2| sin(angle): compare squared to stay exact for tiny and huge scenes alike.
  return !(glm::dot(n, n) > kDegenerateSine * kDegenerateSine * glm::dot(e1, e1) * glm::dot(e2, e2));
}

void VertexNormalSums::add(const glm::uvec3& corners, const std::array<glm::dvec3, 3>& positions) {
  const glm::dvec3 n = glm::cross(positions[1] - positions[0], positions[2] - positions[0]);
  const double length = glm::length(n);
  if (!(length > 0.0) || !std::isfinite(length)) return;
  for (int k = 0; k < 3; ++k) {
    const glm::dvec3 a = positions[(k + 1) % 3] - positions[k], b = positions[(k + 2) % 3] - positions[k];
    // The corner's angle, from atan2 (exact for thin corners where acos of a dot product is not).
    sums_[corners[k]] += std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b)) / length * n;
  }
}

std::vector<glm::vec3> VertexNormalSums::normals() const {
  std::vector<glm::vec3> out(sums_.size(), glm::vec3(0.0f));
  for (std::size_t v = 0; v < sums_.size(); ++v) {
    const double length = glm::length(sums_[v]);
    if (length > 0.0 && std::isfinite(length)) out[v] = glm::vec3(sums_[v] / length);
  }
  return out;
}

std::array<glm::vec3, 3> creasedCorners(const std::array<glm::dvec3, 3>& positions,
                                        const std::array<glm::vec3, 3>& vertexNormals) {
  static const double kCreaseCos = std::cos(kCreaseAngleDegrees * std::numbers::pi / 180.0);
  const glm::dvec3 n = glm::cross(positions[1] - positions[0], positions[2] - positions[0]);
  const double length = glm::length(n);
  const glm::dvec3 face = length > 0.0 && std::isfinite(length) ? n / length : glm::dvec3(0.0);
  std::array<glm::vec3, 3> out;
  for (int k = 0; k < 3; ++k)
    out[k] = glm::dot(glm::dvec3(vertexNormals[k]), face) >= kCreaseCos ? vertexNormals[k] : glm::vec3(face);
  return out;
}

std::vector<std::array<glm::vec3, 3>> cornerNormals(const Mesh& mesh) {
  std::vector<std::array<glm::vec3, 3>> out(mesh.triangles.size());
  const auto positionsOf = [&](const glm::uvec3& t) {
    return std::array<glm::dvec3, 3>{mesh.positions[t.x], mesh.positions[t.y], mesh.positions[t.z]};
  };
  if (!mesh.normals.empty()) {
    for (std::size_t i = 0; i < out.size(); ++i)
      for (int k = 0; k < 3; ++k) out[i][k] = mesh.normals[mesh.triangles[i][k]];
    return out;
  }
  VertexNormalSums sums(mesh.positions.size());
  for (const glm::uvec3& t : mesh.triangles) sums.add(t, positionsOf(t));
  const std::vector<glm::vec3> vertex = sums.normals();
  for (std::size_t i = 0; i < out.size(); ++i) {
    const glm::uvec3 t = mesh.triangles[i];
    out[i] = creasedCorners(positionsOf(t), {vertex[t.x], vertex[t.y], vertex[t.z]});
  }
  return out;
}

std::size_t validateMesh(Mesh& mesh, const std::string& source) {
  const std::size_t nv = mesh.positions.size();
  for (std::size_t i = 0; i < nv; ++i) {
    const glm::dvec3& p = mesh.positions[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      throw std::runtime_error(source + ": vertex " + std::to_string(i) + " has a non-finite coordinate");
    }
  }
  if (!mesh.colors.empty() && mesh.colors.size() != nv) {
    throw std::runtime_error(source + ": " + std::to_string(mesh.colors.size()) + " vertex colors for " +
                             std::to_string(nv) + " vertices");
  }
  if (!mesh.normals.empty() && mesh.normals.size() != nv) {
    throw std::runtime_error(source + ": " + std::to_string(mesh.normals.size()) + " vertex normals for " +
                             std::to_string(nv) + " vertices");
  }
  if (!mesh.uvs.empty() && mesh.uvs.size() != nv) {
    throw std::runtime_error(source + ": " + std::to_string(mesh.uvs.size()) + " texture coordinates for " +
                             std::to_string(nv) + " vertices");
  }
  if (!mesh.triangleMaterials.empty() && mesh.triangleMaterials.size() != mesh.triangles.size()) {
    throw std::runtime_error(source + ": " + std::to_string(mesh.triangleMaterials.size()) +
                             " triangle materials for " + std::to_string(mesh.triangles.size()) +
                             " triangles");
  }
  for (std::size_t m = 0; m < mesh.materials.size(); ++m) {
    const int tex = mesh.materials[m].texture;
    if (tex < -1 ||
        (tex >= 0 && (static_cast<std::size_t>(tex) >= mesh.textures.size() || !mesh.textures[tex]))) {
      throw std::runtime_error(source + ": material " + std::to_string(m) + " names texture " +
                               std::to_string(tex) + ", but the mesh has " +
                               std::to_string(mesh.textures.size()));
    }
  }

  std::size_t kept = 0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const glm::uvec3 tri = mesh.triangles[t];
    for (int k = 0; k < 3; ++k) {
      if (tri[k] >= nv) {
        throw std::runtime_error(source + ": triangle " + std::to_string(t) + " uses vertex " +
                                 std::to_string(tri[k]) + ", but there are only " + std::to_string(nv));
      }
    }
    if (!mesh.triangleMaterials.empty()) {
      const std::uint32_t m = mesh.triangleMaterials[t];
      // Material 0 with no materials is the documented white default; any other missing index is a bug.
      if (m >= mesh.materials.size() && !(m == 0 && mesh.materials.empty())) {
        throw std::runtime_error(source + ": triangle " + std::to_string(t) + " uses material " +
                                 std::to_string(m) + ", but there are only " +
                                 std::to_string(mesh.materials.size()));
      }
    }
    if (tri.x == tri.y || tri.y == tri.z || tri.x == tri.z ||
        isDegenerate(mesh.positions[tri.x], mesh.positions[tri.y], mesh.positions[tri.z]))
      continue;
    mesh.triangles[kept] = tri;
    if (!mesh.triangleMaterials.empty()) mesh.triangleMaterials[kept] = mesh.triangleMaterials[t];
    ++kept;
  }
  const std::size_t dropped = mesh.triangles.size() - kept;
  mesh.triangles.resize(kept);
  if (!mesh.triangleMaterials.empty()) mesh.triangleMaterials.resize(kept);
  return dropped;
}

}  // namespace svo
