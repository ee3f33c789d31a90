// kd-tree after Qian, Liang & Zhang, "Fast high quality k-D tree construction" (J. Software 2012): binned
// START/END event counts (Algorithm 1), the analytic in-bin SAH minimum (Eq. 5, Eq. 6 for empty bins,
// Algorithm 2), bin-count policies (Sec. 3.2), max depth 8 + 1.3·log2 N (Sec. 2.2.3); and the paper's
// baseline, the exact O(N log N) event-sorting SAH build of Wald & Havran 2006.
#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "common.hpp"

namespace svo::accel {

namespace {
// Upper bound on the bins of one node, so c·n·log2 n stays within memory at the root of large scenes.
constexpr std::size_t kMaxBins = std::size_t(1) << 22;
// Deepest tree the traversal stack can hold; max depth 8 + 1.3·log2 N stays far below it for N < 2^32.
constexpr int kMaxStack = 128;
}  // namespace

void KdParams::validate() const {
  using detail::require;
  require(std::isfinite(binCoefficient) && binCoefficient > 0.0, "kd-tree bin coefficient must be > 0");
  require(std::isfinite(traversalCost) && traversalCost >= 0.0, "kd-tree traversal cost C_T must be >= 0");
  require(std::isfinite(intersectionCost) && intersectionCost > 0.0,
          "kd-tree intersection cost C_I must be > 0");
  require(leafSize >= 1, "kd-tree leaf size must be >= 1");
  require(emptySpaceBonus > 0.0 && emptySpaceBonus <= 1.0, "kd-tree empty space bonus must be in (0, 1]");
  require(std::isfinite(depthBase) && depthBase >= 0.0 && std::isfinite(depthSlope) && depthSlope >= 0.0,
          "kd-tree depth rule 8 + 1.3·log2 N needs finite, non-negative coefficients");
}

namespace detail {
namespace {

constexpr std::uint32_t kLeaf = 3;

// 8 bytes, as in Wald's and pbrt's kd-trees: half the memory of a double plane, so twice the nodes per cache
// line. At 1e6 triangles the tree is 27 MB, and traversal waits on node loads.
struct KdNode {
  std::uint32_t word = 0;  // inner: the split plane as float bits, on the SplitGrid; leaf: reference count
  std::uint32_t meta = 0;  // low 2 bits: axis or kLeaf; high bits: right child (inner) or first ref (leaf)
  bool leaf() const { return (meta & 3u) == kLeaf; }
  int axis() const { return int(meta & 3u); }
  std::uint32_t payload() const { return meta >> 2; }
  float split() const { return std::bit_cast<float>(word); }
  std::uint32_t count() const { return word; }
};

// The positions a split plane can take: origin + double(f) for a float f, computed the same way by the
// build and by traversal, so a ray is tested against exactly the plane the triangles were classified by.
// Offsets from the scene's corner keep float precision relative to the scene's extent (a scene far from
// the origin loses nothing). The build classifies triangle boxes rounded to the nearest grid values (the
// exact SAH's planes lie on box walls, and a wall off the grid would make the snapped plane cut its
// triangle; rounding outwards would make triangles that share a vertex overlap). A box moves by at most
// `error`, which traversal adds to its margin: a ray that close to a plane visits both children.
struct SplitGrid {
  dvec3 origin{0.0};
  double error = 0.0;
  SplitGrid() = default;
  explicit SplitGrid(const Box& scene)
      : origin(scene.lo),
        error(std::ldexp(std::max({scene.extent().x, scene.extent().y, scene.extent().z}),
                         -kFloatRoundingExponent)) {}
  // Half a float ulp of the largest offset, 2^-24 relative, plus the double addition's rounding: 2^-23.
  static constexpr int kFloatRoundingExponent = 23;
  double at(int axis, float f) const { return origin[axis] + double(f); }
  // The largest grid value <= x, as its float.
  float below(int axis, double x) const {
    float f = float(std::max(x - origin[axis], double(std::numeric_limits<float>::lowest())));
    while (at(axis, f) > x) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
    return f;
  }
  double nearest(int axis, double x) const {
    const double f = x - origin[axis];
    return std::abs(f) <= double(std::numeric_limits<float>::max()) ? at(axis, float(f)) : x;
  }
  Box rounded(const Box& b) const {
    Box g;
    for (int k = 0; k < 3; ++k) g.lo[k] = nearest(k, b.lo[k]), g.hi[k] = nearest(k, b.hi[k]);
    return g;
  }
};

struct Candidate {
  double cost = kInfinity;
  int axis = -1;
  double pos = 0.0;
};

Box clipped(const Box& b, const Box& node) {
  return Box{glm::max(b.lo, node.lo), glm::min(b.hi, node.hi)};
}

// ----- binned analytic SAH (Algorithms 1 and 2) --------------------------------------------------------
// Why it traverses slower than the exact SAH (more references per triangle in svo bench accel): Eq. 5
// models the START/END events of a bin as spread evenly over it, so its minimum usually falls strictly
// inside a bin, between triangle box walls, and the plane cuts every triangle it crosses; meshes whose
// triangles share vertex coordinates (tessellated sphere, regular field) have all events of a bin on a few
// coordinates, where the exact SAH puts its planes without cutting anything. Searching the longest axis only
// (Sec. 2.2) adds to it. Leaf size, C_I (0.8 ... 3) and the bin coefficient (0.4, 1.0) do not close the gap.
class BinnedSplitter {
 public:
  BinnedSplitter(const KdParams& p) : p_(p) {}

