// Exact-in-double geometric kernels of the voxelizer: triangle/box overlap, polygon clipping, and the
// ancestor-bounded hull (a cube cut by slabs) whose extent decides where a contour pays off.
#pragma once

#include <array>
#include <span>
#include <vector>

#include <glm/vec3.hpp>

namespace svo::geom {

struct Cube {
  glm::dvec3 lo{0.0};
  double size = 1.0;
  glm::dvec3 centre() const { return lo + 0.5 * size; }
};

// Separating-axis test (Akenine-Moller 2001) for a closed cube and a triangle: 13 axes, done in double.
bool triangleOverlapsCube(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c, const Cube& cube);
// The same test for a closed box given by its centre and half extents (the cube test calls it).
bool triangleOverlapsBox(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c,
                         const glm::dvec3& centre, const glm::dvec3& half);

// A convex polygon clipped to a cube has at most 3 + 6 vertices.
inline constexpr int kMaxClippedVertices = 9;
struct Polygon {
  std::array<glm::dvec3, kMaxClippedVertices + 3> v;
  int n = 0;
  std::span<const glm::dvec3> vertices() const { return {v.data(), std::size_t(n)}; }
};
// Sutherland-Hodgman against the six faces of the cube.
Polygon clipTriangleToCube(const glm::dvec3& a, const glm::dvec3& b, const glm::dvec3& c, const Cube& cube);
// Area and area centroid of a planar convex polygon (centroid of the vertices when the area is zero).
double polygonArea(const Polygon& p, glm::dvec3* centroid);

// A slab { x : lo <= n.x <= hi } in octree space.
struct Slab {
  glm::dvec3 normal{0.0};
  double lo = 0.0, hi = 0.0;
};
// True when the slab removes some part of the cube (some corner lies strictly outside it).
bool slabCutsCube(const Slab& slab, const Cube& cube);

// The vertices of cube ∩ slabs (a convex polytope; the two finest slabs are used), duplicates possible.
// Empty when the intersection is empty.
inline constexpr std::size_t kMaxHullSlabs = 2;  // older ancestors' slabs only enlarge the hull a little
struct HullVertices {
  // 8 corners, 12 edges x 4 planes, 6 faces x 4 plane pairs.
  std::array<glm::dvec3, 8 + 12 * 2 * kMaxHullSlabs + 6 * 4> v;
  int n = 0;
  bool empty() const { return n == 0; }
  std::span<const glm::dvec3> vertices() const { return {v.data(), std::size_t(n)}; }
};
HullVertices hullVertices(const Cube& cube, std::span<const Slab> slabs);

}  // namespace svo::geom
