// Top-down voxelization of a triangle mesh into an ESVO octree with contours, colors and normals.
#pragma once

#include <cstdint>
#include <functional>
#include <vector>

#include "svo/builder/mesh.hpp"
#include "svo/store/block.hpp"
#include "svo/store/container.hpp"

namespace svo {

struct BuildOptions {
  int levels = 10;       // octree depth: the finest voxels are 2^-levels of the scene cube
  bool contours = true;  // fit contours (sec. 5.2); off gives cube voxels
  // A contour is stored only where it cuts the voxel's ancestor-bounded hull, along its normal, by more than
  // this fraction of the voxel size (sec. 5.2: "only where it reduces the approximation error enough").
  float contourMinReduction = 0.125f;
  // Error-driven stop (0 = off): a voxel is not refined when its contour thickness is within
  // `geometryError` finest voxels and its attributes within the color / normal errors.
  float geometryError = 0.0f;
  float colorError = 0.0f;   // 8-bit steps, max over the voxel's geometry
  float normalError = 0.0f;  // degrees, max over the voxel's geometry
  LayoutOptions layout;
  // Called from worker threads with the completed fraction in [0, 1].
  std::function<void(double)> progress;
};

struct BuildStats {
  std::vector<std::uint64_t> voxelsPerLevel;  // index 0 = root
  std::uint64_t leafVoxels = 0, contours = 0, trianglesUsed = 0;
  LayoutStats layout;
  double seconds = 0.0;
};

// Scene cube: the mesh bounds' centre, widened to a cube with a small margin so no triangle lies on the
// outer boundary. Throws when the mesh has no extent at all.
SceneTransform fitSceneCube(const Mesh& mesh);

// Builds the voxel tree in the octree's [1,2]^3 frame given by `transform`. Deterministic for a given input
// and options, whatever the thread count.
VoxelTree voxelize(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options,
                   BuildStats* stats = nullptr);

// voxelize + layoutBlock: the whole in-core build.
Octree buildOctree(const Mesh& mesh, const BuildOptions& options, BuildStats* stats = nullptr);

}  // namespace svo