  std::size_t binCount(std::size_t n) const {
    const double lg = std::log2(double(std::max<std::size_t>(n, 2)));
    double bins = 0.0;
    switch (p_.binPolicy) {
      case BinPolicy::kLinear:
        bins = p_.binCoefficient * double(n);
        break;
      case BinPolicy::kLogSquared:
        bins = p_.binCoefficient * lg * lg;
        break;
      case BinPolicy::kNLogN:
        bins = p_.binCoefficient * double(n) * lg;
        break;
    }
    return std::clamp<std::size_t>(std::size_t(std::ceil(bins)), 1, kMaxBins);
  }

  Candidate find(const std::vector<Box>& boxes, const std::vector<std::uint32_t>& prims, const Box& node) {
    Candidate best;
    const dvec3 ext = node.hi - node.lo;
    // Sec. 2.2: the split is searched on the node's longest axis only.
    const int axis = ext.x >= ext.y && ext.x >= ext.z ? 0 : (ext.y >= ext.z ? 1 : 2);
    const double length = ext[axis];
    if (!(length > 0.0)) return best;
    const std::size_t nsl = binCount(prims.size());
    const double step = length / double(nsl);
    // Algorithm 1: NS[0] counts boxes starting before the node; bins are 1..nsl.
    ns_.assign(nsl + 1, 0);
    ne_.assign(nsl + 1, 0);
    const double lo = node.lo[axis];
    const double last = double(nsl - 1);
    for (std::uint32_t id : prims) {
      const Box& b = boxes[id];
      if (b.lo[axis] <= lo) {
        ++ns_[0];  // line 8: starts at or before the node: left of every candidate plane
      } else {
        const double s = std::floor((b.lo[axis] - lo) / step);
        ++ns_[std::size_t(std::clamp(s, 0.0, last)) + 1];
      }
      const double e = std::floor((std::min(b.hi[axis], node.hi[axis]) - lo) / step);
      if (e < double(nsl)) ++ne_[std::size_t(std::max(e, 0.0)) + 1];
    }
    // Algorithm 2 with Eq. 5 (quadratic in the offset d inside a bin) and Eq. 6 (linear, empty bin).
    const double e1 = ext[(axis + 1) % 3], e2 = ext[(axis + 2) % 3];
    const double cross = e1 * e2;          // face area of the box across the axis
    const double slope = 2.0 * (e1 + e2);  // d S_l / d d: "bc" of Eqs. 4-6
    const double sa = 2.0 * cross + length * slope;
    if (!(sa > 0.0)) return best;
    const double n = double(prims.size());
    best.cost = p_.intersectionCost * n;  // line 2: leaf cost N_T·C_I
    double nla = double(ns_[0]), nra = n, sla = 2.0 * cross, sra = sa;
    for (std::size_t i = 1; i <= nsl; ++i) {
      const double nS = double(ns_[i]), nE = double(ne_[i]);
      double a = 0.0, b = slope * (nla - nra), d;
      if (nS + nE > 0.0) {
        a = slope * (nS + nE) / step;  // Eq. 5, d² coefficient (> 0: convex)
        b += (nS * sla - nE * sra) / step;
        d = std::clamp(-b / (2.0 * a), 0.0, step);
      } else {
        d = b < 0.0 ? step : 0.0;  // Eq. 6: the optimum is at a bin boundary, by the sign of the slope
      }
      const double cost =
          p_.traversalCost + p_.intersectionCost / sa * (a * d * d + b * d + nla * sla + nra * sra);
      const double pos = lo + double(i - 1) * step + d;
      if (cost < best.cost && pos > node.lo[axis] && pos < node.hi[axis]) best = Candidate{cost, axis, pos};
      nla += nS;
      nra -= nE;
      sla += step * slope;
      sra -= step * slope;
    }
    return best;
  }

