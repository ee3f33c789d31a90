// A triangle hit shaded as svo::render shades a voxel hit: the same Phong model (shadePhong), with normals
// interpolated from the mesh's shading normals (cornerNormals, as the builder voxelizes them) and colors from
// its vertex colors, materials and base-color textures (a trilinear lookup for the pixel's footprint on the
// triangle, found by ray differentials, as a renderer filters a texture; the builder averages it over each
// voxel's footprint). The exact references of `svo bench quality` (kd-tree) and `svo bench raycast` (Embree)
// share it.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <glm/vec2.hpp>
#include <glm/vec3.hpp>

#include "svo/builder/mesh.hpp"
#include "svo/client/render.hpp"

namespace svo::tools::bench {

// A pixel's two sides where its ray meets the surface, perpendicular to the ray: the camera's right and up
// vectors times the hit distance and the pixel angle (ray differentials).
struct PixelFootprint {
  glm::dvec3 across, down;
  static PixelFootprint at(const Camera::Basis& basis, double distance, double pixelAngle) {
    return {basis.right * (distance * pixelAngle), basis.up * (distance * pixelAngle)};
  }
};

class MeshShading {
 public:
  MeshShading(const Mesh& mesh, const RenderOptions& options);
  // Linear RGB of the hit at barycentrics (u, v) of `triangle` seen along `direction` (unit, from the eye).
  // A texture is filtered for the pixel's footprint projected along the ray onto the triangle's plane.
  glm::vec3 shade(std::uint32_t triangle, double u, double v, const glm::dvec3& direction,
                  const PixelFootprint& footprint) const;
  const glm::vec3& background() const { return background_; }

 private:
  // A textured triangle's UV change per world-space displacement in its plane (a 2x3 matrix, by rows), and
  // its unit normal.
  struct UvGradient {
    glm::vec3 du, dv, normal;
  };
  glm::vec4 textureColor(std::uint32_t triangle, int texture, double u, double v, const glm::dvec3& direction,
                         const PixelFootprint& footprint) const;

  const Mesh& mesh_;
  std::vector<std::array<glm::vec3, 3>> corners_;  // shading normals by triangle, as the builder's
  std::vector<UvGradient> uvGradients_;            // per triangle where a material has a texture, else empty
  bool hasColor_ = false;
  glm::vec3 light_, background_;
};

}  // namespace svo::tools::bench
