// A triangle hit shaded as svo::render shades a voxel hit: the same Phong model (shadePhong), with normals
// interpolated from the mesh's area-weighted vertex normals and colors from its vertex colors and materials.
// The exact references of `svo bench quality` (kd-tree) and `svo bench raycast` (Embree) share it.
#pragma once

#include <cstdint>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/builder/mesh.hpp"
#include "svo/client/render.hpp"

namespace svo::tools::bench {

class MeshShading {
 public:
  MeshShading(const Mesh& mesh, const RenderOptions& options);
  // Linear RGB of the hit at barycentrics (u, v) of `triangle` seen along `direction` (unit, from the eye).
  glm::vec3 shade(std::uint32_t triangle, double u, double v, const glm::dvec3& direction) const;
  const glm::vec3& background() const { return background_; }

 private:
  const Mesh& mesh_;
  std::vector<glm::dvec3> normals_;  // per vertex, area-weighted, not normalized
  bool hasColor_ = false;
  glm::vec3 light_, background_;
};

}  // namespace svo::tools::bench