 private:
  const KdParams& p_;
  std::vector<std::uint32_t> ns_, ne_;
};

// ----- exact SAH by event sorting (Wald & Havran 2006) -------------------------------------------------
struct Event {
  double pos;
  std::uint32_t id;
  std::uint8_t axis;
  std::uint8_t type;  // 0 END, 1 PLANAR, 2 START: the order of equal positions in the sweep
  bool operator<(const Event& o) const {
    if (axis != o.axis) return axis < o.axis;
    if (pos != o.pos) return pos < o.pos;
    return type < o.type;
  }
};

void appendEvents(const Box& b, std::uint32_t id, std::vector<Event>& out) {
  for (std::uint8_t k = 0; k < 3; ++k) {
    if (b.lo[k] == b.hi[k]) {
      out.push_back({b.lo[k], id, k, 1});
    } else {
      out.push_back({b.lo[k], id, k, 2});
      out.push_back({b.hi[k], id, k, 0});
    }
  }
}

double sahCost(const KdParams& p, const Box& node, int axis, double pos, double nl, double nr) {
  const dvec3 ext = node.hi - node.lo;
  const double e1 = ext[(axis + 1) % 3], e2 = ext[(axis + 2) % 3];
  const double sa = 2.0 * (ext.x * ext.y + ext.y * ext.z + ext.z * ext.x);
  const double wl = pos - node.lo[axis], wr = node.hi[axis] - pos;
  const double sl = 2.0 * (e1 * e2 + wl * (e1 + e2)), sr = 2.0 * (e1 * e2 + wr * (e1 + e2));
  const double bonus = (nl == 0.0 || nr == 0.0) ? p.emptySpaceBonus : 1.0;           // Wald & Havran: λ(p)
  return bonus * (p.traversalCost + p.intersectionCost * (sl * nl + sr * nr) / sa);  // Eq. 2
}

// Sweeps the sorted events of a node (all three axes) and returns the cheapest plane.
Candidate sweep(const KdParams& p, const std::vector<Event>& events, const Box& node, std::size_t n) {
  Candidate best;
  best.cost = p.intersectionCost * double(n);
  const dvec3 ext = node.hi - node.lo;
  if (!(2.0 * (ext.x * ext.y + ext.y * ext.z + ext.z * ext.x) > 0.0)) return best;
  std::size_t i = 0;
  while (i < events.size()) {
    const int axis = events[i].axis;
    double nl = 0.0, nr = double(n);
    while (i < events.size() && events[i].axis == axis) {
      const double pos = events[i].pos;
      double pe = 0, pp = 0, ps = 0;
      while (i < events.size() && events[i].axis == axis && events[i].pos == pos && events[i].type == 0)
        ++pe, ++i;
      while (i < events.size() && events[i].axis == axis && events[i].pos == pos && events[i].type == 1)
        ++pp, ++i;
      while (i < events.size() && events[i].axis == axis && events[i].pos == pos && events[i].type == 2)
        ++ps, ++i;
      nr -= pe + pp;
      if (pos > node.lo[axis] && pos < node.hi[axis]) {
        // Planar triangles go to the cheaper side (Wald & Havran, Sec. 4.2).
        const double c =
            std::min(sahCost(p, node, axis, pos, nl + pp, nr), sahCost(p, node, axis, pos, nl, nr + pp));
        if (c < best.cost) best = Candidate{c, axis, pos};
      }
      nl += ps + pp;
    }
  }
  return best;
}

class KdTree final : public Accel {
 public:
  KdTree(const Triangles& triangles, const KdParams& params) : store_(triangles), p_(params) {
    params.validate();
    grid_ = SplitGrid(store_.bounds);
    fat_ = store_.fat + grid_.error;
    root_ = store_.bounds;
    boxes_.resize(store_.size());
    for (std::uint32_t id : store_.valid) boxes_[id] = grid_.rounded(store_.boxes[id]);
    const double n = double(std::max<std::size_t>(store_.valid.size(), 1));
    maxDepth_ = int(std::lround(p_.depthBase + p_.depthSlope * std::log2(n)));
    maxDepth_ = std::clamp(maxDepth_, 0, kMaxStack - 2);
    if (store_.valid.empty()) {
      nodes_.push_back(KdNode{0, kLeaf});
      return;
    }
    side_.assign(store_.size(), 0);
    if (p_.build == KdBuild::kBinnedAnalytic) {
      BinnedSplitter splitter(p_);
      buildBinned(splitter, store_.valid, root_, 0);
    } else {
      std::vector<Event> events;
      events.reserve(6 * store_.valid.size());
      for (std::uint32_t id : store_.valid) appendEvents(boxes_[id], id, events);
      std::sort(events.begin(), events.end());
      std::vector<std::uint32_t> prims = store_.valid;
      buildExact(std::move(events), std::move(prims), root_, 0);
    }
    side_.clear();
    side_.shrink_to_fit();
    std::vector<Box>().swap(boxes_);
    local_.assign(store_, refs_);
  }

