#include "geometry.hpp"

#include <algorithm>
#include <cmath>

#include <glm/geometric.hpp>

namespace svo::geom {
namespace {

using glm::dvec3;

bool axisSeparates(const dvec3& axis, const dvec3& a, const dvec3& b, const dvec3& c, const dvec3& half) {
  const double pa = glm::dot(axis, a), pb = glm::dot(axis, b), pc = glm::dot(axis, c);
  const double r = half.x * std::abs(axis.x) + half.y * std::abs(axis.y) + half.z * std::abs(axis.z);
  return std::min({pa, pb, pc}) > r || std::max({pa, pb, pc}) < -r;
}

}  // namespace

bool triangleOverlapsCube(const dvec3& a0, const dvec3& b0, const dvec3& c0, const Cube& cube) {
  const dvec3 centre = cube.centre(), half(0.5 * cube.size);
  const dvec3 a = a0 - centre, b = b0 - centre, c = c0 - centre;
  // The cube's face normals: the triangle's bounding box against the cube.
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
  const double r = 0.5 * cube.size * (std::abs(slab.normal.x) + std::abs(slab.normal.y) + std::abs(slab.normal.z));
  return c - r < slab.lo || c + r > slab.hi;
}

namespace {

// Fixed capacity: a cube cut by k slabs has at most 6 + 2k faces, each with at most 6 + 2k vertices.
constexpr int kMaxHullSlabs = 2;  // the two finest ancestors bound a voxel most tightly
constexpr int kMaxHullFaces = 6 + 2 * kMaxHullSlabs;
constexpr int kMaxFaceVertices = 6 + 2 * kMaxHullSlabs + 2;
struct Face {
  std::array<dvec3, kMaxFaceVertices> v;
  int n = 0;
};
struct Polytope {
  std::array<Face, kMaxHullFaces> faces;
  int n = 0;
};

// Monotone in the angle of (x, y) over [0, 4): orders points around a centre without atan2.
double pseudoAngle(double x, double y) {
  const double r = std::abs(x) + std::abs(y);
  if (r == 0.0) return 0.0;
  const double p = x / r;
  return y < 0.0 ? 3.0 + p : 1.0 - p;
}

// Clips the polytope by { x : n.x <= d }, closing the hole with a cap face.
void clip(Polytope& poly, const dvec3& n, double d) {
  Polytope out;
  Face cap;
  auto addCap = [&](const dvec3& p) {
    if (cap.n < kMaxFaceVertices) cap.v[cap.n++] = p;
  };
  for (int f = 0; f < poly.n; ++f) {
    const Face& face = poly.faces[f];
    Face g;
    for (int i = 0; i < face.n; ++i) {
      const dvec3& s = face.v[i];
      const dvec3& e = face.v[(i + 1) % face.n];
      const double ds = glm::dot(n, s) - d, de = glm::dot(n, e) - d;
      if (ds <= 0.0 && g.n < kMaxFaceVertices) g.v[g.n++] = s;
      if (ds == 0.0) addCap(s);
      if ((ds < 0.0 && de > 0.0) || (ds > 0.0 && de < 0.0)) {
        const dvec3 x = s + (e - s) * (ds / (ds - de));
        if (g.n < kMaxFaceVertices) g.v[g.n++] = x;
        addCap(x);
      }
    }
    if (g.n >= 3) out.faces[out.n++] = g;
  }
  if (cap.n >= 3 && out.n < kMaxHullFaces) {
    dvec3 mean(0.0);
    for (int i = 0; i < cap.n; ++i) mean += cap.v[i];
    mean /= double(cap.n);
    const dvec3 u = glm::normalize(std::abs(n.x) < 0.9 ? glm::cross(n, dvec3(1, 0, 0)) : glm::cross(n, dvec3(0, 1, 0)));
    const dvec3 v = glm::cross(n, u);
    std::array<double, kMaxFaceVertices> key;
    for (int i = 0; i < cap.n; ++i) key[i] = pseudoAngle(glm::dot(cap.v[i] - mean, u), glm::dot(cap.v[i] - mean, v));
    // Insertion sort: a cap has a handful of points.
    for (int i = 1; i < cap.n; ++i)
      for (int j = i; j > 0 && key[j] < key[j - 1]; --j) std::swap(key[j], key[j - 1]), std::swap(cap.v[j], cap.v[j - 1]);
    out.faces[out.n++] = cap;
  }
  poly = out;
}

}  // namespace

std::vector<dvec3> hullVertices(const Cube& cube, std::span<const Slab> slabs) {
  const dvec3 lo = cube.lo, hi = cube.lo + cube.size;
  auto corner = [&](int i) { return dvec3(i & 1 ? hi.x : lo.x, i & 2 ? hi.y : lo.y, i & 4 ? hi.z : lo.z); };
  Polytope poly;
  // Each face as four corners in cyclic order: axis bit fixed, the other two bits walk a square.
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      const int a = 1 << ((axis + 1) % 3), b = 1 << ((axis + 2) % 3), s = side ? 1 << axis : 0;
      Face& f = poly.faces[poly.n++];
      f.v[0] = corner(s), f.v[1] = corner(s | a), f.v[2] = corner(s | a | b), f.v[3] = corner(s | b), f.n = 4;
    }
  // The finest ancestors bound the voxel most tightly; dropping older slabs only enlarges the hull.
  const std::size_t first = slabs.size() > kMaxHullSlabs ? slabs.size() - kMaxHullSlabs : 0;
  for (std::size_t i = first; i < slabs.size() && poly.n > 0; ++i) {
    clip(poly, slabs[i].normal, slabs[i].hi);
    clip(poly, -slabs[i].normal, -slabs[i].lo);
  }
  std::vector<dvec3> vertices;
  for (int f = 0; f < poly.n; ++f) vertices.insert(vertices.end(), poly.faces[f].v.begin(), poly.faces[f].v.begin() + poly.faces[f].n);
  return vertices;
}

}  // namespace svo::geom
