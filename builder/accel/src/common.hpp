// Shared pieces of the acceleration structures: the triangle store (double positions, validity), the one
// ray/triangle kernel and triangle/box test every structure and the brute force run, ray/box slab clipping,
// and the "fat" tolerance that makes traversal robust to rounding.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

#include <glm/geometric.hpp>
#include <glm/vec3.hpp>

#include "svo/accel/accel.hpp"

namespace svo::accel::detail {

using glm::dvec3;

// Robustness margin, relative to the scene's largest extent: triangles closer than this to a cell or node
// are stored in it too, and traversal never culls a child that a ray passes within this distance of.
constexpr double kFatRelative = 1e-9;
// ... plus this many units in the last place of the largest coordinate (coordinates offset by 1e6).
constexpr double kFatUlps = 64.0;

struct Tri {
  dvec3 a, b, c;
};
// What the ray/triangle kernel reads: vertex a and the edges b - a, c - a, computed once per triangle
// (bit-identical to computing them per test).
struct TriEdges {
  dvec3 a, e1, e2;
};

// Triangles by id; invalid ones (non-finite or zero-area) are kept as slots but never indexed or hit.
class TriangleStore {
 public:
  TriangleStore() = default;
  explicit TriangleStore(const Triangles& triangles);
  // Appends or replaces the slot of `id` from `triangles`; returns whether it is valid.
  bool set(const Triangles& triangles, std::uint32_t id);

  std::vector<Tri> tris;
  std::vector<TriEdges> edges;          // per id, for the kernel
  std::vector<Box> boxes;               // per id; empty for invalid ones
  std::vector<std::uint8_t> validFlag;  // per id
  std::vector<std::uint32_t> valid;     // ids of valid triangles, ascending
  Box bounds;                           // of the valid triangles
  double fat = 0.0;                     // robustness margin in world units (see kFatRelative)

  std::size_t size() const { return tris.size(); }
  bool isValid(std::uint32_t id) const { return id < validFlag.size() && validFlag[id]; }
  double computeFat(const Box& box) const;
};

bool validTriangle(const dvec3& a, const dvec3& b, const dvec3& c);

// Ray with precomputed reciprocals. Inline, like clipRay: the per-ray set-up is a large share of a short
// kd-tree ray's time.
struct RayCtx {
  dvec3 o, d, inv;
  double tMin, tMax;
  explicit RayCtx(const Ray& ray)
      : o(ray.origin), d(ray.direction), inv(1.0 / ray.direction), tMin(ray.tMin), tMax(ray.tMax) {}
  // Finite origin and direction, non-zero direction, tMin <= tMax.
  bool usable() const {
    for (int i = 0; i < 3; ++i)
      if (!std::isfinite(o[i]) || !std::isfinite(d[i])) return false;
    return d != dvec3(0.0) && !std::isnan(tMin) && !std::isnan(tMax) && tMin <= tMax;
  }
};

// Möller-Trumbore in double on precomputed edges, edges inclusive. True when t in [tMin, tMax]; writes
// t, u, v. The barycentric tests run first on the undivided numerators (u·det, v·det), so most misses cost
// no division; the divided tests after them keep the inclusive [0, 1] semantics. Every structure and the
// brute force run this one function, so they agree bit for bit.
inline bool intersect(const RayCtx& r, const TriEdges& tri, double tMin, double tMax, double& t, double& u,
                      double& v) {
  const dvec3 p = glm::cross(r.d, tri.e2);
  const double det = glm::dot(tri.e1, p);
  const dvec3 s = r.o - tri.a;
  const double un = glm::dot(s, p);
  if (det > 0.0) {
    if (un < 0.0 || un > det) return false;
  } else if (det < 0.0) {
    if (un > 0.0 || un < det) return false;
  } else {
    return false;
  }
  const dvec3 q = glm::cross(s, tri.e1);
  const double vn = glm::dot(r.d, q);
  if (det > 0.0 ? (vn < 0.0 || un + vn > det) : (vn > 0.0 || un + vn < det)) return false;
  const double inv = 1.0 / det;
  u = un * inv;
  if (!(u >= 0.0 && u <= 1.0)) return false;
  v = vn * inv;
  if (!(v >= 0.0 && u + v <= 1.0)) return false;
  t = glm::dot(tri.e2, q) * inv;
  return t >= tMin && t <= tMax;
}

// Tests triangle `id` and keeps the better of it and `best`: smaller t, then smaller id.
inline void consider(const RayCtx& r, const TriangleStore& store, std::uint32_t id, Hit& best) {
  double t, u, v;
  if (!intersect(r, store.edges[id], r.tMin, std::min(r.tMax, best.t), t, u, v)) return;
  if (t < best.t || id < best.triangle) best = Hit{id, t, u, v};
}
inline bool hits(const RayCtx& r, const TriangleStore& store, std::uint32_t id) {
  double t, u, v;
  return intersect(r, store.edges[id], r.tMin, r.tMax, t, u, v);
}

// Per-ray mailbox (direct mapped): a triangle referenced from several leaves or cells is tested once per
// ray. Skipping a repeat never changes the answer: the kernel is a pure function of ray and triangle, and a
// repeat could only be tested against a smaller tMax.
class Mailbox {
 public:
  Mailbox() { std::fill(std::begin(slots_), std::end(slots_), kNoTriangle); }
  // True the first time `id` is offered (modulo evictions), false for a repeat.
  bool fresh(std::uint32_t id) {
    std::uint32_t& s = slots_[id & (kSlots - 1)];
    if (s == id) return false;
    s = id;
    return true;
  }

