// The OAVM octree after Yuan et al., "Ray tracing acceleration structure based on octree adaptive volume
// merging" (Acta Optica Sinica 2017): nodes addressed by level and Morton code (Sec. 2.1), empty-leaf merging
// into shared boxes with the direction attribute D, type-1/type-2 nodes (Sec. 2.2), Liang-Barsky clipping
// (Sec. 2.3), neighbour lookup from the code (Sec. 2.4) and local update (Sec. 3).
#include <algorithm>
#include <cassert>
#include <cmath>
#include <stdexcept>
#include <string>

#include "octree_space.hpp"

namespace svo::accel {
namespace detail {
namespace {

// Liang-Barsky (Sec. 2.3, Eq. 6): u·p_k <= q_k, p = (-i, i, -j, j, -k, k), q = (x0 - xmin, xmax - x0, ...).
// u1 = max over p_k < 0 of q_k / p_k, u2 = min over p_k > 0; `exitAxis` is the axis giving u2.
bool liangBarsky(const RayCtx& r, const Box& b, double& u1, double& u2, int& exitAxis) {
  u1 = -kInfinity, u2 = kInfinity, exitAxis = -1;
  for (int a = 0; a < 3; ++a) {
    const double pk[2] = {-r.d[a], r.d[a]}, qk[2] = {r.o[a] - b.lo[a], b.hi[a] - r.o[a]};
    for (int s = 0; s < 2; ++s) {
      if (pk[s] == 0.0) {
        if (qk[s] < 0.0) return false;  // parallel and outside
      } else if (pk[s] < 0.0) {
        u1 = std::max(u1, qk[s] / pk[s]);
      } else if (qk[s] / pk[s] < u2) {
        u2 = qk[s] / pk[s];
        exitAxis = a;
      }
    }
  }
  return u1 <= u2;
}

// ----- flat hash map code -> node index, one per level -------------------------------------------------
class CodeMap {
 public:
  static constexpr U64 kEmpty = ~U64(0);
  std::uint32_t find(U64 code) const {
    if (keys_.empty()) return kNoTriangle;
    for (std::size_t i = hash(code) & mask_;; i = (i + 1) & mask_) {
      if (keys_[i] == code) return values_[i];
      if (keys_[i] == kEmpty) return kNoTriangle;
    }
  }
  void insert(U64 code, std::uint32_t value) {
    if ((size_ + 1) * 2 > keys_.size()) grow();
    for (std::size_t i = hash(code) & mask_;; i = (i + 1) & mask_) {
      if (keys_[i] == code) return void(values_[i] = value);
      if (keys_[i] == kEmpty) {
        keys_[i] = code, values_[i] = value, ++size_;
        return;
      }
    }
  }
  std::size_t bytes() const { return keys_.size() * (sizeof(U64) + sizeof(std::uint32_t)); }

