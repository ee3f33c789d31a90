// Top-down voxelization (DESIGN.md, builder): each voxel keeps the triangles that overlap its cube (exact
// separating-axis test), fits a contour from their clipped pieces, and hands each child the triangles that
// overlap the child. Leaves average color and normal over their clipped geometry, weighted by area; inner
// voxels aggregate their children. The top levels fan out as independent oneTBB tasks whose results are
// concatenated in slot order, so the output does not depend on scheduling.
#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <exception>
#include <mutex>
#include <numbers>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>

#include <tbb/parallel_for.h>
#include <glm/geometric.hpp>

#include "geometry.hpp"
#include "svo/builder/build.hpp"

namespace svo {
namespace {

using glm::dvec3;
using glm::dvec4;

// Levels above this run their children as parallel tasks (8^3 = 512 subtrees keep 2-64 cores busy).
constexpr int kParallelDepth = 3;
// Triangle normals tried as contour directions besides the area-weighted mean (sec. 5.2: candidates from
// the triangles in the voxel); the largest clipped pieces go first.
constexpr int kMaxContourCandidates = 8;
// Candidates closer than this (cosine) to one already tried add nothing.
constexpr double kSameDirectionCos = 0.999;
// Weight of a piece with zero clipped area (a triangle touching the voxel along an edge or at a point),
// relative to the voxel's face area: keeps such voxels' attributes defined without biasing others.
constexpr double kTouchWeight = 1e-9;
// Margin around the mesh bounds when fitting the scene cube, so no triangle lies on the outer boundary.
constexpr double kSceneMargin = 1.0 / 64.0;

struct Triangle {
  dvec3 p[3];    // octree space
  dvec3 normal;  // unit
  std::uint32_t source;
};

// A voxel whose exact overlap test passed but none of whose children's did (rounding on a shared face or
// edge) has no finest descendant: it is marked dead and pruned, so every leaf sits at the finest level.
constexpr std::uint32_t kDeadVoxel = 0xFFFFFFFFu;

struct Aggregate {
  double weight = 0.0;  // zero only for a dead subtree
  dvec4 color{0.0};
  dvec3 normal{0.0};
  void add(const Aggregate& o) {
    weight += o.weight;
    color += o.color;
    normal += o.normal;
  }
};

struct Node {
  int level = 0;
  glm::ivec3 coord{0};
  std::vector<std::uint32_t> triangles;
  std::vector<geom::Slab> slabs;  // ancestor contours that cut this cube
};

// What a voxel decided before its children are built.
struct Prepared {
  VoxelRecord record;
  bool leaf = false;
  Aggregate leafAttributes;    // leaves only
  std::vector<Node> children;  // slot order, non-empty ones
};

struct Piece {
  geom::Polygon polygon;
  double area = 0.0;
  dvec3 centroid{0.0};
  std::uint32_t triangle = 0;
};

class Voxelizer {
 public:
  Voxelizer(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options)
      : mesh_(mesh), options_(options), colors_(mesh.hasColor()) {
    if (options.levels < 1 || options.levels > kMaxLevels)
      throw std::invalid_argument("levels must be in [1, " + std::to_string(kMaxLevels) + "], got " +
                                  std::to_string(options.levels));
    triangles_.reserve(mesh.triangles.size());
    for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
      Triangle t;
      for (int k = 0; k < 3; ++k) t.p[k] = transform.toOctree(mesh.positions[mesh.triangles[i][k]]);
      const dvec3 n = glm::cross(t.p[1] - t.p[0], t.p[2] - t.p[0]);
      const double length = glm::length(n);
      if (!(length > 0.0)) continue;  // degenerate after the transform (sub-ulp triangle)
      t.normal = n / length;
      t.source = std::uint32_t(i);
      triangles_.push_back(t);
    }
    if (triangles_.empty()) throw std::runtime_error("mesh has no non-degenerate triangles");
  }

  VoxelTree run(BuildStats* stats) {
    Node root;
    root.triangles.resize(triangles_.size());
    for (std::uint32_t i = 0; i < root.triangles.size(); ++i) root.triangles[i] = i;
    Subtree s = buildParallel(std::move(root));
    if (s.attributes.weight == 0.0) throw std::runtime_error("mesh produced no voxels");
    VoxelTree tree;
    tree.voxels = deadFound_ ? prune(s.records) : std::move(s.records);
    tree.hasColors = colors_;
    tree.hasNormals = true;
    if (stats) {
      *stats = BuildStats{};
      stats->trianglesUsed = triangles_.size();
      addTreeStats(tree, 0, *stats);
    }
    return tree;
  }

