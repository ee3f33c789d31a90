// The OpenVDB peer's input, shared by the benches that convert a mesh with it (bench_build.cpp,
// bench_volume.cpp), and the NanoVDB peer's ray casting (bench_volume.cpp, the volume tests); included only
// where SVO_BENCH_PEERS compiles OpenVDB and NanoVDB in.
#pragma once

#include <cstdint>
#include <limits>
#include <vector>

#include <nanovdb/util/HDDA.h>
#include <nanovdb/util/OpenToNanoVDB.h>
#include <nanovdb/util/Ray.h>
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

// A level set as NanoVDB's buffer (openToNanoVDB), cast with NanoVDB's HDDA zero crossing on the CPU.
class NanoLevelSet {
 public:
  using Accessor = nanovdb::DefaultReadAccessor<float>;
  explicit NanoLevelSet(const openvdb::FloatGrid& grid)
      : handle_(nanovdb::openToNanoVDB(grid)), grid_(handle_.grid<float>()) {}
  std::uint64_t bytes() const { return handle_.size(); }
  // Accessors cache the path to the last voxel: one per thread, reused along its rays.
  Accessor accessor() const { return grid_->getAccessor(); }
  // The world distance along the unit `direction` to the zero crossing, infinity on a miss. ZeroCrossing
  // walks cells [ijk, ijk + 1) of index space and takes each one's value from its corner sample ijk, while
  // OpenVDB's samples sit at voxel centres: the index ray starts half a voxel up, so that the cells it walks
  // are the voxels centred on their samples. It stops on entering the first voxel whose value's sign differs
  // from the one where it entered the narrow band: the hit is that voxel's face, not interpolated.
  double intersect(Accessor& accessor, const glm::dvec3& eye, const glm::dvec3& direction) const {
    // In double: a far-from-origin grid's index coordinates keep their precision.
    const nanovdb::Vec3d from =
        grid_->worldToIndex(nanovdb::Vec3d(eye.x, eye.y, eye.z)) + nanovdb::Vec3d(0.5);
    const nanovdb::Vec3d along =
        grid_->worldToIndexDir(nanovdb::Vec3d(direction.x, direction.y, direction.z));
    const double scale = along.length();  // index units per world unit
    nanovdb::Ray<double> index(from, along / scale);
    nanovdb::Coord ijk;
    float value = 0.0f, t = 0.0f;
    if (!nanovdb::ZeroCrossing(index, accessor, ijk, value, t))
      return std::numeric_limits<double>::infinity();
    return double(t) / scale;
  }

 private:
  nanovdb::GridHandle<nanovdb::HostBuffer> handle_;
  const nanovdb::NanoGrid<float>* grid_;
};

}  // namespace svo::tools::bench
