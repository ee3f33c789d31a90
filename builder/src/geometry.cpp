#include "geometry.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include <glm/geometric.hpp>

namespace svo::geom {
namespace {

// Points this close (relative to the voxel size) to a bounding plane count as on it.
constexpr double kHullTolerance = 1e-9;
// Two slab normals whose cross product along a face is below this are parallel there: no crossing point.
constexpr double kParallelDeterminant = 1e-12;

using glm::dvec3;

bool axisSeparates(const dvec3& axis, const dvec3& a, const dvec3& b, const dvec3& c, const dvec3& half) {
  const double pa = glm::dot(axis, a), pb = glm::dot(axis, b), pc = glm::dot(axis, c);
  const double r = half.x * std::abs(axis.x) + half.y * std::abs(axis.y) + half.z * std::abs(axis.z);
  return std::min({pa, pb, pc}) > r || std::max({pa, pb, pc}) < -r;
}

}  // namespace

bool triangleOverlapsCube(const dvec3& a0, const dvec3& b0, const dvec3& c0, const Cube& cube) {
  return triangleOverlapsBox(a0, b0, c0, cube.centre(), dvec3(0.5 * cube.size));
}

bool triangleOverlapsBox(const dvec3& a0, const dvec3& b0, const dvec3& c0, const dvec3& centre,
                         const dvec3& half) {
  const dvec3 a = a0 - centre, b = b0 - centre, c = c0 - centre;
  // The box's face normals: the triangle's bounding box against the box.
  for (int i = 0; i < 3; ++i)
    if (std::min({a[i], b[i], c[i]}) > half[i] || std::max({a[i], b[i], c[i]}) < -half[i]) return false;
  const dvec3 e0 = b - a, e1 = c - b, e2 = a - c;
  // The triangle's normal.
  const dvec3 n = glm::cross(e0, e1);
  if (axisSeparates(n, a, b, c, half)) return false;
  // The nine edge cross products.
  const dvec3 axes[3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  for (const dvec3& e : {e0, e1, e2})
    for (const dvec3& u : axes) {
      const dvec3 axis = glm::cross(u, e);
      if (axis != dvec3(0.0) && axisSeparates(axis, a, b, c, half)) return false;
    }
  return true;
}

Polygon clipTriangleToCube(const dvec3& a, const dvec3& b, const dvec3& c, const Cube& cube) {
  // Sutherland-Hodgman between two vertex buffers; a plane that cuts nothing (the common case) costs only
  // the signed distances.
  dvec3 buffers[2][kMaxClippedVertices + 3];
  dvec3* p = buffers[0];
  dvec3* q = buffers[1];
  p[0] = a, p[1] = b, p[2] = c;
  int n = 3;
  const dvec3 hi = cube.lo + cube.size;
  double distance[kMaxClippedVertices + 3];
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      // Keep where sign * (x[axis] - bound) <= 0.
      const double bound = side ? hi[axis] : cube.lo[axis];
      const double sign = side ? 1.0 : -1.0;
      bool allInside = true;
      for (int i = 0; i < n; ++i) {
        distance[i] = sign * (p[i][axis] - bound);
        allInside &= distance[i] <= 0.0;
      }
      if (allInside) continue;
      int m = 0;
      for (int i = 0; i < n; ++i) {
        const int j = i + 1 == n ? 0 : i + 1;
        const double ds = distance[i], de = distance[j];
        if (ds <= 0.0) q[m++] = p[i];
        if ((ds < 0.0 && de > 0.0) || (ds > 0.0 && de < 0.0)) {
          dvec3 x = p[i] + (p[j] - p[i]) * (ds / (ds - de));
          x[axis] = bound;  // exactly on the plane despite rounding
          q[m++] = x;
        }
      }
      std::swap(p, q);
      n = m;
      if (n == 0) return {};
    }
  Polygon out;
  std::copy(p, p + n, out.v.begin());
  out.n = n;
  return out;
}

double polygonArea(const Polygon& p, dvec3* centroid) {
  dvec3 mean(0.0);
  for (int i = 0; i < p.n; ++i) mean += p.v[i];
  if (p.n) mean /= double(p.n);
  double area = 0.0;
  dvec3 weighted(0.0);
  for (int i = 1; i + 1 < p.n; ++i) {
    const double t = 0.5 * glm::length(glm::cross(p.v[i] - p.v[0], p.v[i + 1] - p.v[0]));
    area += t;
    weighted += t * (p.v[0] + p.v[i] + p.v[i + 1]) / 3.0;
  }
  if (centroid) *centroid = area > 0.0 ? weighted / area : mean;
  return area;
}

bool slabCutsCube(const Slab& slab, const Cube& cube) {
  // Extent of the cube along the normal, from its centre.
  const double c = glm::dot(slab.normal, cube.centre());
  const double r =
      0.5 * cube.size * (std::abs(slab.normal.x) + std::abs(slab.normal.y) + std::abs(slab.normal.z));
  return c - r < slab.lo || c + r > slab.hi;
}

HullVertices hullVertices(const Cube& cube, std::span<const Slab> slabs) {
  // The polytope's vertices are where three of its planes meet: cube corners inside every slab, cube edges
  // crossing a slab plane, and cube faces crossing two planes of different slabs. Each kind is found from
  // the slabs' values at the cube corners, so only crossings that exist are ever solved for.
  const std::size_t first = slabs.size() > kMaxHullSlabs ? slabs.size() - kMaxHullSlabs : 0;
  slabs = slabs.subspan(first);
  const std::size_t slabCount = slabs.size();
  const dvec3 lo = cube.lo, hi = cube.lo + cube.size;
  const double eps = kHullTolerance * cube.size;
  HullVertices out;
  const auto add = [&](const dvec3& x) { out.v[out.n++] = x; };
  const auto withinSlab = [&](std::size_t k, double value) {
    return value >= slabs[k].lo - eps && value <= slabs[k].hi + eps;
  };

  std::array<dvec3, 8> corner;
  double value[kMaxHullSlabs][8];  // n_k . corner
  for (int i = 0; i < 8; ++i) {
    corner[i] = dvec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    bool inside = true;
    for (std::size_t k = 0; k < slabCount; ++k) {
      value[k][i] = glm::dot(slabs[k].normal, corner[i]);
      inside &= withinSlab(k, value[k][i]);
    }
    if (inside) add(corner[i]);
  }
  // Cube edges: corners i and i | bit for each i without that bit. A plane of slab k crosses the edge where
  // its value passes the plane's; the point is on the cube, on that plane (so inside slab k), and needs only
  // the other slab's test.
  for (int bit = 1; bit < 8; bit <<= 1)
    for (int i = 0; i < 8; ++i) {
      if (i & bit) continue;
      const int j = i | bit;
      for (std::size_t k = 0; k < slabCount; ++k)
        for (const double d : {slabs[k].lo, slabs[k].hi}) {
          const double vi = value[k][i] - d, vj = value[k][j] - d;
          if (!((vi < 0.0 && vj > 0.0) || (vi > 0.0 && vj < 0.0))) continue;
          const dvec3 x = corner[i] + (corner[j] - corner[i]) * (vi / (vi - vj));
          bool inside = true;
          for (std::size_t other = 0; other < slabCount; ++other)
            if (other != k) inside &= withinSlab(other, glm::dot(slabs[other].normal, x));
          if (inside) add(x);
        }
    }
  // Cube faces (axis a fixed) against a plane of each of two slabs: a 2x2 system in the other coordinates;
  // the point is on both planes, so it only has to lie within the face.
  if (slabCount == 2) {
    static_assert(kMaxHullSlabs == 2);
    for (int a = 0; a < 3; ++a) {
      const int b = (a + 1) % 3, c = (a + 2) % 3;
      const dvec3 &P = slabs[0].normal, &Q = slabs[1].normal;
      const double det = P[b] * Q[c] - P[c] * Q[b];
      if (std::abs(det) < kParallelDeterminant) continue;
      const double invDet = 1.0 / det;
      for (const double xa : {lo[a], hi[a]})
        for (const double dp : {slabs[0].lo, slabs[0].hi})
          for (const double dq : {slabs[1].lo, slabs[1].hi}) {
            const double rp = dp - P[a] * xa, rq = dq - Q[a] * xa;
            dvec3 x;
            x[a] = xa;
            x[b] = (rp * Q[c] - rq * P[c]) * invDet;
            x[c] = (P[b] * rq - Q[b] * rp) * invDet;
            if (x[b] >= lo[b] - eps && x[b] <= hi[b] + eps && x[c] >= lo[c] - eps && x[c] <= hi[c] + eps)
              add(x);
          }
    }
  }
  // Interior vertices where three slab planes meet need three slabs; with at most two they cannot occur.
  return out;
}

}  // namespace svo::geom