 private:
  static std::size_t hash(U64 k) { return std::size_t((k * 0x9E3779B97F4A7C15ULL) >> 20); }
  void grow() {
    std::vector<U64> k = std::move(keys_);
    std::vector<std::uint32_t> v = std::move(values_);
    const std::size_t cap = std::max<std::size_t>(16, k.size() * 2);
    keys_.assign(cap, kEmpty);
    values_.assign(cap, 0);
    mask_ = cap - 1;
    size_ = 0;
    for (std::size_t i = 0; i < k.size(); ++i)
      if (k[i] != kEmpty) insert(k[i], v[i]);
  }
  std::vector<U64> keys_;
  std::vector<std::uint32_t> values_;
  std::size_t mask_ = 0, size_ = 0;
};

// ===== OAVM ================================================================================================
enum class Kind : std::uint8_t { kInternal, kFull, kEmpty };

struct ONode {
  U64 code = 0;
  std::uint8_t level = 0;
  Kind kind = Kind::kEmpty;
  std::uint8_t type = 0;      // Sec. 2.2: 1 = all children empty, 2 = some children merged; internal only
  std::uint32_t payload = 0;  // full: list index; empty: volume index
};

class Oavm final : public OavmOctree {
 public:
  Oavm(const Triangles& triangles, const OctreeParams& params, const Box& bounds)
      : store_(triangles), p_(params) {
    params.validate();
    Box b = store_.bounds;
    if (!bounds.empty()) b.extend(bounds);
    space_ = makeSpace(b, store_.valid.size(), p_.maxLevel);
    store_.fat = store_.computeFat(Box{space_.lo, space_.lo + space_.size});
    levels_.resize(space_.maxLevel + 1);
    std::vector<std::uint32_t> prims;
    for (std::uint32_t id : store_.valid)
      if (overlapsCell(store_, id, rootBox())) prims.push_back(id);
    buildNode(0, 0, std::move(prims));
    // Merge bottom-up (Sec. 2.2): deepest parents first, so type-1 nodes are known when their parent merges.
    std::vector<std::uint32_t> internal;
    for (std::uint32_t i = 0; i < nodes_.size(); ++i)
      if (nodes_[i].kind == Kind::kInternal) internal.push_back(i);
    std::stable_sort(internal.begin(), internal.end(),
                     [&](std::uint32_t a, std::uint32_t b) { return nodes_[a].level > nodes_[b].level; });
    for (std::uint32_t i : internal) mergeChildren(i);
    if (nodes_[0].kind == Kind::kEmpty) nodes_[0].payload = newVolume(space_.cell(0, 0));
  }

  std::string name() const override { return "oavm"; }

  Hit closestHit(const Ray& ray) const override {
    return closestHitBy(store_, ray,
                        [&](const RayCtx& r, const Hit& best, auto&& v) { return march(r, best, v); });
  }
  bool anyHit(const Ray& ray) const override {
    return anyHitBy(store_, ray,
                    [&](const RayCtx& r, const Hit& best, auto&& v) { return march(r, best, v); });
  }

  std::vector<std::uint32_t> boxQuery(const Box& box) const override {
    std::vector<std::uint32_t> candidates;
    if (!box.empty()) collect(0, grow(box, store_.fat), candidates);
    return filterBoxQuery(store_, std::move(candidates), box);
  }

  std::vector<Plane> planes(std::size_t limit) const override { return octreePlanes(space_, depth(), limit); }

  Stats stats() const override {
    Stats s;
    s.triangles = store_.valid.size();
    s.cells = nodes_.size();
    std::vector<std::uint32_t> vols;
    for (const ONode& n : nodes_) {
      s.maxDepth = std::max<std::size_t>(s.maxDepth, n.level);
      if (n.kind == Kind::kInternal) continue;
      ++s.leaves;
      if (n.kind == Kind::kFull)
        s.references += lists_[n.payload].size();
      else
        ++s.emptyLeaves, vols.push_back(n.payload);
    }
    std::sort(vols.begin(), vols.end());
    s.volumes = std::size_t(std::unique(vols.begin(), vols.end()) - vols.begin());
    s.pointers =
        s.leaves;  // Sec. 2.1: one pointer per leaf (triangle list or merged volume); no child/parent
    s.bytes = nodes_.size() * sizeof(ONode) + s.references * sizeof(std::uint32_t) + s.volumes * sizeof(IBox);
    for (const CodeMap& m : levels_) s.bytes += m.bytes();
    return s;
  }

  void insert(const Triangles& triangles, std::uint32_t id) override {
    require(!store_.isValid(id), "OAVM insert: triangle already present");
    if (!store_.set(triangles, id)) return;  // invalid triangles are never indexed
    const Box& tb = store_.boxes[id];
    const Box root = grow(rootBox(), store_.fat);
    if (!(tb.lo.x >= root.lo.x && tb.lo.y >= root.lo.y && tb.lo.z >= root.lo.z && tb.hi.x <= root.hi.x &&
          tb.hi.y <= root.hi.y && tb.hi.z <= root.hi.z)) {
      store_.validFlag[id] = 0;
      throw std::invalid_argument("accel: OAVM insert: triangle " + std::to_string(id) +
                                  " lies outside the root cube");
    }
    store_.valid.insert(std::lower_bound(store_.valid.begin(), store_.valid.end(), id), id);
    insertInto(0, id);
  }