  std::string name() const override { return p_.build == KdBuild::kExactSah ? "kd-sah" : "kd-binned"; }

  Hit closestHit(const Ray& ray) const override {
    return closestHitLocal(store_, local_, ray,
                           [&](const RayCtx& r, const Hit& best, auto&& v) { return traverse(r, best, v); });
  }
  bool anyHit(const Ray& ray) const override {
    return anyHitLocal(store_, local_, ray,
                       [&](const RayCtx& r, const Hit& best, auto&& v) { return traverse(r, best, v); });
  }

  std::vector<std::uint32_t> boxQuery(const Box& box) const override {
    std::vector<std::uint32_t> candidates;
    if (box.empty() || store_.valid.empty()) return candidates;
    const Box query = grow(box, fat_);
    std::vector<std::uint32_t> stack{0};
    while (!stack.empty()) {
      const KdNode& node = nodes_[stack.back()];
      const std::uint32_t index = stack.back();
      stack.pop_back();
      if (node.leaf()) {
        for (std::uint32_t k = 0; k < node.count(); ++k)
          candidates.push_back(local_.id(refs_[node.payload() + k]));
        continue;
      }
      const double split = grid_.at(node.axis(), node.split());
      if (query.lo[node.axis()] <= split) stack.push_back(index + 1);
      if (query.hi[node.axis()] >= split) stack.push_back(node.payload());
    }
    return filterBoxQuery(store_, std::move(candidates), box);
  }

