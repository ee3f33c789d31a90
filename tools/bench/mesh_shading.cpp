#include "mesh_shading.hpp"

#include <glm/geometric.hpp>

namespace svo::tools::bench {
namespace {

// Whether any material of the mesh has a texture its triangles can sample (they have UVs).
bool sampledTextures(const Mesh& mesh) {
  if (mesh.uvs.empty()) return false;
  for (const Material& m : mesh.materials)
    if (m.texture >= 0) return true;
  return false;
}

}  // namespace

MeshShading::MeshShading(const Mesh& mesh, const RenderOptions& options)
    : mesh_(mesh),
      corners_(cornerNormals(mesh)),
      hasColor_(mesh.hasColor()),
      light_(glm::normalize(options.lightDirection)),
      background_(options.background) {
  if (sampledTextures(mesh)) uvGradients_.resize(mesh.triangles.size());
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    const glm::uvec3 t = mesh.triangles[i];
    const glm::dvec3 e0 = mesh.positions[t.y] - mesh.positions[t.x];
    const glm::dvec3 e1 = mesh.positions[t.z] - mesh.positions[t.x];
    if (uvGradients_.empty()) continue;
    const glm::dvec3 n = glm::cross(e0, e1);
    const double d00 = glm::dot(e0, e0), d01 = glm::dot(e0, e1), d11 = glm::dot(e1, e1);
    const double den = d00 * d11 - d01 * d01;
    if (!(den > 0.0)) continue;  // degenerate (loadMesh drops them): left zero, its lookups take the mean
    // A displacement r in the plane moves the barycentrics of vertices 1 and 2 by the solution of the 2x2
    // normal equations, b1 = (d11 e0 - d01 e1) . r / den and b2 = (d00 e1 - d01 e0) . r / den, and the UV
    // by b1 du0 + b2 du1.
    const glm::dvec2 du0 = glm::dvec2(mesh.uvs[t.y]) - glm::dvec2(mesh.uvs[t.x]);
    const glm::dvec2 du1 = glm::dvec2(mesh.uvs[t.z]) - glm::dvec2(mesh.uvs[t.x]);
    const glm::dvec3 g1 = (d11 * e0 - d01 * e1) / den, g2 = (d00 * e1 - d01 * e0) / den;
    uvGradients_[i] = {glm::vec3(du0.x * g1 + du1.x * g2), glm::vec3(du0.y * g1 + du1.y * g2),
                       glm::vec3(glm::normalize(n))};
  }
}

glm::vec4 MeshShading::textureColor(std::uint32_t triangle, int texture, double u, double v,
                                    const glm::dvec3& direction, const PixelFootprint& footprint) const {
  const glm::uvec3 t = mesh_.triangles[triangle];
  const double w0 = 1.0 - u - v;
  const glm::dvec2 uv =
      w0 * glm::dvec2(mesh_.uvs[t.x]) + u * glm::dvec2(mesh_.uvs[t.y]) + v * glm::dvec2(mesh_.uvs[t.z]);
  const UvGradient& g = uvGradients_[triangle];
  // Each side of the pixel slid along the ray onto the plane (grazing rays stretch it; parallel ones give a
  // non-finite side, which looks up the texture's mean), then mapped to UV.
  const glm::dvec3 n(g.normal);
  const double facing = glm::dot(n, direction);
  const auto sideInUv = [&](const glm::dvec3& side) {
    const glm::dvec3 onPlane = side - direction * (glm::dot(n, side) / facing);
    return glm::vec2(glm::dot(glm::dvec3(g.du), onPlane), glm::dot(glm::dvec3(g.dv), onPlane));
  };
  return mesh_.textures[std::size_t(texture)]->trilinear(glm::vec2(uv), sideInUv(footprint.across),
                                                         sideInUv(footprint.down));
}

glm::vec3 MeshShading::shade(std::uint32_t triangle, double u, double v, const glm::dvec3& direction,
                             const PixelFootprint& footprint) const {
  const glm::uvec3 t = mesh_.triangles[triangle];
  const double w0 = 1.0 - u - v;
  const std::array<glm::vec3, 3>& corners = corners_[triangle];
  glm::dvec3 n = w0 * glm::dvec3(corners[0]) + u * glm::dvec3(corners[1]) + v * glm::dvec3(corners[2]);
  if (!(glm::length(n) > 0.0))
    n = glm::cross(mesh_.positions[t.y] - mesh_.positions[t.x], mesh_.positions[t.z] - mesh_.positions[t.x]);
  glm::vec3 albedo(kNeutralGreyAlbedo);
  if (hasColor_) {
    const Material& material = mesh_.materialOf(triangle);
    glm::vec4 c = material.baseColor;
    if (!mesh_.colors.empty())
      c *= float(w0) * mesh_.colors[t.x] + float(u) * mesh_.colors[t.y] + float(v) * mesh_.colors[t.z];
    if (material.texture >= 0 && !uvGradients_.empty())
      c *= textureColor(triangle, material.texture, u, v, direction, footprint);
    albedo = glm::vec3(c);
  }
  return shadePhong(albedo, glm::vec3(glm::normalize(n)), glm::vec3(direction), light_);
}

}  // namespace svo::tools::bench