  // The levels above `cellLevel` as voxelize() builds them, each cell (a voxel of cellLevel) built on its own
  // and handed to `callbacks.built`, up to `concurrency` cells at a time. Returns the tree down to cellLevel
  // with the cells' roots as leaves.
  VoxelTree runCells(int cellLevel, const CellCallbacks& callbacks, int concurrency) {
    // 1. Top down to the cells, exactly as buildParallel prepares these levels.
    std::vector<TopVoxel> top;
    std::vector<Node> cellNodes;
    Node root;
    root.triangles.resize(triangles_.size());
    for (std::uint32_t i = 0; i < root.triangles.size(); ++i) root.triangles[i] = i;
    prepareTop(std::move(root), cellLevel, top, cellNodes);
    if (callbacks.planned) callbacks.planned(cellNodes.size());

    // 2. The cells: built (or taken from an earlier run) and handed on; only their roots stay here.
    std::vector<CellRoot> cells(cellNodes.size());
    std::atomic<std::size_t> next{0};
    std::mutex failedMutex;
    std::exception_ptr failed;  // the first error stops the rest and is rethrown here
    const auto work = [&] {
      try {
        buildCells(next, cellNodes, cells, callbacks);
      } catch (...) {
        std::lock_guard lock(failedMutex);
        if (!failed) failed = std::current_exception();
        next = cellNodes.size();
      }
    };
    {
      std::vector<std::jthread> workers;
      for (int t = 1; t < std::max(1, concurrency); ++t) workers.emplace_back(work);
      work();
    }
    if (failed) std::rethrow_exception(failed);

    // 3. The top's attributes from the cells' sums, bottom up in slot order as buildParallel adds them.
    VoxelTree tree;
    tree.hasColors = colors_;
    tree.hasNormals = true;
    tree.voxels.resize(1);
    const Aggregate all = assembleTop(top, 0, cells, tree.voxels, 0);
    if (all.weight == 0.0) throw std::runtime_error("mesh produced no voxels");
    tree.voxels = prune(tree.voxels);
    return tree;
  }

 private:
  struct Subtree {
    std::vector<VoxelRecord> records;  // [0] is the subtree's root
    Aggregate attributes;
  };

  void buildCells(std::atomic<std::size_t>& next, std::vector<Node>& cellNodes, std::vector<CellRoot>& cells,
                  const CellCallbacks& callbacks) const {
    for (std::size_t i; (i = next.fetch_add(1)) < cellNodes.size();) {
      Node& node = cellNodes[i];
      const glm::ivec3 coord = node.coord;
      if (callbacks.finished)
        if (std::optional<CellRoot> done = callbacks.finished(coord)) {
          cells[i] = *done;
          node = Node{};
          continue;
        }
      Subtree cell;
      cell.records.resize(1);
      cell.attributes = buildInto(node, cell.records, 0);
      node = Node{};
      VoxelTree tree;
      const bool dead = std::any_of(cell.records.begin(), cell.records.end(),
                                    [](const VoxelRecord& r) { return r.firstChild == kDeadVoxel; });
      tree.voxels = dead ? prune(cell.records) : std::move(cell.records);
      cell.records = {};
      tree.hasColors = colors_;
      tree.hasNormals = true;
      cells[i] = {tree.voxels[0], {cell.attributes.weight, cell.attributes.color, cell.attributes.normal}};
      callbacks.built(coord, std::move(tree), cells[i]);
    }
  }

  // A voxel above the cells: its prepared record, and its children (top voxels or cells) in slot order.
  struct TopVoxel {
    VoxelRecord record;
    bool leaf = false;
    Aggregate leafAttributes;
    std::vector<std::int64_t> children;  // >= 0: a top voxel; < 0: cell ~index
  };

  void prepareTop(Node node, int cellLevel, std::vector<TopVoxel>& top, std::vector<Node>& cellNodes) const {
    const std::size_t self = top.size();
    top.emplace_back();
    Prepared p = prepare(node);
    node.triangles = {};
    top[self].record = p.record;
    if (p.leaf) {
      top[self].leaf = true;
      top[self].leafAttributes = p.leafAttributes;
      return;
    }
    for (Node& child : p.children) {
      if (child.level == cellLevel) {
        top[self].children.push_back(~std::int64_t(cellNodes.size()));
        cellNodes.push_back(std::move(child));
      } else {
        top[self].children.push_back(std::int64_t(top.size()));
        prepareTop(std::move(child), cellLevel, top, cellNodes);
      }
    }
  }