  void remove(std::uint32_t id) override {
    require(store_.isValid(id), "OAVM remove: triangle not present");
    removeFrom(0, id);
    store_.validFlag[id] = 0;
    store_.valid.erase(std::lower_bound(store_.valid.begin(), store_.valid.end(), id));
  }

  void checkInvariants() const override;

 private:
  Box rootBox() const { return Box{space_.lo, space_.lo + space_.size}; }
  std::uint32_t findNode(int level, U64 code) const { return levels_[level].find(code); }
  std::size_t depth() const { return deepest_; }

  std::uint32_t addNode(int level, U64 code) {
    const std::uint32_t index = std::uint32_t(nodes_.size());
    nodes_.push_back(ONode{code, std::uint8_t(level), Kind::kEmpty, 0, 0});
    deepest_ = std::max<std::size_t>(deepest_, level);
    levels_[level].insert(code, index);
    return index;
  }

  void makeLeaf(std::uint32_t index, std::vector<std::uint32_t> prims) {
    ONode& n = nodes_[index];
    if (prims.empty()) {
      n.kind = Kind::kEmpty;
      n.payload = newVolume(space_.cell(n.level, n.code));
    } else {
      n.kind = Kind::kFull;
      n.payload = newList(std::move(prims));
    }
  }

  std::uint32_t buildNode(int level, U64 code, std::vector<std::uint32_t> prims) {
    const std::uint32_t index = addNode(level, code);
    std::vector<std::uint32_t> children[8];
    if (!subdivide(store_, space_, p_, level, code, prims, children)) {
      makeLeaf(index, std::move(prims));
      return index;
    }
    nodes_[index].kind = Kind::kInternal;
    { std::vector<std::uint32_t>().swap(prims); }
    for (int f = 0; f < 8; ++f) buildNode(level + 1, code * 8 + U64(f), std::move(children[f]));
    return index;
  }

  std::uint32_t newList(std::vector<std::uint32_t> prims) {
    if (!freeLists_.empty()) {
      const std::uint32_t i = freeLists_.back();
      freeLists_.pop_back();
      lists_[i] = std::move(prims);
      return i;
    }
    lists_.push_back(std::move(prims));
    return std::uint32_t(lists_.size() - 1);
  }
  std::uint32_t newVolume(const IBox& b) {
    volumes_.push_back(b);
    return std::uint32_t(volumes_.size() - 1);
  }

  std::uint32_t child(std::uint32_t index, int f) const {
    const ONode& n = nodes_[index];
    return findNode(n.level + 1, n.code * 8 + U64(f));
  }
  bool isEmptyUnit(std::uint32_t index) const {
    const ONode& n = nodes_[index];
    return n.kind == Kind::kEmpty || (n.kind == Kind::kInternal && n.type == 1);
  }
  // Points every empty leaf under `index` at volume `v`.
  void assignVolume(std::uint32_t index, std::uint32_t v) {
    ONode& n = nodes_[index];
    if (n.kind == Kind::kEmpty)
      n.payload = v;
    else if (n.kind == Kind::kInternal)
      for (int f = 0; f < 8; ++f) assignVolume(child(index, f), v);
  }