  std::vector<Plane> planes(std::size_t limit) const override {
    std::vector<Plane> out;
    for (const KdNode& n : nodes_)
      if (!n.leaf() && out.size() < limit) out.push_back(Plane{n.axis(), grid_.at(n.axis(), n.split())});
    return out;
  }

  Stats stats() const override {
    Stats s;
    s.triangles = store_.valid.size();
    s.cells = nodes_.size();
    s.references = refs_.size();
    for (const KdNode& n : nodes_)
      if (n.leaf()) ++s.leaves, s.emptyLeaves += n.count() == 0;
    s.pointers = nodes_.size();  // a right-child index per inner node, a reference offset per leaf
    s.maxDepth = depthReached_;
    s.bytes = nodes_.size() * sizeof(KdNode) + refs_.size() * sizeof(std::uint32_t) + local_.bytes();
    return s;
  }

 private:
  std::uint32_t makeLeaf(const std::vector<std::uint32_t>& prims) {
    const std::uint32_t index = std::uint32_t(nodes_.size());
    nodes_.push_back(KdNode{std::uint32_t(prims.size()), (std::uint32_t(refs_.size()) << 2) | kLeaf});
    refs_.insert(refs_.end(), prims.begin(), prims.end());
    return index;
  }

  // Splits `prims` by the plane: left when the box reaches below pos, right when it reaches above; a box
  // touching the plane from one side stays on that side, one lying in the plane goes to both (Wald & Havran's
  // classification). Rays meeting the plane within the margin visit both children (traverse), so a hit on
  // the plane is found from either side.
  void partition(const std::vector<std::uint32_t>& prims, int axis, double pos,
                 std::vector<std::uint32_t>& left, std::vector<std::uint32_t>& right) const {
    for (std::uint32_t id : prims) {
      const Box& b = boxes_[id];
      if (b.lo[axis] < pos || b.hi[axis] <= pos) left.push_back(id);
      if (b.hi[axis] > pos || b.lo[axis] >= pos) right.push_back(id);
    }
  }

  std::uint32_t makeInner(int axis, float split) {
    const std::uint32_t index = std::uint32_t(nodes_.size());
    nodes_.push_back(KdNode{std::bit_cast<std::uint32_t>(split), std::uint32_t(axis)});
    return index;
  }

  // The plane a candidate becomes: its position snapped down onto the grid (a no-op for the exact build's
  // planes, which lie on grid box walls); none when the snap leaves the node.
  bool snap(Candidate& c, const Box& node, float& split) const {
    if (c.axis < 0) return false;
    split = grid_.below(c.axis, c.pos);
    c.pos = grid_.at(c.axis, split);
    return c.pos > node.lo[c.axis] && c.pos < node.hi[c.axis];
  }

  void buildBinned(BinnedSplitter& splitter, const std::vector<std::uint32_t>& prims, const Box& box,
                   int depth) {
    depthReached_ = std::max<std::size_t>(depthReached_, depth);
    if (prims.size() <= p_.leafSize || depth >= maxDepth_) return void(makeLeaf(prims));
    Candidate c = splitter.find(boxes_, prims, box);
    float split;
    if (!snap(c, box, split)) return void(makeLeaf(prims));
    std::vector<std::uint32_t> left, right;
    partition(prims, c.axis, c.pos, left, right);
    if (left.size() == prims.size() && right.size() == prims.size()) return void(makeLeaf(prims));
    const std::uint32_t index = makeInner(c.axis, split);
    Box lb = box, rb = box;
    lb.hi[c.axis] = rb.lo[c.axis] = c.pos;
    buildBinned(splitter, left, lb, depth + 1);
    { std::vector<std::uint32_t>().swap(left); }
    nodes_[index].meta |= std::uint32_t(nodes_.size()) << 2;
    buildBinned(splitter, right, rb, depth + 1);
  }

