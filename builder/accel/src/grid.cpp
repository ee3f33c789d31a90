// Grids after Li & Wang, "Optimized grid construction with linear time and space" (J. Software 2011): the
// ORG hierarchy (Eq. 1, Algorithms 1 and 2, sub-grid resolution divided by β, cut-off γ, MAXDEPTH) and the
// comparison structures of its Table 1: UG, RG (Jevans & Wyvill) and RG-2 (Ize et al.). One 3D-DDA
// traversal serves all of them; it steps one axis at a time, so it never skips a cell.
#include <algorithm>
#include <cassert>
#include <cmath>
#include <utility>

#include "common.hpp"

namespace svo::accel {

namespace {
// Naive Eq. 1 (UG, RG, RG-2) on a flat box divides by a zero volume: extents below this fraction of the
// largest count as this fraction, and no axis gets more than kNaiveAxisCap cells. Safety valves only; the
// paper's point is that those grids blow up there, which the caps still show (up to 64× the target).
constexpr double kNaiveMinExtent = 1e-3;
constexpr double kNaiveAxisCap = 1024.0;
// ... and no naive grid gets more than this many times its target cell count (memory safety valve).
constexpr double kNaiveCellCap = 64.0;
// Memory safety valve for every kind (not from the paper): no sub-grid is built once the structure holds
// this many cells per triangle plus kCellBudgetBase; RG and RG-2 reach it on flat scenes.
constexpr double kCellBudgetPerTriangle = 64.0;
constexpr double kCellBudgetBase = double(1 << 20);
// ORG Algorithm 1 rounds to nearest; an axis never exceeds this many cells (λN stays far below it).
constexpr double kAxisCap = double(1 << 24);
}  // namespace

void GridParams::validate() const {
  using detail::require;
  require(std::isfinite(lambda) && lambda > 0.0, "grid λ (cell density) must be > 0");
  require(std::isfinite(uniformLambda) && uniformLambda > 0.0, "uniform grid λ must be > 0");
  require(std::isfinite(alpha) && alpha > 0.0, "grid α (cell / primitive size ratio) must be > 0");
  require(std::isfinite(gamma) && gamma >= 1.0, "grid γ (sub-grid cut-off) must be >= 1");
  require(maxDepth >= 1 && maxDepth <= 32, "grid MAXDEPTH must be in [1, 32]");
  require(rgThreshold >= 1, "RG subdivision threshold must be >= 1");
  require(rgMaxDepth >= 1 && rgMaxDepth <= 32, "RG max depth must be in [1, 32]");
  require(std::isfinite(rg2TopExponent) && rg2TopExponent > 0.0 && rg2TopExponent <= 1.0,
          "RG-2 top exponent must be in (0, 1]");
  require(std::isfinite(rg2Density) && rg2Density > 0.0, "RG-2 density must be > 0");
}

glm::ivec3 orgResolution(const glm::dvec3& extent, double n, double lambda) {
  detail::require(std::isfinite(lambda) && lambda > 0.0, "grid λ (cell density) must be > 0");
  const double target = std::max(lambda * n, 1.0);  // λN cells
  int order[3] = {0, 1, 2};
  std::sort(order, order + 3, [&](int a, int b) { return extent[a] > extent[b]; });
  const double li = std::max(extent[order[0]], 0.0), lj = std::max(extent[order[1]], 0.0),
               lk = std::max(extent[order[2]], 0.0);
  double mi = 1, mj = 1, mk = 1;
  auto case2 = [&] { mi = target, mj = mk = 1; };  // one extent: a line of λN cells
  auto case3 = [&] {                               // two extents: M_i·M_j = λN, square cells
    mi = std::sqrt(target * li / lj), mj = std::sqrt(target * lj / li), mk = 1;
    if (mj < 1.0) case2();
  };
  if (!(li > 0.0)) {
    // case 1: a point, one cell
  } else if (!(lj > 0.0)) {
    case2();
  } else if (!(lk > 0.0)) {
    case3();
  } else {
    const double c = std::cbrt(target / (li * lj * lk));  // Eq. 1: M = L·(λN/V)^(1/3)
    mi = li * c, mj = lj * c, mk = lk * c;
    if (mk < 1.0) case3();
  }
  glm::ivec3 res(1);
  res[order[0]] = int(std::clamp(std::round(mi), 1.0, kAxisCap));
  res[order[1]] = int(std::clamp(std::round(mj), 1.0, kAxisCap));
  res[order[2]] = int(std::clamp(std::round(mk), 1.0, kAxisCap));
  return res;
}

namespace detail {
namespace {

constexpr std::uint32_t kSubGrid = 0xffffffffu;

struct Cell {
  std::uint32_t first = 0;
  std::uint32_t count = 0;  // kSubGrid: `first` is a grid index
};

struct Grid {
  Box box;
  glm::ivec3 res{1};
  dvec3 cell{1.0}, inv{1.0};
  std::uint32_t firstCell = 0;
  int depth = 1;
  std::size_t cellIndex(int x, int y, int z) const {
    return firstCell + (std::size_t(z) * res.y + y) * res.x + x;
  }
  Box cellBox(int x, int y, int z) const {
    Box b;
    b.lo = box.lo + dvec3(x, y, z) * cell;
    b.hi = glm::dvec3(x + 1 == res.x ? box.hi.x : box.lo.x + (x + 1) * cell.x,
                      y + 1 == res.y ? box.hi.y : box.lo.y + (y + 1) * cell.y,
                      z + 1 == res.z ? box.hi.z : box.lo.z + (z + 1) * cell.z);
    return b;
  }
  glm::ivec3 clampIndex(const dvec3& p) const {
    glm::ivec3 i;
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor((p[a] - box.lo[a]) * inv[a]);
      i[a] = int(std::clamp(std::isnan(f) ? 0.0 : f, 0.0, double(res[a] - 1)));
    }
    return i;
  }
};

// Naive Eq. 1 for `target` cells: M_i = L_i·(target/V)^(1/3) (UG, RG, RG-2).
glm::ivec3 naiveResolution(const dvec3& extent, double target) {
  const double lmax = std::max({extent.x, extent.y, extent.z});
  if (!(lmax > 0.0)) return glm::ivec3(1);
  const dvec3 l = glm::max(extent, dvec3(kNaiveMinExtent * lmax));
  target = std::max(target, 1.0);
  const double c = std::cbrt(target / (l.x * l.y * l.z));
  dvec3 m;
  for (int a = 0; a < 3; ++a) m[a] = std::clamp(std::round(l[a] * c), 1.0, kNaiveAxisCap);
  const double excess = m.x * m.y * m.z / (kNaiveCellCap * target);
  if (excess > 1.0) m = glm::max(glm::floor(m / std::cbrt(excess)), dvec3(1.0));
  const glm::ivec3 res(m);
  return res;
}

class GridAccel final : public Accel {
 public:
  GridAccel(const Triangles& triangles, const GridParams& params) : store_(triangles), p_(params) {
    params.validate();
    Box box = store_.bounds;
    if (store_.valid.empty()) box = Box{dvec3(0.0), dvec3(0.0)};
    const dvec3 ext = box.extent();
    const double n = double(store_.valid.size());
    glm::ivec3 res;
    switch (p_.kind) {
      case GridKind::kUniform:
        res = naiveResolution(ext, p_.uniformLambda * n);
        break;
      case GridKind::kRecursive:
        res = naiveResolution(ext, p_.lambda * n);
        break;
      case GridKind::kTwoLevel:
        res = naiveResolution(ext, std::pow(p_.rg2Density * n, p_.rg2TopExponent));
        break;
      case GridKind::kOrg:
        res = capByPrimitiveSize(orgResolution(ext, n, p_.lambda), store_.valid, box);
        break;
    }
    build(store_.valid, box, res, 1);
    local_.assign(store_, refs_);
  }

