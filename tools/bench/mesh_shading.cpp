#include "mesh_shading.hpp"

#include <glm/geometric.hpp>

namespace svo::tools::bench {

MeshShading::MeshShading(const Mesh& mesh, const RenderOptions& options)
    : mesh_(mesh),
      normals_(mesh.positions.size(), glm::dvec3(0.0)),
      hasColor_(mesh.hasColor()),
      light_(glm::normalize(options.lightDirection)),
      background_(options.background) {
  for (const glm::uvec3& t : mesh.triangles) {
    // Area-weighted: the unnormalized cross product is twice the area times the unit normal.
    const glm::dvec3 n =
        glm::cross(mesh.positions[t.y] - mesh.positions[t.x], mesh.positions[t.z] - mesh.positions[t.x]);
    for (int k = 0; k < 3; ++k) normals_[t[k]] += n;
  }
}

glm::vec3 MeshShading::shade(std::uint32_t triangle, double u, double v, const glm::dvec3& direction) const {
  const glm::uvec3 t = mesh_.triangles[triangle];
  const double w0 = 1.0 - u - v;
  glm::dvec3 n = w0 * normals_[t.x] + u * normals_[t.y] + v * normals_[t.z];
  if (!(glm::length(n) > 0.0))
    n = glm::cross(mesh_.positions[t.y] - mesh_.positions[t.x], mesh_.positions[t.z] - mesh_.positions[t.x]);
  glm::vec3 albedo(kNeutralGreyAlbedo);
  if (hasColor_) {
    glm::vec4 c = mesh_.materialOf(triangle).baseColor;
    if (!mesh_.colors.empty())
      c *= float(w0) * mesh_.colors[t.x] + float(u) * mesh_.colors[t.y] + float(v) * mesh_.colors[t.z];
    albedo = glm::vec3(c);
  }
  return shadePhong(albedo, glm::vec3(glm::normalize(n)), glm::vec3(direction), light_);
}

}  // namespace svo::tools::bench
