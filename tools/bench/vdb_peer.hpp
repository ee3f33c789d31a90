// The OpenVDB peer's input, shared by the benches that convert a mesh with it (bench_build.cpp,
// bench_volume.cpp); included only where SVO_BENCH_PEERS compiles OpenVDB in.
#pragma once

#include <vector>

#include <openvdb/openvdb.h>

#include "svo/builder/mesh.hpp"

namespace svo::tools::bench {

// The same triangles as OpenVDB wants them: float points relative to the scene cube's corner, so that the
// voxel grid lines up with the octree's and far-from-origin coordinates keep their precision.
struct VdbMesh {
  std::vector<openvdb::Vec3s> points;
  std::vector<openvdb::Vec3I> triangles;
};

inline VdbMesh toVdbMesh(const Mesh& mesh, glm::dvec3 corner) {
  VdbMesh out;
  out.points.reserve(mesh.positions.size());
  for (const glm::dvec3& p : mesh.positions) {
    const glm::dvec3 q = p - corner;
    out.points.emplace_back(float(q.x), float(q.y), float(q.z));
  }
  out.triangles.reserve(mesh.triangles.size());
  for (const glm::uvec3& t : mesh.triangles) out.triangles.emplace_back(t.x, t.y, t.z);
  return out;
}

}  // namespace svo::tools::bench
