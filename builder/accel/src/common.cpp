#include "common.hpp"

#include <algorithm>
#include <cfloat>
#include <stdexcept>
#include <string>

#include "geometry.hpp"
#include "svo/builder/mesh.hpp"

namespace svo::accel {

void Box::extend(const glm::dvec3& p) {
  lo = glm::min(lo, p);
  hi = glm::max(hi, p);
}
void Box::extend(const Box& b) {
  lo = glm::min(lo, b.lo);
  hi = glm::max(hi, b.hi);
}

Triangles trianglesOf(const Mesh& mesh) {
  return {mesh.positions, mesh.triangles};
}

namespace detail {

void require(bool ok, const char* what) {
  if (!ok) throw std::invalid_argument(std::string("accel: ") + what);
}

bool validTriangle(const dvec3& a, const dvec3& b, const dvec3& c) {
  for (int i = 0; i < 3; ++i)
    if (!std::isfinite(a[i]) || !std::isfinite(b[i]) || !std::isfinite(c[i])) return false;
  return glm::cross(b - a, c - a) != dvec3(0.0);
}

TriangleStore::TriangleStore(const Triangles& triangles) {
  const std::size_t n = triangles.indices.size();
  tris.resize(n);
  edges.resize(n);
  boxes.resize(n);
  validFlag.assign(n, 0);
  for (std::uint32_t id = 0; id < n; ++id) set(triangles, id);
  valid.clear();
  for (std::uint32_t id = 0; id < n; ++id)
    if (validFlag[id]) {
      valid.push_back(id);
      bounds.extend(boxes[id]);
    }
  fat = computeFat(bounds);
}

bool TriangleStore::set(const Triangles& triangles, std::uint32_t id) {
  require(id < triangles.indices.size(), "triangle id out of range");
  if (id >= tris.size()) {
    tris.resize(id + 1);
    edges.resize(id + 1);
    boxes.resize(id + 1);
    validFlag.resize(id + 1, 0);
  }
  const glm::uvec3 idx = triangles.indices[id];
  const std::size_t np = triangles.positions.size();
  validFlag[id] = 0;
  boxes[id] = Box{};
  if (idx.x >= np || idx.y >= np || idx.z >= np) return false;  // bad index: never hit
  Tri& t = tris[id];
  t = Tri{triangles.positions[idx.x], triangles.positions[idx.y], triangles.positions[idx.z]};
  if (!validTriangle(t.a, t.b, t.c)) return false;
  validFlag[id] = 1;
  edges[id] = TriEdges{t.a, t.b - t.a, t.c - t.a};
  boxes[id].extend(t.a);
  boxes[id].extend(t.b);
  boxes[id].extend(t.c);
  return true;
}

double TriangleStore::computeFat(const Box& box) const {
  if (box.empty()) return 0.0;
  const dvec3 e = box.hi - box.lo;
  const double extent = std::max({e.x, e.y, e.z});
  const double magnitude = std::max(glm::length(box.lo), glm::length(box.hi));
  return kFatRelative * extent + kFatUlps * DBL_EPSILON * magnitude + DBL_MIN;
}

void LocalTriangles::assign(const TriangleStore& store, std::vector<std::uint32_t>& refs) {
  std::vector<std::uint32_t> localOf(store.size(), kNoTriangle);
  tris.clear();
  for (std::uint32_t& ref : refs) {
    std::uint32_t& l = localOf[ref];
    if (l == kNoTriangle) {
      l = std::uint32_t(tris.size());
      tris.push_back(Entry{store.edges[ref], ref});
    }
    ref = l;
  }
  tris.shrink_to_fit();
}

bool triangleOverlapsBox(const Tri& tri, const Box& box) {
  for (int i = 0; i < 3; ++i)  // the cheap part first: bounding boxes
    if (std::min({tri.a[i], tri.b[i], tri.c[i]}) > box.hi[i] ||
        std::max({tri.a[i], tri.b[i], tri.c[i]}) < box.lo[i])
      return false;
  return geom::triangleOverlapsBox(tri.a, tri.b, tri.c, 0.5 * (box.lo + box.hi), 0.5 * (box.hi - box.lo));
}

bool boxesOverlap(const Box& a, const Box& b) {
  return a.lo.x <= b.hi.x && b.lo.x <= a.hi.x && a.lo.y <= b.hi.y && b.lo.y <= a.hi.y && a.lo.z <= b.hi.z &&
         b.lo.z <= a.hi.z;
}

std::vector<std::uint32_t> filterBoxQuery(const TriangleStore& store, std::vector<std::uint32_t> candidates,
                                          const Box& box) {
  std::sort(candidates.begin(), candidates.end());
  candidates.erase(std::unique(candidates.begin(), candidates.end()), candidates.end());
  std::vector<std::uint32_t> out;
  if (box.empty()) return out;
  for (std::uint32_t id : candidates)
    if (store.isValid(id) && boxesOverlap(store.boxes[id], box) && triangleOverlapsBox(store.tris[id], box))
      out.push_back(id);
  return out;
}

namespace {

class BruteForce final : public Accel {
 public:
  explicit BruteForce(const Triangles& triangles) : store_(triangles) {}
  std::string name() const override { return "brute"; }
  Hit closestHit(const Ray& ray) const override {
    Hit best;
    const RayCtx r(ray);
    if (!r.usable()) return best;
    for (std::uint32_t id : store_.valid) consider(r, store_, id, best);
    return best;
  }
  bool anyHit(const Ray& ray) const override {
    const RayCtx r(ray);
    if (!r.usable()) return false;
    for (std::uint32_t id : store_.valid)
      if (hits(r, store_, id)) return true;
    return false;
  }
  std::vector<std::uint32_t> boxQuery(const Box& box) const override {
    return filterBoxQuery(store_, store_.valid, box);
  }
  Stats stats() const override {
    Stats s;
    s.triangles = store_.valid.size();
    s.cells = s.leaves = 1;
    s.references = store_.valid.size();
    s.pointers = 1;
    s.bytes = store_.valid.size() * sizeof(std::uint32_t);
    return s;
  }

 private:
  TriangleStore store_;
};

}  // namespace
}  // namespace detail

std::unique_ptr<Accel> buildBruteForce(const Triangles& triangles) {
  return std::make_unique<detail::BruteForce>(triangles);
}

std::vector<std::string> structureNames() {
  return {"kd-binned", "kd-sah", "ug", "rg", "rg2", "org", "octree", "oavm"};
}

std::unique_ptr<Accel> buildByName(const std::string& name, const Triangles& triangles) {
  if (name == "brute") return buildBruteForce(triangles);
  if (name == "kd-binned") return buildKdTree(triangles, KdParams{});
  if (name == "kd-sah") {
    KdParams p;
    p.build = KdBuild::kExactSah;
    return buildKdTree(triangles, p);
  }
  const std::pair<const char*, GridKind> grids[] = {{"ug", GridKind::kUniform},
                                                    {"rg", GridKind::kRecursive},
                                                    {"rg2", GridKind::kTwoLevel},
                                                    {"org", GridKind::kOrg}};
  for (const auto& [n, kind] : grids)
    if (name == n) {
      GridParams p;
      p.kind = kind;
      return buildGrid(triangles, p);
    }
  if (name == "octree") return buildClassicOctree(triangles);
  if (name == "oavm") return OavmOctree::build(triangles);
  throw std::invalid_argument("accel: unknown structure '" + name + "'");
}

}  // namespace svo::accel