  // Writes top voxel `t` at out[self] and its children's records after it, depth first like buildInto;
  // cells become leaves carrying their roots' contour and attributes. Returns the voxel's sums.
  Aggregate assembleTop(const std::vector<TopVoxel>& top, std::size_t t, const std::vector<CellRoot>& cells,
                        std::vector<VoxelRecord>& out, std::size_t self) const {
    const TopVoxel& v = top[t];
    if (v.leaf) {
      out[self] = v.record;
      return v.leafAttributes;
    }
    const std::size_t first = out.size();
    out[self] = v.record;
    out[self].firstChild = std::uint32_t(first);
    out.resize(first + v.children.size());
    Aggregate sum;
    for (std::size_t k = 0; k < v.children.size(); ++k) {
      const std::int64_t c = v.children[k];
      if (c >= 0) {
        sum.add(assembleTop(top, std::size_t(c), cells, out, first + k));
        continue;
      }
      const CellRoot& cell = cells[std::size_t(~c)];
      VoxelRecord leaf = cell.record;
      leaf.childMask = 0;
      if (cell.sums.weight == 0.0) {
        leaf.firstChild = kDeadVoxel;  // the cell's voxels all died: pruned like any dead voxel
        deadFound_ = true;
      } else {
        leaf.firstChild = 0;
      }
      out[first + k] = leaf;
      sum.add(Aggregate{cell.sums.weight, cell.sums.color, cell.sums.normal});
    }
    if (!markIfDead(out[self], sum)) setAttributes(out[self], sum);
    return sum;
  }

  geom::Cube cubeOf(const Node& node) const {
    const double size = std::ldexp(1.0, -node.level);
    return {dvec3(1.0) + dvec3(node.coord) * size, size};
  }

  // Color of the source triangle at a point of its plane, times its material and texture over the piece.
  dvec4 pieceColor(const Piece& piece) const {
    const glm::uvec3 idx = mesh_.triangles[triangles_[piece.triangle].source];
    const Triangle& t = triangles_[piece.triangle];
    auto barycentric = [&](const dvec3& x) {
      const dvec3 e0 = t.p[1] - t.p[0], e1 = t.p[2] - t.p[0], r = x - t.p[0];
      const double d00 = glm::dot(e0, e0), d01 = glm::dot(e0, e1), d11 = glm::dot(e1, e1);
      const double d20 = glm::dot(r, e0), d21 = glm::dot(r, e1), den = d00 * d11 - d01 * d01;
      const double v = (d11 * d20 - d01 * d21) / den, w = (d00 * d21 - d01 * d20) / den;
      return dvec3(1.0 - v - w, v, w);
    };
    const Material& material = mesh_.materialOf(t.source);
    dvec4 color(material.baseColor);
    if (!mesh_.colors.empty()) {
      const dvec3 b = barycentric(piece.centroid);
      color *= b.x * dvec4(mesh_.colors[idx.x]) + b.y * dvec4(mesh_.colors[idx.y]) +
               b.z * dvec4(mesh_.colors[idx.z]);
    }
    if (material.texture >= 0 && !mesh_.uvs.empty()) {
      glm::vec2 uv[geom::kMaxClippedVertices + 3];
      for (int k = 0; k < piece.polygon.n; ++k) {
        const dvec3 b = barycentric(piece.polygon.v[k]);
        uv[k] = glm::vec2(b.x * glm::dvec2(mesh_.uvs[idx.x]) + b.y * glm::dvec2(mesh_.uvs[idx.y]) +
                          b.z * glm::dvec2(mesh_.uvs[idx.z]));
      }
      color *= dvec4(mesh_.textures[material.texture]->average({uv, std::size_t(piece.polygon.n)}));
    }
    return color;
  }