  void buildExact(std::vector<Event> events, std::vector<std::uint32_t> prims, const Box& box, int depth) {
    depthReached_ = std::max<std::size_t>(depthReached_, depth);
    if (prims.size() <= p_.leafSize || depth >= maxDepth_) return void(makeLeaf(prims));
    Candidate c = sweep(p_, events, box, prims.size());
    float split;
    if (!snap(c, box, split)) return void(makeLeaf(prims));
    std::vector<std::uint32_t> left, right;
    partition(prims, c.axis, c.pos, left, right);
    if (left.size() == prims.size() && right.size() == prims.size()) return void(makeLeaf(prims));
    // Classify (1 left only, 2 right only, 3 both), then split the sorted list and merge in the new,
    // clipped events of the straddling triangles (Wald & Havran Sec. 5: O(N log N) overall).
    for (std::uint32_t id : left) side_[id] = 1;
    for (std::uint32_t id : right) side_[id] |= 2;
    Box lb = box, rb = box;
    lb.hi[c.axis] = rb.lo[c.axis] = c.pos;
    std::vector<Event> el, er, bl, br;
    el.reserve(events.size() / 2);
    er.reserve(events.size() / 2);
    for (const Event& e : events) {
      if (side_[e.id] == 1)
        el.push_back(e);
      else if (side_[e.id] == 2)
        er.push_back(e);
    }
    for (std::uint32_t id : prims)
      if (side_[id] == 3) {
        appendEvents(clipped(boxes_[id], lb), id, bl);
        appendEvents(clipped(boxes_[id], rb), id, br);
      }
    for (std::uint32_t id : prims) side_[id] = 0;
    { std::vector<Event>().swap(events); }
    std::sort(bl.begin(), bl.end());
    std::sort(br.begin(), br.end());
    auto merged = [](std::vector<Event>& a, std::vector<Event>& b) {
      std::vector<Event> out(a.size() + b.size());
      std::merge(a.begin(), a.end(), b.begin(), b.end(), out.begin());
      std::vector<Event>().swap(a);
      std::vector<Event>().swap(b);
      return out;
    };
    std::vector<Event> leftEvents = merged(el, bl), rightEvents = merged(er, br);
    const std::uint32_t index = makeInner(c.axis, split);
    { std::vector<std::uint32_t>().swap(prims); }
    buildExact(std::move(leftEvents), std::move(left), lb, depth + 1);
    nodes_[index].meta |= std::uint32_t(nodes_.size()) << 2;
    buildExact(std::move(rightEvents), std::move(right), rb, depth + 1);
  }

  // Front-to-back traversal with a stack; `visit(id)` returns true to stop (and so does this). Children a ray
  // passes within the margin of are never culled, and planes parallel to the ray are handled without
  // dividing.
  template <class Visit>
  bool traverse(const RayCtx& r, const Hit& best, Visit&& visit) const {
    double t0, t1;
    if (!clipRay(r, root_, fat_, t0, t1)) return false;
    // Only rays with a zero direction component need the test for planes parallel to them; the others skip
    // it at every node.
    if (r.d.x == 0.0 || r.d.y == 0.0 || r.d.z == 0.0) return descend<true>(r, t0, t1, best, visit);
    return descend<false>(r, t0, t1, best, visit);
  }

