#include "geometry.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include <glm/geometric.hpp>

namespace svo::geom {
namespace {

// Only the finest ancestors' slabs bound a voxel tightly; older ones only enlarge the hull a little.
constexpr std::size_t kMaxHullSlabs = 2;
// Points this close (relative to the voxel size) to a bounding plane count as on it.
constexpr double kHullTolerance = 1e-9;

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
  Polygon p, q;
  p.v[0] = a, p.v[1] = b, p.v[2] = c, p.n = 3;
  const dvec3 hi = cube.lo + cube.size;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      // Keep where sign * (x[axis] - bound) <= 0.
      const double bound = side ? hi[axis] : cube.lo[axis];
      const double sign = side ? 1.0 : -1.0;
      bool allInside = true;
      for (int i = 0; i < p.n; ++i) allInside &= sign * (p.v[i][axis] - bound) <= 0.0;
      if (allInside) continue;  // most planes cut nothing: skip the copy
      q.n = 0;
      for (int i = 0; i < p.n; ++i) {
        const dvec3& s = p.v[i];
        const dvec3& e = p.v[(i + 1) % p.n];
        const double ds = sign * (s[axis] - bound), de = sign * (e[axis] - bound);
        if (ds <= 0.0) q.v[q.n++] = s;
        if ((ds < 0.0 && de > 0.0) || (ds > 0.0 && de < 0.0)) {
          dvec3 x = s + (e - s) * (ds / (ds - de));
          x[axis] = bound;  // exactly on the plane despite rounding
          q.v[q.n++] = x;
        }
      }
      std::swap(p, q);
      if (p.n == 0) return p;
    }
  return p;
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

std::vector<dvec3> hullVertices(const Cube& cube, std::span<const Slab> slabs) {
  // The polytope's vertices are where three of its planes meet: cube corners, cube edges crossing a slab
  // plane, and cube faces crossing two planes of different slabs. Enumerate those and keep the ones inside
  // everything (an LP's vertex set, cheap for the few slabs that cut one voxel).
  const std::size_t first = slabs.size() > kMaxHullSlabs ? slabs.size() - kMaxHullSlabs : 0;
  slabs = slabs.subspan(first);
  const dvec3 lo = cube.lo, hi = cube.lo + cube.size;
  const double eps = kHullTolerance * cube.size;
  auto inside = [&](const dvec3& x) {
    for (int a = 0; a < 3; ++a)
      if (x[a] < lo[a] - eps || x[a] > hi[a] + eps) return false;
    for (const Slab& s : slabs) {
      const double d = glm::dot(s.normal, x);
      if (d < s.lo - eps || d > s.hi + eps) return false;
    }
    return true;
  };
  std::vector<dvec3> vertices;
  for (int i = 0; i < 8; ++i) {
    const dvec3 c(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z);
    if (inside(c)) vertices.push_back(c);
  }
  struct Plane {
    dvec3 n;
    double d;
    std::size_t slab;
  };
  std::array<Plane, 2 * kMaxHullSlabs> planes;
  std::size_t planeCount = 0;
  for (std::size_t k = 0; k < slabs.size(); ++k) {
    planes[planeCount++] = {slabs[k].normal, slabs[k].lo, k};
    planes[planeCount++] = {slabs[k].normal, slabs[k].hi, k};
  }
  // Cube edges (along axis a; the other two coordinates at lo or hi) against each plane.
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    for (int corner = 0; corner < 4; ++corner) {
      dvec3 x;
      x[b] = corner & 1 ? hi[b] : lo[b];
      x[c] = corner & 2 ? hi[c] : lo[c];
      for (std::size_t p = 0; p < planeCount; ++p) {
        const Plane& pl = planes[p];
        if (pl.n[a] == 0.0) continue;
        x[a] = (pl.d - pl.n[b] * x[b] - pl.n[c] * x[c]) / pl.n[a];
        if (inside(x)) vertices.push_back(x);
      }
    }
  }
  // Cube faces (axis a fixed) against two planes of different slabs: a 2x2 system in the other coordinates.
  for (int a = 0; a < 3; ++a) {
    const int b = (a + 1) % 3, c = (a + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      const double xa = side ? hi[a] : lo[a];
      for (std::size_t p = 0; p < planeCount; ++p)
        for (std::size_t q = p + 1; q < planeCount; ++q) {
          const Plane &P = planes[p], &Q = planes[q];
          if (P.slab == Q.slab) continue;
          const double det = P.n[b] * Q.n[c] - P.n[c] * Q.n[b];
          if (std::abs(det) < 1e-12) continue;
          const double rp = P.d - P.n[a] * xa, rq = Q.d - Q.n[a] * xa;
          dvec3 x;
          x[a] = xa;
          x[b] = (rp * Q.n[c] - rq * P.n[c]) / det;
          x[c] = (P.n[b] * rq - Q.n[b] * rp) / det;
          if (inside(x)) vertices.push_back(x);
        }
    }
  }
  // Interior vertices where three slab planes meet need three slabs; with at most two they cannot occur.
  static_assert(kMaxHullSlabs <= 2);
  return vertices;
}

}  // namespace svo::geom