  // Contour fit (sec. 5.2-5.3): among the candidate normals keep the slab that cuts away most of the
  // ancestor-bounded hull; store it only when the cut exceeds contourMinReduction voxels.
  struct ContourFit {
    std::uint32_t bits = 0;
    double cut = 0.0;        // voxel units removed from the hull along the normal
    double thickness = 0.0;  // surface extent along the normal, voxel units
  };
  std::optional<ContourFit> fitContour(const geom::Cube& cube, const std::vector<Piece>& pieces,
                                       const std::vector<geom::Slab>& slabs, double minCut) const {
    std::vector<dvec3> candidates;
    dvec3 mean(0.0);
    for (const Piece& p : pieces)
      mean += triangles_[p.triangle].normal * (p.area + kTouchWeight * cube.size * cube.size);
    if (glm::length(mean) > 0.0) candidates.push_back(glm::normalize(mean));
    std::vector<const Piece*> largest;
    for (const Piece& p : pieces) largest.push_back(&p);
    const std::size_t keep = std::min<std::size_t>(largest.size(), kMaxContourCandidates * 4);
    std::partial_sort(largest.begin(), largest.begin() + keep, largest.end(),
                      [](const Piece* a, const Piece* b) {
                        return a->area > b->area || (a->area == b->area && a->triangle < b->triangle);
                      });
    for (std::size_t i = 0; i < keep && int(candidates.size()) <= kMaxContourCandidates; ++i) {
      const dvec3 n = triangles_[largest[i]->triangle].normal;
      const bool seen = std::any_of(candidates.begin(), candidates.end(), [&](const dvec3& c) {
        return std::abs(glm::dot(c, n)) > kSameDirectionCos;
      });
      if (!seen) candidates.push_back(n);
    }

    const dvec3 centre = cube.centre();
    const geom::HullVertices hull = slabs.empty() ? geom::HullVertices{} : geom::hullVertices(cube, slabs);
    std::optional<ContourFit> best;
    double bestScore = 0.0;
    for (const dvec3& candidate : candidates) {
      const glm::ivec3 qn = quantizeContourNormal(candidate);
      const dvec3 n = dvec3(qn) / double(kContourNormalScale);
      double lo = 1e300, hi = -1e300;
      for (const Piece& p : pieces)
        for (const dvec3& v : p.polygon.vertices()) {
          const double d = glm::dot(n, v - centre) / cube.size;
          lo = std::min(lo, d), hi = std::max(hi, d);
        }
      double hullLo, hullHi;
      if (hull.empty()) {
        hullHi = 0.5 * (std::abs(n.x) + std::abs(n.y) + std::abs(n.z));
        hullLo = -hullHi;
      } else {
        hullLo = 1e300, hullHi = -1e300;
        for (const dvec3& v : hull.vertices()) {
          const double d = glm::dot(n, v - centre) / cube.size;
          hullLo = std::min(hullLo, d), hullHi = std::max(hullHi, d);
        }
      }
      std::uint32_t bits;
      if (!(hullHi > hullLo) || !encodeContour(qn, lo, hi, bits)) continue;
      const Contour c = decodeContour(bits);
      const double slabLo = c.position - 0.5 * c.thickness, slabHi = c.position + 0.5 * c.thickness;
      const double cut = std::max(0.0, slabLo - hullLo) + std::max(0.0, hullHi - slabHi);
      const double score = cut / (hullHi - hullLo);
      if (cut >= minCut && score > bestScore) bestScore = score, best = ContourFit{bits, cut, hi - lo};
    }
    return best;
  }

  std::vector<Piece> clipPieces(const Node& node, const geom::Cube& cube) const {
    std::vector<Piece> pieces;
    pieces.reserve(node.triangles.size());
    for (std::uint32_t ti : node.triangles) {
      const Triangle& t = triangles_[ti];
      Piece p;
      p.triangle = ti;
      p.polygon = geom::clipTriangleToCube(t.p[0], t.p[1], t.p[2], cube);
      if (p.polygon.n == 0) {
        // The SAT says the closed cube touches the triangle; clipping lost it to rounding. Keep the
        // triangle's closest vertex so the voxel still has a defined piece.
        p.polygon.n = 1;
        p.polygon.v[0] = glm::clamp(t.p[0], cube.lo, cube.lo + cube.size);
      }
      p.area = geom::polygonArea(p.polygon, &p.centroid);
      pieces.push_back(p);
    }
    return pieces;
  }