  // Sec. 2.2.1: merge the empty children of an internal node. Each unmerged empty child grows, axis by axis,
  // towards the coplanar siblings its direction attribute D still allows (D: 6 bits, bit 2a+s set when the
  // sibling on side s of axis a lies in the same parent), D of a group the AND of its members' D. All eight
  // empty: type 1 (the node's cube is one volume); otherwise type 2 when anything merged.
  void mergeChildren(std::uint32_t index) {
    std::uint32_t kids[8];
    bool empty[8], merged[8] = {};
    int emptyCount = 0;
    for (int f = 0; f < 8; ++f) {
      kids[f] = child(index, f);
      assert(kids[f] != kNoTriangle);
      empty[f] = isEmptyUnit(kids[f]);
      emptyCount += empty[f];
    }
    ONode& n = nodes_[index];
    if (emptyCount == 8) {
      n.type = 1;
      assignVolume(index, newVolume(space_.cell(n.level, n.code)));
      return;
    }
    n.type = 0;
    const int level = n.level;
    const U64 code = n.code;
    auto directions = [](int f) {
      std::uint8_t d = 0;
      for (int a = 0; a < 3; ++a) d |= std::uint8_t(1u << (2 * a + ((f >> a) & 1 ? 0 : 1)));
      return d;  // the sibling is on the + side when the bit of F is 0, on the - side when it is 1
    };
    for (int f = 0; f < 8; ++f) {
      if (!empty[f] || merged[f]) continue;
      int members[8] = {f};
      int count = 1;
      std::uint8_t d = directions(f);
      merged[f] = true;
      for (int a = 0; a < 3; ++a) {
        if (!(d & (3u << (2 * a)))) continue;  // no sibling left along this axis
        bool ok = true;
        for (int m = 0; m < count && ok; ++m)
          ok = empty[members[m] ^ (1 << a)] && !merged[members[m] ^ (1 << a)];
        if (!ok) continue;
        for (int m = 0, c = count; m < c; ++m) {
          const int g = members[m] ^ (1 << a);
          members[count++] = g;
          merged[g] = true;
          d &= directions(g);  // Sec. 2.2.2: D of the merged node, bitwise AND
        }
      }
      IBox box = space_.cell(level + 1, code * 8 + U64(members[0]));
      for (int m = 1; m < count; ++m) {
        const IBox c = space_.cell(level + 1, code * 8 + U64(members[m]));
        box.lo = glm::min(box.lo, c.lo);
        box.hi = glm::max(box.hi, c.hi);
      }
      if (count > 1) nodes_[index].type = 2;
      const std::uint32_t v = newVolume(box);
      for (int m = 0; m < count; ++m) assignVolume(kids[members[m]], v);
    }
  }

  std::uint32_t parentOf(std::uint32_t index) const {
    const ONode& n = nodes_[index];
    return n.level == 0 ? kNoTriangle : findNode(n.level - 1, n.code >> 3);
  }

  // Sec. 3: after a leaf under `parent` changed between empty and full, re-merge upwards while the node is,
  // or was, type 1; stop at the first node that is neither (a type-2 or unmerged node).
  void remergeUp(std::uint32_t parent) {
    while (parent != kNoTriangle) {
      const bool wasType1 = nodes_[parent].type == 1;
      mergeChildren(parent);
      if (!wasType1 && nodes_[parent].type != 1) return;
      parent = parentOf(parent);
    }
  }

  void insertInto(std::uint32_t index, std::uint32_t id) {
    ONode& n = nodes_[index];
    if (!overlapsCell(store_, id, space_.worldBox(space_.cell(n.level, n.code)))) return;
    if (n.kind == Kind::kInternal) {
      for (int f = 0; f < 8; ++f) insertInto(child(index, f), id);
      return;
    }
    if (n.kind == Kind::kEmpty) {
      n.kind = Kind::kFull;
      n.payload = newList({id});
      remergeUp(parentOf(index));  // step 3: the leaf leaves its volume
      return;
    }
    std::vector<std::uint32_t>& list = lists_[n.payload];
    list.insert(std::lower_bound(list.begin(), list.end(), id), id);
    std::vector<std::uint32_t> children[8];
    if (!subdivide(store_, space_, p_, n.level, n.code, list, children)) return;
    // Over the leaf size: the leaf becomes an internal node with eight new leaves.
    freeLists_.push_back(n.payload);
    lists_[n.payload].clear();
    n.kind = Kind::kInternal;
    n.type = 0;
    const int level = n.level;
    const U64 code = n.code;
    for (int f = 0; f < 8; ++f) {
      const std::uint32_t c = addNode(level + 1, code * 8 + U64(f));
      makeLeaf(c, std::move(children[f]));
    }
    mergeChildren(index);
  }

