// The classic pointer octree the OAVM paper compares with: it subdivides space as the OAVM octree does (same
// leaves, same references), with eight child pointers per internal node.
#include <algorithm>
#include <string>

#include "octree_space.hpp"

namespace svo::accel {
namespace detail {
namespace {

struct CNode {
  std::uint32_t children[8];  // all kNoTriangle for a leaf
  std::uint32_t parent = kNoTriangle;
  std::uint32_t first = 0, count = 0;
  Box box;
  bool leaf() const { return children[0] == kNoTriangle; }
};

class ClassicOctree final : public Accel {
 public:
  ClassicOctree(const Triangles& triangles, const OctreeParams& params) : store_(triangles), p_(params) {
    params.validate();
    space_ = makeSpace(store_.bounds, store_.valid.size(), p_.maxLevel);
    store_.fat = store_.computeFat(Box{space_.lo, space_.lo + space_.size});
    std::vector<std::uint32_t> prims;
    const Box root{space_.lo, space_.lo + space_.size};
    for (std::uint32_t id : store_.valid)
      if (overlapsCell(store_, id, root)) prims.push_back(id);
    build(0, 0, std::move(prims), kNoTriangle);
  }
  std::string name() const override { return "octree"; }

  Hit closestHit(const Ray& ray) const override {
    return closestHitBy(store_, ray,
                        [&](const RayCtx& r, const Hit& best, auto&& v) { return walk(r, best, v); });
  }
  bool anyHit(const Ray& ray) const override {
    return anyHitBy(store_, ray,
                    [&](const RayCtx& r, const Hit& best, auto&& v) { return walk(r, best, v); });
  }
  std::vector<std::uint32_t> boxQuery(const Box& box) const override {
    std::vector<std::uint32_t> out;
    if (!box.empty() && !store_.valid.empty()) collect(0, grow(box, store_.fat), out);
    return filterBoxQuery(store_, std::move(out), box);
  }
  Stats stats() const override {
    Stats s;
    s.triangles = store_.valid.size();
    s.cells = nodes_.size();
    s.references = refs_.size();
    s.maxDepth = maxDepth_;
    for (const CNode& n : nodes_) {
      if (n.leaf()) {
        ++s.leaves;
        if (n.count == 0)
          ++s.emptyLeaves;
        else
          ++s.pointers;  // triangle list
      } else {
        s.pointers += 8;  // child pointers
      }
      if (n.parent != kNoTriangle) ++s.pointers;
    }
    s.bytes = nodes_.size() * sizeof(CNode) + refs_.size() * sizeof(std::uint32_t);
    return s;
  }
  std::vector<Plane> planes(std::size_t limit) const override;

 private:
  std::uint32_t build(int level, U64 code, std::vector<std::uint32_t> prims, std::uint32_t parent) {
    const std::uint32_t index = std::uint32_t(nodes_.size());
    nodes_.emplace_back();
    std::fill(std::begin(nodes_[index].children), std::end(nodes_[index].children), kNoTriangle);
    nodes_[index].parent = parent;
    nodes_[index].box = space_.worldBox(space_.cell(level, code));
    maxDepth_ = std::max<std::size_t>(maxDepth_, level);
    std::vector<std::uint32_t> children[8];
    if (!subdivide(store_, space_, p_, level, code, prims, children)) {
      nodes_[index].first = std::uint32_t(refs_.size());
      nodes_[index].count = std::uint32_t(prims.size());
      refs_.insert(refs_.end(), prims.begin(), prims.end());
      return index;
    }
    { std::vector<std::uint32_t>().swap(prims); }
    for (int f = 0; f < 8; ++f) {
      const std::uint32_t c = build(level + 1, code * 8 + U64(f), std::move(children[f]), index);
      nodes_[index].children[f] = c;
    }
    return index;
  }

  template <class Visit>
  bool walk(const RayCtx& r, const Hit& best, Visit&& f) const {
    double t0, t1;
    return clipRay(r, nodes_[0].box, store_.fat, t0, t1) && visit(r, 0, best, f);
  }

  // Recursive front to back: children sorted by entry distance, skipped once the best hit is nearer.
  template <class Visit>
  bool visit(const RayCtx& r, std::uint32_t index, const Hit& best, Visit&& f) const {
    const CNode& n = nodes_[index];
    if (n.leaf()) {
      for (std::uint32_t k = 0; k < n.count; ++k)
        if (f(refs_[n.first + k])) return true;
      return false;
    }
    std::pair<double, std::uint32_t> order[8];
    int count = 0;
    for (int c = 0; c < 8; ++c) {
      double t0, t1;
      if (clipRay(r, nodes_[n.children[c]].box, store_.fat, t0, t1)) {
        int k = count++;
        while (k > 0 && order[k - 1].first > t0) order[k] = order[k - 1], --k;
        order[k] = {t0, n.children[c]};
      }
    }
    for (int k = 0; k < count; ++k) {
      if (order[k].first > best.t) break;
      if (visit(r, order[k].second, best, f)) return true;
    }
    return false;
  }

  void collect(std::uint32_t index, const Box& q, std::vector<std::uint32_t>& out) const {
    const CNode& n = nodes_[index];
    if (!boxesOverlap(q, n.box)) return;
    if (n.leaf())
      return void(out.insert(out.end(), refs_.begin() + n.first, refs_.begin() + n.first + n.count));
    for (std::uint32_t c : n.children) collect(c, q, out);
  }

  TriangleStore store_;
  OctreeParams p_;
  Space space_;
  std::vector<CNode> nodes_;
  std::vector<std::uint32_t> refs_;
  std::size_t maxDepth_ = 0;
};

std::vector<Accel::Plane> ClassicOctree::planes(std::size_t limit) const {
  std::vector<Plane> out;
  for (const CNode& n : nodes_)
    if (!n.leaf())
      for (int a = 0; a < 3 && out.size() < limit; ++a)
        out.push_back(Plane{a, nodes_[n.children[7]].box.lo[a]});
  return out;
}

}  // namespace
}  // namespace detail

std::unique_ptr<Accel> buildClassicOctree(const Triangles& triangles, const OctreeParams& params) {
  params.validate();
  return std::make_unique<detail::ClassicOctree>(triangles, params);
}

}  // namespace svo::accel