  Aggregate attributesOf(const std::vector<Piece>& pieces, const geom::Cube& cube, double* colorSpread,
                         double* normalSpreadCos) const {
    Aggregate a;
    std::vector<dvec4> colors(colors_ ? pieces.size() : 0);
    for (std::size_t i = 0; i < pieces.size(); ++i) {
      const double w = pieces[i].area + kTouchWeight * cube.size * cube.size;
      a.weight += w;
      a.normal += w * triangles_[pieces[i].triangle].normal;
      if (colors_) colors[i] = pieceColor(pieces[i]), a.color += w * colors[i];
    }
    if (colorSpread) {
      *colorSpread = 0.0;
      const dvec4 mean = a.color / a.weight;
      for (const dvec4& c : colors) {
        const dvec4 d = glm::abs(c - mean) * 255.0;
        *colorSpread = std::max({*colorSpread, d.r, d.g, d.b, d.a});
      }
    }
    if (normalSpreadCos) {
      *normalSpreadCos = 1.0;
      const dvec3 mean = glm::length(a.normal) > 0.0 ? glm::normalize(a.normal) : dvec3(0, 0, 1);
      for (const Piece& p : pieces)
        *normalSpreadCos = std::min(*normalSpreadCos, glm::dot(mean, triangles_[p.triangle].normal));
    }
    return a;
  }

  void setAttributes(VoxelRecord& r, const Aggregate& a) const {
    if (colors_) r.color = encodeColor(glm::vec4(a.color / a.weight));
    r.normal =
        encodeNormal(glm::length(a.normal) > 0.0 ? glm::vec3(glm::normalize(a.normal)) : glm::vec3(0, 0, 1));
  }