 private:
  static constexpr std::uint32_t kSlots = 64;
  std::uint32_t slots_[kSlots];
};

// closestHit and anyHit of a structure from its one walk over candidate triangles: `walk(r, best, visit)`
// offers triangle ids to `visit` (true: stop), may stop once nothing nearer than `best` can follow, and
// returns whether `visit` stopped it.
template <class Walk>
Hit closestHitBy(const TriangleStore& store, const Ray& ray, Walk&& walk) {
  Hit best;
  const RayCtx r(ray);
  if (!r.usable() || store.valid.empty()) return best;
  Mailbox mail;
  walk(r, best, [&](std::uint32_t id) {
    if (mail.fresh(id)) consider(r, store, id, best);
    return false;
  });
  return best;
}
template <class Walk>
bool anyHitBy(const TriangleStore& store, const Ray& ray, Walk&& walk) {
  const Hit none;
  const RayCtx r(ray);
  if (!r.usable() || store.valid.empty()) return false;
  Mailbox mail;
  return walk(r, none, [&](std::uint32_t id) { return mail.fresh(id) && hits(r, store, id); });
}

// Kernel data in the order a static structure's references first name the triangles (leaf / cell order),
// so neighbouring leaves and cells read neighbouring memory instead of the mesh order (random for soups:
// one cache miss per test). `assign` renumbers the references to these local indices; `ids` maps back.
// The id sits next to the kernel data: a hit reads no second array (a second cache miss per hit).
struct LocalTriangles {
  struct Entry {
    TriEdges edges;
    std::uint32_t id;  // triangle id
  };
  std::vector<Entry> tris;  // by local index
  void assign(const TriangleStore& store, std::vector<std::uint32_t>& refs);
  std::uint32_t id(std::uint32_t k) const { return tris[k].id; }
  std::size_t bytes() const { return tris.size() * sizeof(Entry); }
};

// closestHitBy / anyHitBy for walks that offer local indices of `local`.
template <class Walk>
Hit closestHitLocal(const TriangleStore& store, const LocalTriangles& local, const Ray& ray, Walk&& walk) {
  Hit best;
  const RayCtx r(ray);
  if (!r.usable() || store.valid.empty()) return best;
  Mailbox mail;
  walk(r, best, [&](std::uint32_t k) {
    double t, u, v;
    if (!mail.fresh(k)) return false;
    const LocalTriangles::Entry& e = local.tris[k];
    if (!intersect(r, e.edges, r.tMin, std::min(r.tMax, best.t), t, u, v)) return false;
    const std::uint32_t id = e.id;
    if (t < best.t || id < best.triangle) best = Hit{id, t, u, v};
    return false;
  });
  return best;
}
template <class Walk>
bool anyHitLocal(const TriangleStore& store, const LocalTriangles& local, const Ray& ray, Walk&& walk) {
  const Hit none;
  const RayCtx r(ray);
  if (!r.usable() || store.valid.empty()) return false;
  Mailbox mail;
  return walk(r, none, [&](std::uint32_t k) {
    double t, u, v;
    return mail.fresh(k) && intersect(r, local.tris[k].edges, r.tMin, r.tMax, t, u, v);
  });
}

// Separating-axis test of a triangle against a closed box (exact up to double rounding).
bool triangleOverlapsBox(const Tri& tri, const Box& box);
inline Box grow(const Box& b, double margin) {
  return Box{b.lo - margin, b.hi + margin};
}
bool boxesOverlap(const Box& a, const Box& b);

// Clips the ray against the box grown by `margin`: [t0, t1] ∩ [tMin, tMax]. Axis-parallel rays are handled
// without dividing by zero. False when the span is empty.
inline bool clipRay(const RayCtx& r, const Box& box, double margin, double& t0, double& t1) {
  t0 = r.tMin;
  t1 = r.tMax;
  for (int i = 0; i < 3; ++i) {
    const double lo = box.lo[i] - margin, hi = box.hi[i] + margin;
    if (r.d[i] == 0.0) {
      if (r.o[i] < lo || r.o[i] > hi) return false;
      continue;
    }
    double a = (lo - r.o[i]) * r.inv[i], b = (hi - r.o[i]) * r.inv[i];
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
  }
  return t0 <= t1;
}

// The final box-query filter shared by every structure: candidates (any order, duplicates allowed) to the
// sorted ids that pass triangleOverlapsBox.
std::vector<std::uint32_t> filterBoxQuery(const TriangleStore& store, std::vector<std::uint32_t> candidates,
                                          const Box& box);

// Throws std::invalid_argument with "accel: <what>" when `ok` is false.
void require(bool ok, const char* what);

}  // namespace svo::accel::detail