  std::string name() const override {
    switch (p_.kind) {
      case GridKind::kUniform:
        return "ug";
      case GridKind::kRecursive:
        return "rg";
      case GridKind::kTwoLevel:
        return "rg2";
      case GridKind::kOrg:
        break;
    }
    return "org";
  }

  Hit closestHit(const Ray& ray) const override {
    return closestHitLocal(store_, local_, ray, [&](const RayCtx& r, const Hit& best, auto&& v) {
      return traverse(r, 0, best, v);
    });
  }
  bool anyHit(const Ray& ray) const override {
    return anyHitLocal(store_, local_, ray,
                       [&](const RayCtx& r, const Hit& best, auto&& v) { return traverse(r, 0, best, v); });
  }

  std::vector<std::uint32_t> boxQuery(const Box& box) const override {
    std::vector<std::uint32_t> candidates;
    if (!box.empty() && !store_.valid.empty()) collect(0, grow(box, store_.fat), candidates);
    return filterBoxQuery(store_, std::move(candidates), box);
  }

  std::vector<Plane> planes(std::size_t limit) const override {
    std::vector<Plane> out;
    for (const Grid& g : grids_)
      for (int a = 0; a < 3; ++a)
        for (int i = 0; i <= g.res[a] && out.size() < limit; ++i)
          out.push_back(Plane{a, i == g.res[a] ? g.box.hi[a] : g.box.lo[a] + double(i) * g.cell[a]});
    return out;
  }