  Prepared prepare(Node& node) const {
    Prepared out;
    const geom::Cube cube = cubeOf(node);
    const bool finest = node.level == options_.levels;
    // Clipped pieces feed the contour fit and a leaf's attributes. The root needs neither (it has no contour
    // and is never a leaf), which spares holding every triangle of the scene clipped at once (~340 B each).
    const bool needPieces = finest || (options_.contours && node.level > 0);
    const std::vector<Piece> pieces = needPieces ? clipPieces(node, cube) : std::vector<Piece>{};
    // The root has no parent descriptor to hold a contour.
    std::optional<ContourFit> contour;
    if (options_.contours && node.level > 0)
      contour = fitContour(cube, pieces, node.slabs, options_.contourMinReduction);
    if (contour) out.record.hasContour = true, out.record.contour = contour->bits;

    bool stop = finest;
    std::optional<Aggregate> attributes;
    if (!finest && node.level > 0 && options_.geometryError > 0.0f && contour) {
      double colorSpread = 0.0, normalCos = 1.0;
      attributes = attributesOf(pieces, cube, &colorSpread, &normalCos);
      const double thicknessFinest = contour->thickness * std::ldexp(1.0, options_.levels - node.level);
      stop = thicknessFinest <= options_.geometryError &&
             (options_.colorError <= 0.0f || colorSpread <= options_.colorError) &&
             (options_.normalError <= 0.0f ||
              normalCos >= std::cos(double(options_.normalError) * std::numbers::pi / 180.0));
    }
    if (stop) {
      out.leaf = true;
      out.leafAttributes = attributes ? *attributes : attributesOf(pieces, cube, nullptr, nullptr);
      setAttributes(out.record, out.leafAttributes);
      return out;
    }

    // Slabs the children inherit: ours and our ancestors', each kept only where it still cuts the child.
    std::vector<geom::Slab> slabs = node.slabs;
    if (contour) {
      const Contour c = decodeContour(contour->bits);
      const dvec3 n(c.normal);
      const double base = glm::dot(n, cube.centre());
      slabs.push_back({n, base + cube.size * (double(c.position) - 0.5 * double(c.thickness)),
                       base + cube.size * (double(c.position) + 0.5 * double(c.thickness))});
    }
    // Classify triangles into the 8 children: bounding-box candidates, then the exact overlap test.
    std::vector<std::uint32_t> lists[8];
    const dvec3 mid = cube.centre();
    const double half = 0.5 * cube.size;
    for (std::uint32_t ti : node.triangles) {
      const Triangle& t = triangles_[ti];
      const dvec3 lo = glm::min(glm::min(t.p[0], t.p[1]), t.p[2]),
                  hi = glm::max(glm::max(t.p[0], t.p[1]), t.p[2]);
      for (int slot = 0; slot < 8; ++slot) {
        geom::Cube child{cube.lo + dvec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1) * half, half};
        bool candidate = true, inside = true;
        for (int a = 0; a < 3; ++a) {
          const bool upper = slot >> a & 1;
          if (upper ? hi[a] < mid[a] : lo[a] > mid[a]) candidate = false;
          if (lo[a] < child.lo[a] || hi[a] > child.lo[a] + half) inside = false;
        }
        if (candidate && (inside || geom::triangleOverlapsCube(t.p[0], t.p[1], t.p[2], child)))
          lists[slot].push_back(ti);
      }
    }
    for (int slot = 0; slot < 8; ++slot) {
      if (lists[slot].empty()) continue;
      Node child;
      child.level = node.level + 1;
      child.coord = node.coord * 2 + glm::ivec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1);
      child.triangles = std::move(lists[slot]);
      const geom::Cube childCube = cubeOf(child);
      for (const geom::Slab& s : slabs)
        if (geom::slabCutsCube(s, childCube)) child.slabs.push_back(s);
      out.record.childMask |= std::uint8_t(1u << slot);
      out.children.push_back(std::move(child));
    }
    return out;
  }

  // Marks `r` dead when none of its children survived; returns whether it did.
  bool markIfDead(VoxelRecord& r, const Aggregate& sum) const {
    if (sum.weight != 0.0) return false;
    r.childMask = 0;
    r.firstChild = kDeadVoxel;
    deadFound_ = true;
    return true;
  }

  // Drops dead records: breadth first from the root, keeping each voxel's live children contiguous.
  static std::vector<VoxelRecord> prune(const std::vector<VoxelRecord>& in) {
    std::vector<VoxelRecord> out{in[0]};
    std::vector<std::pair<std::uint32_t, std::uint32_t>> queue{{0u, 0u}};  // (input index, output index)
    for (std::size_t q = 0; q < queue.size(); ++q) {
      const auto [i, o] = queue[q];
      const VoxelRecord& r = in[i];
      if (r.childMask == 0) continue;
      std::uint8_t mask = 0;
      const std::uint32_t first = std::uint32_t(out.size());
      for (std::uint32_t c = r.firstChild, slot = 0; slot < 8; ++slot) {
        if (!(r.childMask >> slot & 1u)) continue;
        if (in[c].firstChild != kDeadVoxel) {
          mask |= std::uint8_t(1u << slot);
          queue.push_back({c, std::uint32_t(out.size())});
          out.push_back(in[c]);
        }
        ++c;
      }
      out[o].childMask = mask;
      out[o].firstChild = first;
    }
    return out;
  }

  // Depth-first into one vector: a voxel's children get consecutive records, then each child's subtree.
  Aggregate buildInto(Node& node, std::vector<VoxelRecord>& out, std::size_t self) const {
    Prepared p = prepare(node);
    node.triangles = {};  // free early: the children hold what they need
    if (p.leaf) {
      out[self] = p.record;
      return p.leafAttributes;
    }
    const std::size_t first = out.size();
    p.record.firstChild = std::uint32_t(first);
    out[self] = p.record;
    out.resize(first + p.children.size());
    Aggregate sum;
    for (std::size_t i = 0; i < p.children.size(); ++i) sum.add(buildInto(p.children[i], out, first + i));
    if (!markIfDead(out[self], sum)) setAttributes(out[self], sum);
    return sum;
  }

  Subtree buildParallel(Node node) const {
    Subtree s;
    if (node.level >= kParallelDepth || node.level == options_.levels) {
      s.records.resize(1);
      s.attributes = buildInto(node, s.records, 0);
      reportProgress(node.level);
      return s;
    }
    Prepared p = prepare(node);
    node.triangles = {};
    if (p.leaf) {
      s.records.push_back(p.record);
      s.attributes = p.leafAttributes;
      reportProgress(node.level);
      return s;
    }
    // Empty children count as done at once.
    for (int slot = 0; slot < 8; ++slot)
      if (!(p.record.childMask >> slot & 1u)) reportProgress(node.level + 1);
    std::vector<Subtree> parts(p.children.size());
    tbb::parallel_for(std::size_t(0), parts.size(),
                      [&](std::size_t i) { parts[i] = buildParallel(std::move(p.children[i])); });

    // Concatenate: our record, the children's roots, then the rest of each child's records.
    const std::size_t k = parts.size();
    std::size_t total = 1 + k;
    for (const Subtree& part : parts) total += part.records.size() - 1;
    s.records.reserve(total);
    s.records.push_back(p.record);
    s.records[0].firstChild = 1;
    std::vector<std::size_t> base(k);
    std::size_t next = 1 + k;
    for (std::size_t i = 0; i < k; ++i) base[i] = next, next += parts[i].records.size() - 1;
    for (std::size_t i = 0; i < k; ++i) s.records.push_back(parts[i].records[0]);
    for (std::size_t i = 0; i < k; ++i)
      s.records.insert(s.records.end(), parts[i].records.begin() + 1, parts[i].records.end());
    for (std::size_t i = 0; i < k; ++i) {
      // Local index j >= 1 of part i now sits at base[i] + j - 1.
      auto fix = [&](VoxelRecord& r) {
        if (r.childMask) r.firstChild = std::uint32_t(base[i] + r.firstChild - 1);
      };
      fix(s.records[1 + i]);
      for (std::size_t j = 0; j + 1 < parts[i].records.size(); ++j) fix(s.records[base[i] + j]);
      s.attributes.add(parts[i].attributes);
    }
    if (!markIfDead(s.records[0], s.attributes)) setAttributes(s.records[0], s.attributes);
    return s;
  }

  void reportProgress(int level) const {
    if (!options_.progress) return;
    const double done = done_.fetch_add(std::ldexp(1.0, -3 * level)) + std::ldexp(1.0, -3 * level);
    options_.progress(std::min(done, 1.0));
  }

  const Mesh& mesh_;
  const BuildOptions& options_;
  const bool colors_;
  std::vector<Triangle> triangles_;
  mutable std::atomic<double> done_{0.0};
  mutable std::atomic<bool> deadFound_{false};
};

}  // namespace