  void removeFrom(std::uint32_t index, std::uint32_t id) {
    ONode& n = nodes_[index];
    if (n.kind == Kind::kEmpty) return;
    if (!overlapsCell(store_, id, space_.worldBox(space_.cell(n.level, n.code)))) return;
    if (n.kind == Kind::kInternal) {
      for (int f = 0; f < 8; ++f) removeFrom(child(index, f), id);
      return;
    }
    std::vector<std::uint32_t>& list = lists_[n.payload];
    const auto it = std::lower_bound(list.begin(), list.end(), id);
    if (it == list.end() || *it != id) return;
    list.erase(it);
    if (!list.empty()) return;
    // Step 2: the leaf turned empty: merge with its empty siblings, upwards while all eight are empty.
    freeLists_.push_back(n.payload);
    n.kind = Kind::kEmpty;
    n.payload = newVolume(space_.cell(n.level, n.code));
    const std::uint32_t parent = parentOf(index);
    if (parent == kNoTriangle) return;
    remergeUp(parent);
  }

  // Leaf containing the finest-level cell q, searched from `level` (Sec. 2.4): up while the code does not
  // exist at that level (parent = code >> 3), down while the node is internal (child = 8·code + F). The
  // neighbour's code is re-encoded from integer coordinates: Eq. 7 (N' = N + 4α + 2β + γ) only holds
  // between siblings whose coordinate bits do not carry, so it is not used as printed.
  std::uint32_t locate(const glm::u64vec3& q, int level) const {
    const int maxLevel = space_.maxLevel;
    for (;;) {
      const int shift = maxLevel - level;
      const std::uint32_t i = findNode(level, morton(q.x >> shift, q.y >> shift, q.z >> shift));
      if (i == kNoTriangle) {
        assert(level > 0);
        --level;
        continue;
      }
      if (nodes_[i].kind != Kind::kInternal) return i;
      ++level;
    }
  }

  glm::u64vec3 quantize(const dvec3& p) const {
    const double top = double((U64(1) << space_.maxLevel) - 1);
    glm::u64vec3 q;
    for (int a = 0; a < 3; ++a) {
      const double f = std::floor((p[a] - space_.lo[a]) / space_.fine);
      q[a] = U64(std::clamp(std::isnan(f) ? 0.0 : f, 0.0, top));
    }
    return q;
  }

  // Walks the leaves and merged volumes along the ray: Liang-Barsky exit of the current box, then the
  // neighbour across the exit face found from the Morton code (Sec. 2.3-2.4). `visit` returns true to stop.
  template <class Visit>
  bool march(const RayCtx& r, const Hit& best, Visit&& visit) const {
    if (store_.valid.empty()) return false;
    double u1, u2;
    int axis;
    if (!liangBarsky(r, grow(rootBox(), store_.fat), u1, u2, axis)) return false;
    double t = std::max(u1, r.tMin);
    const double tEnd = std::min(u2, r.tMax);
    if (t > tEnd) return false;
    const U64 cells = U64(1) << space_.maxLevel;
    std::uint32_t leaf = locate(quantize(r.o + r.d * t), 0);
    // Each step crosses a face of the current box, so this bounds the walk (a safety net, never reached).
    const std::size_t maxSteps = 6 * std::size_t(cells) * 3 + 64;
    for (std::size_t step = 0; step < maxSteps; ++step) {
      const ONode& n = nodes_[leaf];
      IBox region;
      if (n.kind == Kind::kFull) {
        region = space_.cell(n.level, n.code);
        for (std::uint32_t id : lists_[n.payload])
          if (visit(id)) return true;
      } else {
        region = volumes_[n.payload];  // the merged volume: skipped in one step
      }
      // The box grown by the margin: a ray that rounding put a hair beside it still gets its exit face.
      if (!liangBarsky(r, grow(space_.worldBox(region), store_.fat), u1, u2, axis)) return false;
      if (axis < 0 || best.t <= u2 || u2 >= tEnd) return false;
      t = std::max(t, u2);
      glm::u64vec3 q = quantize(r.o + r.d * t);
      if (r.d[axis] > 0.0) {
        if (region.hi[axis] >= cells) return false;
        q[axis] = region.hi[axis];
      } else {
        if (region.lo[axis] == 0) return false;
        q[axis] = region.lo[axis] - 1;
      }
      // Keep the other coordinates inside the face we leave through when rounding put them beside it.
      for (int a = 0; a < 3; ++a)
        if (a != axis) q[a] = std::clamp(q[a], region.lo[a], region.hi[a] - 1);
      leaf = locate(q, n.level);
    }
    assert(false && "OAVM march did not terminate");
    return false;
  }