  Stats stats() const override {
    Stats s;
    s.triangles = store_.valid.size();
    s.cells = cells_.size();
    for (const Cell& c : cells_)
      if (c.count != kSubGrid) ++s.leaves, s.emptyLeaves += c.count == 0;
    s.references = refs_.size();
    s.pointers = cells_.size();
    s.volumes = grids_.size();
    for (const Grid& g : grids_) s.maxDepth = std::max<std::size_t>(s.maxDepth, g.depth - 1);
    s.bytes = cells_.size() * sizeof(Cell) + refs_.size() * sizeof(std::uint32_t) +
              grids_.size() * sizeof(Grid) + local_.bytes();
    return s;
  }

 private:
  // Algorithm 2: no axis finer than α·L_i / LF_avg_i, LF_avg the mean primitive box extent (clipped to box).
  glm::ivec3 capByPrimitiveSize(glm::ivec3 res, const std::vector<std::uint32_t>& prims,
                                const Box& box) const {
    if (prims.empty()) return res;
    dvec3 sum(0.0);
    for (std::uint32_t id : prims) {
      const Box& b = store_.boxes[id];
      sum += glm::max(glm::min(b.hi, box.hi) - glm::max(b.lo, box.lo), dvec3(0.0));
    }
    const dvec3 avg = sum / double(prims.size()), ext = box.extent();
    for (int a = 0; a < 3; ++a)
      if (avg[a] > 0.0) res[a] = int(std::clamp(std::floor(p_.alpha * ext[a] / avg[a]), 1.0, double(res[a])));
    return res;
  }

  // Resolution of the sub-grid of a cell holding `prims`, or (0,0,0) to keep the cell a leaf.
  glm::ivec3 subResolution(const std::vector<std::uint32_t>& prims, const Box& box, int depth,
                           double beta) const {
    const double n = double(prims.size());
    const dvec3 ext = box.extent();
    switch (p_.kind) {
      case GridKind::kUniform:
        return glm::ivec3(0);
      case GridKind::kRecursive:
        if (prims.size() <= p_.rgThreshold || depth >= p_.rgMaxDepth) return glm::ivec3(0);
        return naiveResolution(ext, p_.lambda * n);
      case GridKind::kTwoLevel:
        if (prims.size() < 2 || depth >= 2) return glm::ivec3(0);
        return naiveResolution(ext, p_.rg2Density * n);
      case GridKind::kOrg: {
        if (depth >= p_.maxDepth) return glm::ivec3(0);
        // Sec. 2: the sub-grid gets λ·N_i / β cells, β the subdivision pointer ratio; below γ cells, no
        // sub-grid.
        glm::ivec3 res = orgResolution(ext, n, p_.lambda / beta);
        if (double(res.x) * res.y * res.z < p_.gamma) return glm::ivec3(0);
        res = capByPrimitiveSize(res, prims, box);
        if (double(res.x) * res.y * res.z < p_.gamma) return glm::ivec3(0);
        return res;
      }
    }
    return glm::ivec3(0);
  }

