// Stiff and extreme cases: generated scenes with the rays that stress them, and
// the checks `svo bench stability` prints and tests/unit/test_stability.cpp asserts. Every check compares
// against the double-precision brute-force triangle reference (svo::accel::buildBruteForce):
//  - the ESVO ray caster gives no NaN or infinity and stays under its iteration cap;
//  - it never sees through the surface: where the reference hits at t, the caster hits no later than t (its
//    voxels contain the triangles, and every contour slab contains its voxel's pieces: sec. 5.2), except for
//    contacts closer to the origin than the origin's float rounding;
//  - its hit point lies within one voxel diagonal (sqrt(3) x the hit voxel's size) of the mesh, because the
//    hit voxel overlaps a triangle and the hit is clamped into the voxel (sec. 6.1);
//  - every acceleration structure returns the brute-force answer (same triangle, or the same t within 1e-6
//    relative where two triangles tie).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/builder/mesh.hpp"

namespace svo::tools {

struct StiffRay {
  glm::dvec3 origin{0.0}, direction{0.0, 0.0, -1.0};  // world space; direction need not be unit length
};

struct StiffCase {
  std::string name;  // short, for tables and test names
  std::string what;  // one line: what is extreme about it
  Mesh mesh;
  int levels = 8;
  // Cast with contours; off where a float ray cannot resolve a slab (23 levels: a ray's position in [1, 2] is
  // itself only known to half a finest voxel).
  bool contours = true;
  std::vector<StiffRay> rays;
};

// The cases. `detail` scales the generated sizes: 1 for the tests (seconds), larger for the bench (the
// "millions of tiny triangles" case has 10^4 x detail^2 of them).
std::vector<StiffCase> stiffCases(int detail);

// Bounds the checks use (also printed by the bench).
struct StabilityBounds {
  // Surface error: hit point to mesh distance in hit-voxel diagonals; 1 is the geometric bound, the rest is
  // float rounding of positions in [1, 2] (2^-23 per coordinate) relative to the finest voxel.
  double surfaceDiagonals = 1.0;
  // See-through slack: the caster's t may exceed the reference's by this much (octree units: 16 float ulps
  // of [1, 2]) plus this fraction of t.
  double seeThroughOctree = 1.0 / double(1 << 19);
  double seeThroughRelative = 1e-5;
  // Acceleration structures against brute force (the tolerance of the accel tests).
  double accelRelative = 1e-6;
};

struct CaseResult {
  std::string name, what;
  std::size_t triangles = 0, rays = 0, referenceHits = 0, casterHits = 0;
  std::size_t droppedTriangles = 0;  // degenerate ones removed first, as svo build does
  std::size_t nonFinite = 0;         // caster outputs with a NaN or infinity where a number was due
  int maxIterations = 0;             // ESVO loop iterations, worst ray
  double meanIterations = 0.0;       // over all rays
  std::size_t capped = 0;            // rays stopped by the iteration cap
  std::size_t seeThrough = 0;        // reference hits the caster missed or hit later than allowed
  double maxSeeThrough = 0.0;        // largest excess of the caster's t over the reference's, finest voxels
  double maxSurfaceError = 0.0, meanSurfaceError = 0.0;  // hit point to mesh, hit-voxel diagonals
  std::size_t accelMismatches = 0;                       // structure answers differing from brute force
  double maxAccelError = 0.0;                            // relative t error of those
  std::size_t structures = 0;
  double seconds = 0.0;
  std::string failure;  // empty when every check passed; else the first failed check
  bool pass() const { return failure.empty(); }
};

CaseResult evaluateCase(const StiffCase& stiffCase, const StabilityBounds& bounds = {});

}  // namespace svo::tools