  template <bool kAxisParallel, class Visit>
  bool descend(const RayCtx& r, double t0, double t1, const Hit& best, Visit& visit) const {
    // Each entry also keeps the smallest t0 at or below it: once the closest hit so far lies before that, the
    // rest of the stack is skipped at once instead of entry by entry (its order in t0 is only approximate:
    // margins and rays along planes push spans that start where the current one does).
    struct Entry {
      std::uint32_t node;
      double t0, t1, lowestT0;
    };
    Entry stack[kMaxStack];
    int top = 0;
    const auto push = [&](std::uint32_t node, double t0, double t1) {
      assert(top < kMaxStack);
      stack[top] = {node, t0, t1, top ? std::min(t0, stack[top - 1].lowestT0) : t0};
      ++top;
    };
    std::uint32_t index = 0;
    const double fat = fat_;
    // Per-axis terms in plain arrays: glm's vec3 operator[] is a switch, so indexing it by a node's axis
    // costs mispredicted branches at every node.
    // The origin relative to the split grid, once per ray, so a node's plane enters as its float. This rounds
    // differently from (grid + split) - origin, by about an ulp of the coordinates as that expression's own
    // rounding does; the margin's kFatUlps covers both.
    double origin[3], dir[3], inv[3], tol[3], gridOrigin[3], fromGrid[3];
    for (int k = 0; k < 3; ++k) {
      origin[k] = r.o[k], dir[k] = r.d[k], inv[k] = r.inv[k];
      tol[k] = fat * std::abs(r.inv[k]);
      gridOrigin[k] = grid_.origin[k];
      fromGrid[k] = origin[k] - gridOrigin[k];
    }
    for (;;) {
      const KdNode* node = &nodes_[index];
      while (!node->leaf()) {
        const int a = node->axis();
        const double d = dir[a];
        const std::uint32_t left = index + 1, right = node->payload();
        if (kAxisParallel && d == 0.0) {
          const double o = origin[a];
          const double split = gridOrigin[a] + double(node->split());  // == grid_.at(a, ...), as built
          if (o < split - fat)
            index = left;
          else if (o > split + fat)
            index = right;
          else {
            push(right, t0, t1);
            index = left;
          }
        } else {
          const double ts = (double(node->split()) - fromGrid[a]) * inv[a];
          const double margin = tol[a];
          // The child met first along +t is fixed by the direction's sign (left where it is positive), so the
          // spans of t alone decide, with no comparison of the origin against the plane (a branch that
          // mispredicts wherever the origin lies off to either side).
          std::uint32_t nearChild = left, farChild = right;
          if (d < 0.0) std::swap(nearChild, farChild);
          if (ts > t1 + margin) {
            index = nearChild;
          } else if (ts < t0 - margin) {
            index = farChild;
          } else {
            // The far child is often far away in memory (depth-first order); fetch it while the near side
            // runs.
            __builtin_prefetch(&nodes_[farChild]);
            push(farChild, std::max(t0, ts - margin), t1);
            index = nearChild;
            t1 = std::min(t1, ts + margin);
          }
        }
        node = &nodes_[index];
      }
      const std::uint32_t* refs = refs_.data() + node->payload();
      const std::uint32_t count = node->count();
      for (std::uint32_t k = 0; k < count; ++k)
        if (visit(refs[k])) return true;
      for (;;) {
        if (top == 0 || stack[top - 1].lowestT0 > best.t) return false;
        const Entry e = stack[--top];
        if (e.t0 > best.t) continue;
        index = e.node, t0 = e.t0, t1 = e.t1;
        break;
      }
    }
  }

  TriangleStore store_;
  KdParams p_;
  Box root_;
  SplitGrid grid_;
  double fat_ = 0.0;        // traversal margin: the store's plus the grid's rounding
  std::vector<Box> boxes_;  // during the build: triangle boxes rounded onto grid_
  int maxDepth_ = 0;
  std::size_t depthReached_ = 0;
  std::vector<KdNode> nodes_;
  std::vector<std::uint32_t> refs_;  // after the build: local indices into local_
  LocalTriangles local_;
  std::vector<std::uint8_t> side_;
};

}  // namespace
}  // namespace detail

std::unique_ptr<Accel> buildKdTree(const Triangles& triangles, const KdParams& params) {
  params.validate();
  return std::make_unique<detail::KdTree>(triangles, params);
}

}  // namespace svo::accel