  // Builds one grid over `box` and, recursively, the sub-grids of its cells; returns the grid index.
  std::uint32_t build(const std::vector<std::uint32_t>& prims, const Box& box, glm::ivec3 res, int depth) {
    const std::uint32_t gi = std::uint32_t(grids_.size());
    Grid g;
    g.box = box;
    g.res = res;
    g.depth = depth;
    const dvec3 ext = box.extent();
    for (int a = 0; a < 3; ++a) {
      g.cell[a] = ext[a] / double(res[a]);
      g.inv[a] = g.cell[a] > 0.0 ? 1.0 / g.cell[a] : 0.0;
    }
    const std::size_t ncells = std::size_t(res.x) * res.y * res.z;
    g.firstCell = std::uint32_t(cells_.size());
    grids_.push_back(g);
    cells_.resize(cells_.size() + ncells);
    // Pairs (cell, triangle) from the exact triangle/cell test against every cell of the triangle's box.
    std::vector<std::pair<std::uint32_t, std::uint32_t>> pairs;
    pairs.reserve(prims.size() * 2);
    const double fat = store_.fat;
    for (std::uint32_t id : prims) {
      const Box& b = store_.boxes[id];
      const glm::ivec3 lo = g.clampIndex(b.lo - fat), hi = g.clampIndex(b.hi + fat);
      const bool single = lo == hi;
      for (int z = lo.z; z <= hi.z; ++z)
        for (int y = lo.y; y <= hi.y; ++y)
          for (int x = lo.x; x <= hi.x; ++x)
            if (single || triangleOverlapsBox(store_.tris[id], grow(g.cellBox(x, y, z), fat)))
              pairs.emplace_back(std::uint32_t((std::size_t(z) * res.y + y) * res.x + x), id);
    }
    // Counting sort by cell (linear).
    std::vector<std::uint32_t> start(ncells + 1, 0);
    for (const auto& pr : pairs) ++start[pr.first + 1];
    for (std::size_t c = 0; c < ncells; ++c) start[c + 1] += start[c];
    std::vector<std::uint32_t> sorted(pairs.size());
    {
      std::vector<std::uint32_t> fill(start.begin(), start.end() - 1);
      for (const auto& pr : pairs) sorted[fill[pr.first]++] = pr.second;
    }
    { decltype(pairs)().swap(pairs); }
    // β, the subdivision pointer ratio, of this grid: references / primitives, ≥ 1. Sec. 2's derivation
    // (level k holds β^(k-1)·λN cells unless divided by β) needs β ≥ 1 as the references a subdivision
    // produces per triangle it receives; the translated definition reads inverted (cell / sub-grid pointers,
    // ≤ 1), which would raise the resolution instead. It is measured per grid, not estimated per cell.
    const double beta = std::max(1.0, prims.empty() ? 1.0 : double(sorted.size()) / double(prims.size()));
    std::vector<std::uint32_t> cellPrims;
    for (int z = 0; z < res.z; ++z)
      for (int y = 0; y < res.y; ++y)
        for (int x = 0; x < res.x; ++x) {
          const std::size_t local = (std::size_t(z) * res.y + y) * res.x + x;
          cellPrims.assign(sorted.begin() + start[local], sorted.begin() + start[local + 1]);
          const Box cb = grids_[gi].cellBox(x, y, z);
          const glm::ivec3 sub =
              cellPrims.empty() ? glm::ivec3(0) : subResolution(cellPrims, cb, depth, beta);
          const std::size_t ci = grids_[gi].firstCell + local;
          const double budget = kCellBudgetPerTriangle * double(store_.valid.size()) + kCellBudgetBase;
          if (sub.x > 0 && double(cells_.size()) + double(sub.x) * sub.y * sub.z <= budget) {
            const std::uint32_t child = build(cellPrims, cb, sub, depth + 1);
            cells_[ci] = Cell{child, kSubGrid};
          } else {
            cells_[ci] = Cell{std::uint32_t(refs_.size()), std::uint32_t(cellPrims.size())};
            refs_.insert(refs_.end(), cellPrims.begin(), cellPrims.end());
          }
        }
    return gi;
  }