  void collect(std::uint32_t index, const Box& q, std::vector<std::uint32_t>& out) const {
    const ONode& n = nodes_[index];
    if (n.kind == Kind::kEmpty || !boxesOverlap(q, space_.worldBox(space_.cell(n.level, n.code)))) return;
    if (n.kind == Kind::kFull)
      return void(out.insert(out.end(), lists_[n.payload].begin(), lists_[n.payload].end()));
    for (int f = 0; f < 8; ++f) collect(child(index, f), q, out);
  }

  static std::vector<Plane> octreePlanes(const Space& s, std::size_t depth, std::size_t limit);
  friend std::vector<Plane> classicPlanes(const Space& s, std::size_t depth, std::size_t limit);

  TriangleStore store_;
  OctreeParams p_;
  Space space_;
  std::vector<CodeMap> levels_;
  std::vector<ONode> nodes_;
  std::vector<std::vector<std::uint32_t>> lists_;
  std::vector<std::uint32_t> freeLists_;
  std::vector<IBox> volumes_;
  std::size_t deepest_ = 0;
};

std::vector<Accel::Plane> Oavm::octreePlanes(const Space& s, std::size_t depth, std::size_t limit) {
  std::vector<Plane> out;
  for (std::size_t level = 1; level <= depth; ++level) {
    const U64 n = U64(1) << level;
    for (U64 k = 1; k < n; k += 1)
      for (int a = 0; a < 3 && out.size() < limit; ++a)
        out.push_back(Plane{a, s.lo[a] + double(k << (s.maxLevel - int(level))) * s.fine});
  }
  return out;
}

void Oavm::checkInvariants() const {
  auto fail = [](const std::string& what) { throw std::logic_error("OAVM invariant: " + what); };
  for (std::uint32_t i = 0; i < nodes_.size(); ++i) {
    const ONode& n = nodes_[i];
    if (findNode(n.level, n.code) != i) fail("node not found from its code");
    if (n.kind == Kind::kInternal) {
      bool allEmpty = true;
      for (int f = 0; f < 8; ++f) {
        const std::uint32_t c = child(i, f);
        if (c == kNoTriangle) fail("internal node without all eight children");
        allEmpty &= isEmptyUnit(c);
      }
      if (allEmpty != (n.type == 1)) fail("type 1 exactly when all children are empty");
    } else if (n.kind == Kind::kEmpty) {
      const IBox cell = space_.cell(n.level, n.code), v = volumes_[n.payload];
      for (int a = 0; a < 3; ++a)
        if (cell.lo[a] < v.lo[a] || cell.hi[a] > v.hi[a]) fail("empty leaf outside its volume");
    } else {
      for (std::uint32_t id : lists_[n.payload])
        if (!store_.isValid(id)) fail("full leaf lists a removed triangle");
      if (lists_[n.payload].empty()) fail("full leaf without triangles");
    }
  }
  // No volume overlaps a full leaf's interior.
  for (const ONode& n : nodes_) {
    if (n.kind != Kind::kEmpty) continue;
    const IBox v = volumes_[n.payload];
    for (const ONode& m : nodes_) {
      if (m.kind != Kind::kFull) continue;
      const IBox c = space_.cell(m.level, m.code);
      if (c.lo.x < v.hi.x && v.lo.x < c.hi.x && c.lo.y < v.hi.y && v.lo.y < c.hi.y && c.lo.z < v.hi.z &&
          v.lo.z < c.hi.z)
        fail("a merged volume covers a full leaf");
    }
  }
}

}  // namespace
}  // namespace detail

std::unique_ptr<OavmOctree> OavmOctree::build(const Triangles& triangles, const OctreeParams& params,
                                              const Box& bounds) {
  params.validate();
  return std::make_unique<detail::Oavm>(triangles, params, bounds);
}

}  // namespace svo::accel