SceneTransform fitSceneCube(const Mesh& mesh) {
  if (mesh.triangles.empty()) throw std::runtime_error("mesh has no triangles");
  dvec3 lo(1e308), hi(-1e308);
  for (const glm::uvec3& t : mesh.triangles)
    for (int k = 0; k < 3; ++k)
      lo = glm::min(lo, mesh.positions[t[k]]), hi = glm::max(hi, mesh.positions[t[k]]);
  const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z});
  if (!(extent > 0.0)) throw std::runtime_error("mesh has no extent: all vertices coincide");
  SceneTransform t;
  t.size = extent * (1.0 + 2.0 * kSceneMargin);
  t.origin = 0.5 * (lo + hi) - 0.5 * t.size;
  return t;
}

VoxelTree voxelize(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options,
                   BuildStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  VoxelTree tree = Voxelizer(mesh, transform, options).run(stats);
  if (stats) stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return tree;
}

VoxelTree voxelizeCells(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options,
                        int cellLevel, const CellCallbacks& callbacks, int concurrency) {
  if (cellLevel < 1 || cellLevel >= options.levels)
    throw std::invalid_argument("cell level must be in [1, levels - 1] = [1, " +
                                std::to_string(options.levels - 1) + "], got " + std::to_string(cellLevel));
  if (!callbacks.built) throw std::invalid_argument("voxelizeCells: no callback for built cells");
  return Voxelizer(mesh, transform, options).runCells(cellLevel, callbacks, concurrency);
}

void addTreeStats(const VoxelTree& tree, int rootLevel, BuildStats& stats) {
  std::vector<std::pair<std::uint32_t, int>> stack{{0u, rootLevel}};
  while (!stack.empty()) {
    const auto [v, level] = stack.back();
    stack.pop_back();
    if (stats.voxelsPerLevel.size() <= std::size_t(level))
      stats.voxelsPerLevel.resize(std::size_t(level) + 1);
    ++stats.voxelsPerLevel[std::size_t(level)];
    const VoxelRecord& r = tree.voxels[v];
    stats.contours += r.hasContour;
    if (r.childMask == 0) ++stats.leafVoxels;
    for (int c = 0; c < std::popcount(unsigned(r.childMask)); ++c)
      stack.push_back({r.firstChild + c, level + 1});
  }
}

Octree buildOctree(const Mesh& mesh, const BuildOptions& options, BuildStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  Octree octree;
  octree.transform = fitSceneCube(mesh);
  octree.parameters = {options.levels, options.geometryError, options.colorError, options.normalError,
                       std::uint32_t(options.contours)};
  const VoxelTree tree = voxelize(mesh, octree.transform, options, stats);
  octree.block = layoutBlock(tree, options.layout, stats ? &stats->layout : nullptr);
  if (stats) stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return octree;
}

}  // namespace svo