  // 3D-DDA over grid `gi`; `visit(id)` returns true to stop (any hit). Returns whether it stopped.
  template <class Visit>
  bool traverse(const RayCtx& r, std::uint32_t gi, const Hit& best, Visit&& visit) const {
    const Grid& g = grids_[gi];
    const double fat = store_.fat;
    double t0, t1;
    if (!clipRay(r, g.box, fat, t0, t1)) return false;
    glm::ivec3 idx = g.clampIndex(r.o + r.d * t0), step(0);
    dvec3 tNext(kInfinity), tDelta(kInfinity);
    // The cell's index follows the steps: one add per step instead of the full product per cell.
    std::size_t cell = g.cellIndex(idx.x, idx.y, idx.z);
    std::ptrdiff_t indexStep[3] = {0, 0, 0};
    for (int a = 0; a < 3; ++a) {
      if (r.d[a] > 0.0) {
        step[a] = 1;
        tNext[a] = (g.box.lo[a] + double(idx[a] + 1) * g.cell[a] - r.o[a]) * r.inv[a];
        tDelta[a] = g.cell[a] * r.inv[a];
      } else if (r.d[a] < 0.0) {
        step[a] = -1;
        tNext[a] = (g.box.lo[a] + double(idx[a]) * g.cell[a] - r.o[a]) * r.inv[a];
        tDelta[a] = -g.cell[a] * r.inv[a];
      }
      if (g.res[a] == 1) tNext[a] = kInfinity;  // one cell along this axis: never step
      const std::ptrdiff_t stride = a == 0 ? 1 : (a == 1 ? g.res.x : std::ptrdiff_t(g.res.x) * g.res.y);
      indexStep[a] = step[a] * stride;
    }
    for (;;) {
      const int a = tNext.x <= tNext.y && tNext.x <= tNext.z ? 0 : (tNext.y <= tNext.z ? 1 : 2);
      const double cellExit = std::min(tNext[a], t1);
      const Cell& c = cells_[cell];
      if (c.count == kSubGrid) {
        if (traverse(r, c.first, best, visit)) return true;
      } else {
        for (std::uint32_t k = 0; k < c.count; ++k)
          if (visit(refs_[c.first + k])) return true;
      }
      if (best.t <= cellExit || tNext[a] > t1) return false;
      idx[a] += step[a];
      if (idx[a] < 0 || idx[a] >= g.res[a]) return false;
      cell = std::size_t(std::ptrdiff_t(cell) + indexStep[a]);
      tNext[a] += tDelta[a];
    }
  }

  void collect(std::uint32_t gi, const Box& q, std::vector<std::uint32_t>& out) const {
    const Grid& g = grids_[gi];
    if (!boxesOverlap(q, g.box)) return;
    const glm::ivec3 lo = g.clampIndex(q.lo), hi = g.clampIndex(q.hi);
    for (int z = lo.z; z <= hi.z; ++z)
      for (int y = lo.y; y <= hi.y; ++y)
        for (int x = lo.x; x <= hi.x; ++x) {
          const Cell& c = cells_[g.cellIndex(x, y, z)];
          if (c.count == kSubGrid)
            collect(c.first, q, out);
          else
            for (std::uint32_t k = 0; k < c.count; ++k) out.push_back(local_.id(refs_[c.first + k]));
        }
  }

  TriangleStore store_;
  GridParams p_;
  std::vector<Grid> grids_;
  std::vector<Cell> cells_;
  std::vector<std::uint32_t> refs_;  // after the build: local indices into local_
  LocalTriangles local_;
};

}  // namespace
}  // namespace detail

std::unique_ptr<Accel> buildGrid(const Triangles& triangles, const GridParams& params) {
  params.validate();
  return std::make_unique<detail::GridAccel>(triangles, params);
}

}  // namespace svo::accel
