// Top-down voxelization (DESIGN.md, builder): each voxel keeps the triangles that overlap its cube (exact
// separating-axis test), fits a contour from their clipped pieces, and hands each child the triangles that
// overlap the child. Leaves average color and normal over their clipped geometry, weighted by area; inner
// voxels aggregate their children. The top levels fan out as independent oneTBB tasks whose results are
// concatenated in slot order, so the output does not depend on scheduling.
#include <algorithm>
#include <array>
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

#include "cell_partition.hpp"
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

void checkLevels(const BuildOptions& options) {
  if (options.levels < 1 || options.levels > kMaxLevels)
    throw std::invalid_argument("levels must be in [1, " + std::to_string(kMaxLevels) + "], got " +
                                std::to_string(options.levels));
}

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

// Frees a vector's memory (`v = {}` assigns an empty initializer list and keeps the capacity).
template <class T>
void release(std::vector<T>& v) {
  std::vector<T>().swap(v);
}

// The octree-space triangle of world corners, or nullopt when it is degenerate after the transform (a
// sub-ulp triangle); both voxelizers skip those.
std::optional<Triangle> makeTriangle(const std::array<dvec3, 3>& world, const SceneTransform& transform,
                                     std::uint32_t source) {
  Triangle t;
  for (int k = 0; k < 3; ++k) t.p[k] = transform.toOctree(world[k]);
  const dvec3 n = glm::cross(t.p[1] - t.p[0], t.p[2] - t.p[0]);
  const double length = glm::length(n);
  if (!(length > 0.0)) return std::nullopt;
  t.normal = n / length;
  t.source = source;
  return t;
}

geom::Cube cubeAt(int level, glm::ivec3 coord) {
  const double size = std::ldexp(1.0, -level);
  return {dvec3(1.0) + dvec3(coord) * size, size};
}

glm::ivec3 childCoordOf(glm::ivec3 coord, int slot) {
  return coord * 2 + glm::ivec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1);
}

// The children of `cube` the triangle overlaps, as a slot mask: bounding-box candidates, then the exact test.
std::uint8_t overlappedChildren(const Triangle& t, const geom::Cube& cube) {
  const dvec3 mid = cube.centre();
  const double half = 0.5 * cube.size;
  const dvec3 lo = glm::min(glm::min(t.p[0], t.p[1]), t.p[2]),
              hi = glm::max(glm::max(t.p[0], t.p[1]), t.p[2]);
  std::uint8_t mask = 0;
  for (int slot = 0; slot < 8; ++slot) {
    geom::Cube child{cube.lo + dvec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1) * half, half};
    bool candidate = true, inside = true;
    for (int a = 0; a < 3; ++a) {
      const bool upper = slot >> a & 1;
      if (upper ? hi[a] < mid[a] : lo[a] > mid[a]) candidate = false;
      if (lo[a] < child.lo[a] || hi[a] > child.lo[a] + half) inside = false;
    }
    if (candidate && (inside || geom::triangleOverlapsCube(t.p[0], t.p[1], t.p[2], child)))
      mask |= std::uint8_t(1u << slot);
  }
  return mask;
}

Piece clipPiece(const Triangle& t, std::uint32_t index, const geom::Cube& cube) {
  Piece p;
  p.triangle = index;
  p.polygon = geom::clipTriangleToCube(t.p[0], t.p[1], t.p[2], cube);
  if (p.polygon.n == 0) {
    // The SAT says the closed cube touches the triangle; clipping lost it to rounding. Keep the triangle's
    // closest vertex so the voxel still has a defined piece.
    p.polygon.n = 1;
    p.polygon.v[0] = glm::clamp(t.p[0], cube.lo, cube.lo + cube.size);
  }
  p.area = geom::polygonArea(p.polygon, &p.centroid);
  return p;
}

// A piece's weight in its voxel's averages.
double pieceWeight(const Piece& p, const geom::Cube& cube) {
  return p.area + kTouchWeight * cube.size * cube.size;
}

// Color of the source triangle at the piece (barycentric vertex colors), times its material and texture.
// `colors` and `uvs` are the three corners' or null when the mesh has none.
dvec4 pieceColor(const Piece& piece, const Triangle& t, const glm::vec4* colors, const glm::vec2* uvs,
                 const Material& material, const std::vector<std::shared_ptr<const TextureImage>>& textures) {
  auto barycentric = [&](const dvec3& x) {
    const dvec3 e0 = t.p[1] - t.p[0], e1 = t.p[2] - t.p[0], r = x - t.p[0];
    const double d00 = glm::dot(e0, e0), d01 = glm::dot(e0, e1), d11 = glm::dot(e1, e1);
    const double d20 = glm::dot(r, e0), d21 = glm::dot(r, e1), den = d00 * d11 - d01 * d01;
    const double v = (d11 * d20 - d01 * d21) / den, w = (d00 * d21 - d01 * d20) / den;
    return dvec3(1.0 - v - w, v, w);
  };
  dvec4 color(material.baseColor);
  if (colors) {
    const dvec3 b = barycentric(piece.centroid);
    color *= b.x * dvec4(colors[0]) + b.y * dvec4(colors[1]) + b.z * dvec4(colors[2]);
  }
  if (material.texture >= 0 && uvs) {
    glm::vec2 uv[geom::kMaxClippedVertices + 3];
    for (int k = 0; k < piece.polygon.n; ++k) {
      const dvec3 b = barycentric(piece.polygon.v[k]);
      uv[k] = glm::vec2(b.x * glm::dvec2(uvs[0]) + b.y * glm::dvec2(uvs[1]) + b.z * glm::dvec2(uvs[2]));
    }
    color *= dvec4(textures[material.texture]->average({uv, std::size_t(piece.polygon.n)}));
  }
  return color;
}

// Attribute sums and spreads (the error-driven stop's measures) over a voxel's pieces.
void accumulate(Aggregate& a, double weight, const dvec3& normal, const dvec4* color) {
  a.weight += weight;
  a.normal += weight * normal;
  if (color) a.color += weight * *color;
}
dvec3 meanNormal(const Aggregate& a) {
  return glm::length(a.normal) > 0.0 ? glm::normalize(a.normal) : dvec3(0, 0, 1);
}
struct Spread {
  double color = 0.0;      // 8-bit steps from the mean color, max over the pieces
  double normalCos = 1.0;  // cosine to the mean normal, min over the pieces
  void add(const Aggregate& sums, const dvec3& normal, const dvec4* pieceColor) {
    if (pieceColor) {
      const dvec4 d = glm::abs(*pieceColor - sums.color / sums.weight) * 255.0;
      color = std::max({color, d.r, d.g, d.b, d.a});
    }
    normalCos = std::min(normalCos, glm::dot(meanNormal(sums), normal));
  }
};

// A contour direction: the candidate normal and its 6-bit quantization.
struct Direction {
  glm::ivec3 quantized;
  dvec3 normal;  // the quantized normal, as the slab uses it
};
// Where a voxel's pieces lie along a direction, in voxel units from its centre.
struct Extent {
  double lo = 1e300, hi = -1e300;
};

// Contour direction candidates (sec. 5.2): the area-weighted mean normal, then the normals of the largest
// pieces, skipping near-duplicates. Fed piece by piece, so a voxel's pieces need not exist all at once.
class ContourCandidates {
 public:
  void add(const Piece& p, const dvec3& normal, double weight) {
    mean_ += normal * weight;
    largest_.push_back({p.area, p.triangle, normal});
    std::push_heap(largest_.begin(), largest_.end(), ranksBefore);
    if (largest_.size() > kLargestKept) {
      std::pop_heap(largest_.begin(), largest_.end(), ranksBefore);  // the smallest kept goes
      largest_.pop_back();
    }
  }
  std::vector<Direction> directions() const {
    std::vector<dvec3> candidates;
    if (glm::length(mean_) > 0.0) candidates.push_back(glm::normalize(mean_));
    std::vector<Entry> largest = largest_;
    std::sort_heap(largest.begin(), largest.end(), ranksBefore);  // largest first
    for (std::size_t i = 0; i < largest.size() && int(candidates.size()) <= kMaxContourCandidates; ++i) {
      const dvec3 n = largest[i].normal;
      const bool seen = std::any_of(candidates.begin(), candidates.end(), [&](const dvec3& c) {
        return std::abs(glm::dot(c, n)) > kSameDirectionCos;
      });
      if (!seen) candidates.push_back(n);
    }
    std::vector<Direction> out;
    for (const dvec3& c : candidates) {
      const glm::ivec3 q = quantizeContourNormal(c);
      out.push_back({q, dvec3(q) / double(kContourNormalScale)});
    }
    return out;
  }

 private:
  // Pieces whose normals may become candidates: enough to find kMaxContourCandidates distinct ones.
  static constexpr std::size_t kLargestKept = kMaxContourCandidates * 4;
  struct Entry {
    double area;
    std::uint32_t triangle;
    dvec3 normal;
  };
  // Larger area first, ties by triangle order: a strict order, so the kept set is what a full sort keeps.
  static bool ranksBefore(const Entry& a, const Entry& b) {
    return a.area > b.area || (a.area == b.area && a.triangle < b.triangle);
  }
  dvec3 mean_{0.0};
  std::vector<Entry> largest_;  // a heap with the smallest kept piece on top
};

void extendExtents(const std::vector<Direction>& directions, const Piece& p, const geom::Cube& cube,
                   std::vector<Extent>& extents) {
  const dvec3 centre = cube.centre();
  for (std::size_t i = 0; i < directions.size(); ++i)
    for (const dvec3& v : p.polygon.vertices()) {
      const double d = glm::dot(directions[i].normal, v - centre) / cube.size;
      extents[i].lo = std::min(extents[i].lo, d), extents[i].hi = std::max(extents[i].hi, d);
    }
}

// The contour fit (sec. 5.2-5.3) once the candidates' extents are known: keep the slab that cuts away most of
// the ancestor-bounded hull; store it only when the cut exceeds `minCut` voxels.
struct ContourFit {
  std::uint32_t bits = 0;
  double cut = 0.0;        // voxel units removed from the hull along the normal
  double thickness = 0.0;  // surface extent along the normal, voxel units
};
std::optional<ContourFit> chooseContour(const geom::Cube& cube, const std::vector<Direction>& directions,
                                        const std::vector<Extent>& extents,
                                        const std::vector<geom::Slab>& slabs, double minCut) {
  const dvec3 centre = cube.centre();
  const geom::HullVertices hull = slabs.empty() ? geom::HullVertices{} : geom::hullVertices(cube, slabs);
  std::optional<ContourFit> best;
  double bestScore = 0.0;
  for (std::size_t i = 0; i < directions.size(); ++i) {
    const dvec3 n = directions[i].normal;
    const double lo = extents[i].lo, hi = extents[i].hi;
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
    if (!(hullHi > hullLo) || !encodeContour(directions[i].quantized, lo, hi, bits)) continue;
    const Contour c = decodeContour(bits);
    const double slabLo = c.position - 0.5 * c.thickness, slabHi = c.position + 0.5 * c.thickness;
    const double cut = std::max(0.0, slabLo - hullLo) + std::max(0.0, hullHi - slabHi);
    const double score = cut / (hullHi - hullLo);
    if (cut >= minCut && score > bestScore) bestScore = score, best = ContourFit{bits, cut, hi - lo};
  }
  return best;
}

// The error-driven stop: a voxel with a contour stops refining when its surface is within the geometry error
// and its attributes within the color and normal errors.
bool stopsRefining(const BuildOptions& options, int level, const ContourFit& contour, const Spread& spread) {
  const double thicknessFinest = contour.thickness * std::ldexp(1.0, options.levels - level);
  return thicknessFinest <= options.geometryError &&
         (options.colorError <= 0.0f || spread.color <= options.colorError) &&
         (options.normalError <= 0.0f ||
          spread.normalCos >= std::cos(double(options.normalError) * std::numbers::pi / 180.0));
}

// The slab a contour adds to the ones its descendants are bounded by.
geom::Slab slabOf(const geom::Cube& cube, std::uint32_t contourBits) {
  const Contour c = decodeContour(contourBits);
  const dvec3 n(c.normal);
  const double base = glm::dot(n, cube.centre());
  return {n, base + cube.size * (double(c.position) - 0.5 * double(c.thickness)),
          base + cube.size * (double(c.position) + 0.5 * double(c.thickness))};
}

// The slabs among `slabs` that still cut `cube`.
std::vector<geom::Slab> slabsCutting(const std::vector<geom::Slab>& slabs, const geom::Cube& cube) {
  std::vector<geom::Slab> out;
  for (const geom::Slab& s : slabs)
    if (geom::slabCutsCube(s, cube)) out.push_back(s);
  return out;
}

void setAttributes(VoxelRecord& r, const Aggregate& a, bool colors) {
  if (colors) r.color = encodeColor(glm::vec4(a.color / a.weight));
  r.normal = latticeNormal(glm::vec3(meanNormal(a)));  // the store keeps normals on its 16-bit lattice
}

// Marks `r` dead when none of its children survived; returns whether it did.
bool markIfDead(VoxelRecord& r, const Aggregate& sum) {
  if (sum.weight != 0.0) return false;
  r.childMask = 0;
  r.firstChild = kDeadVoxel;
  return true;
}

// Drops dead records: breadth first from the root, keeping each voxel's live children contiguous.
std::vector<VoxelRecord> prune(const std::vector<VoxelRecord>& in) {
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

std::vector<VoxelRecord> pruneIfDead(std::vector<VoxelRecord>&& records) {
  const bool dead = std::any_of(records.begin(), records.end(),
                                [](const VoxelRecord& r) { return r.firstChild == kDeadVoxel; });
  return dead ? prune(records) : std::move(records);
}

// The in-core voxelizer: every triangle of `mesh` in memory. The out-of-core build runs one per cell, over
// the cell's triangles.
class Voxelizer {
 public:
  Voxelizer(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options, bool colors)
      : mesh_(mesh), options_(options), colors_(colors) {
    triangles_.reserve(mesh.triangles.size());
    for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
      const glm::uvec3 t = mesh.triangles[i];
      if (const auto triangle = makeTriangle({mesh.positions[t.x], mesh.positions[t.y], mesh.positions[t.z]},
                                             transform, std::uint32_t(i)))
        triangles_.push_back(*triangle);
    }
  }

  VoxelTree run(BuildStats* stats) {
    if (triangles_.empty()) throw std::runtime_error("mesh has no non-degenerate triangles");
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

  // One cell: the voxel of `level` at `coord` bounded by its ancestors' `slabs`, over all of the mesh's
  // triangles (the ones that reach the cell; at least one), depth first on this thread. Its root first, dead
  // voxels pruned.
  VoxelTree runCell(int level, glm::ivec3 coord, std::vector<geom::Slab> slabs, Aggregate& sums) const {
    Node node;
    node.level = level;
    node.coord = coord;
    node.slabs = std::move(slabs);
    node.triangles.resize(triangles_.size());
    for (std::uint32_t i = 0; i < node.triangles.size(); ++i) node.triangles[i] = i;
    std::vector<VoxelRecord> records(1);
    sums = buildInto(node, records, 0);
    VoxelTree tree;
    tree.voxels = pruneIfDead(std::move(records));
    tree.hasColors = colors_;
    tree.hasNormals = true;
    return tree;
  }

 private:
  struct Subtree {
    std::vector<VoxelRecord> records;  // [0] is the subtree's root
    Aggregate attributes;
  };

  dvec4 colorOf(const Piece& piece) const {
    const Triangle& t = triangles_[piece.triangle];
    const glm::uvec3 idx = mesh_.triangles[t.source];
    glm::vec4 colors[3];
    glm::vec2 uvs[3];
    for (int k = 0; k < 3; ++k) {
      if (!mesh_.colors.empty()) colors[k] = mesh_.colors[idx[k]];
      if (!mesh_.uvs.empty()) uvs[k] = mesh_.uvs[idx[k]];
    }
    return pieceColor(piece, t, mesh_.colors.empty() ? nullptr : colors, mesh_.uvs.empty() ? nullptr : uvs,
                      mesh_.materialOf(t.source), mesh_.textures);
  }

  std::optional<ContourFit> fitContour(const geom::Cube& cube, const std::vector<Piece>& pieces,
                                       const std::vector<geom::Slab>& slabs, bool finest) const {
    ContourCandidates candidates;
    for (const Piece& p : pieces) candidates.add(p, triangles_[p.triangle].normal, pieceWeight(p, cube));
    const std::vector<Direction> directions = candidates.directions();
    std::vector<Extent> extents(directions.size());
    for (const Piece& p : pieces) extendExtents(directions, p, cube, extents);
    return chooseContour(cube, directions, extents, slabs,
                         finest ? options_.leafContourMinReduction : options_.innerContourMinReduction);
  }

  std::vector<Piece> clipPieces(const Node& node, const geom::Cube& cube) const {
    std::vector<Piece> pieces;
    pieces.reserve(node.triangles.size());
    for (std::uint32_t ti : node.triangles) pieces.push_back(clipPiece(triangles_[ti], ti, cube));
    return pieces;
  }

  Aggregate attributesOf(const std::vector<Piece>& pieces, const geom::Cube& cube, Spread* spread) const {
    Aggregate a;
    std::vector<dvec4> colors(colors_ ? pieces.size() : 0);
    for (std::size_t i = 0; i < pieces.size(); ++i) {
      if (colors_) colors[i] = colorOf(pieces[i]);
      accumulate(a, pieceWeight(pieces[i], cube), triangles_[pieces[i].triangle].normal,
                 colors_ ? &colors[i] : nullptr);
    }
    if (spread)
      for (std::size_t i = 0; i < pieces.size(); ++i)
        spread->add(a, triangles_[pieces[i].triangle].normal, colors_ ? &colors[i] : nullptr);
    return a;
  }

  Prepared prepare(Node& node) const {
    Prepared out;
    const geom::Cube cube = cubeAt(node.level, node.coord);
    const bool finest = node.level == options_.levels;
    // Clipped pieces feed the contour fit and a leaf's attributes. The root needs neither (it has no contour
    // and is never a leaf), which spares holding every triangle of the scene clipped at once (~340 B each).
    const bool needPieces = finest || (options_.contours && node.level > 0);
    const std::vector<Piece> pieces = needPieces ? clipPieces(node, cube) : std::vector<Piece>{};
    // The root has no parent descriptor to hold a contour.
    std::optional<ContourFit> contour;
    if (options_.contours && node.level > 0) contour = fitContour(cube, pieces, node.slabs, finest);
    if (contour) out.record.hasContour = true, out.record.contour = contour->bits;

    bool stop = finest;
    std::optional<Aggregate> attributes;
    if (!finest && node.level > 0 && options_.geometryError > 0.0f && contour) {
      Spread spread;
      attributes = attributesOf(pieces, cube, &spread);
      stop = stopsRefining(options_, node.level, *contour, spread);
    }
    if (stop) {
      out.leaf = true;
      out.leafAttributes = attributes ? *attributes : attributesOf(pieces, cube, nullptr);
      setAttributes(out.record, out.leafAttributes, colors_);
      return out;
    }

    // Slabs the children inherit: ours and our ancestors', each kept only where it still cuts the child.
    std::vector<geom::Slab> slabs = node.slabs;
    if (contour) slabs.push_back(slabOf(cube, contour->bits));
    std::vector<std::uint32_t> lists[8];
    for (std::uint32_t ti : node.triangles)
      for (std::uint8_t mask = overlappedChildren(triangles_[ti], cube); mask; mask &= std::uint8_t(mask - 1))
        lists[std::countr_zero(unsigned(mask))].push_back(ti);
    for (int slot = 0; slot < 8; ++slot) {
      if (lists[slot].empty()) continue;
      Node child;
      child.level = node.level + 1;
      child.coord = childCoordOf(node.coord, slot);
      child.triangles = std::move(lists[slot]);
      child.slabs = slabsCutting(slabs, cubeAt(child.level, child.coord));
      out.record.childMask |= std::uint8_t(1u << slot);
      out.children.push_back(std::move(child));
    }
    return out;
  }

  bool markDead(VoxelRecord& r, const Aggregate& sum) const {
    if (!markIfDead(r, sum)) return false;
    deadFound_ = true;
    return true;
  }

  // Depth-first into one vector: a voxel's children get consecutive records, then each child's subtree.
  Aggregate buildInto(Node& node, std::vector<VoxelRecord>& out, std::size_t self) const {
    Prepared p = prepare(node);
    release(node.triangles);  // free early: the children hold what they need
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
    if (!markDead(out[self], sum)) setAttributes(out[self], sum, colors_);
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
    release(node.triangles);
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
    if (!markDead(s.records[0], s.attributes)) setAttributes(s.records[0], s.attributes, colors_);
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

// The out-of-core voxelizer: the levels above the cell level are computed from two streaming passes over
// the source, cells are built one by one from their binned triangles. Equal to Voxelizer's tree: the same
// triangles reach each voxel in the same order, and the contour fit and the attributes see the same pieces.
class CellVoxelizer {
 public:
  CellVoxelizer(const TriangleSource& source, const SceneTransform& transform, const BuildOptions& options,
                int cellLevel, const CellCallbacks& callbacks)
      : source_(source),
        transform_(transform),
        options_(options),
        cellLevel_(cellLevel),
        callbacks_(callbacks),
        colors_(source.hasColor()),
        errorStop_(options.geometryError > 0.0f && options.contours) {}

  VoxelTree run(const std::filesystem::path& scratch, int concurrency) {
    CellPartition partition(scratch, source_.hasVertexColors(), source_.hasUvs(),
                            source_.materials().size() > 1);
    partition_ = &partition;
    nodes_.push_back(TopNode{});  // the root
    // 1. Bin every triangle into its cells, and gather the top voxels' contour candidates and sums.
    streamThroughTop("partition", [&](std::uint32_t node, const Triangle& t, std::uint32_t index,
                                      const SourceTriangle& s) {
      TopNode& n = nodes_[node];
      if (n.level == cellLevel_) {
        if (!n.done) partition.append(n.bucket, s);
        return;
      }
      if (!hasPieces(n)) return;
      const geom::Cube cube = cubeAt(n.level, n.coord);
      const Piece piece = clipPiece(t, index, cube);
      n.candidates.add(piece, t.normal, pieceWeight(piece, cube));
      if (errorStop_) {
        const std::optional<dvec4> color = colorOf(piece, t, s);
        accumulate(n.sums, pieceWeight(piece, cube), t.normal, color ? &*color : nullptr);
      }
    });
    partition.flush();
    // 2. Where the pieces lie along each candidate direction (and how far they spread from the sums).
    if (options_.contours && cellLevel_ > 1) {
      for (TopNode& n : nodes_)
        if (hasPieces(n)) n.directions = n.candidates.directions(), n.extents.resize(n.directions.size());
      streamThroughTop("contours", [&](std::uint32_t node, const Triangle& t, std::uint32_t index,
                                       const SourceTriangle& s) {
        TopNode& n = nodes_[node];
        if (!hasPieces(n)) return;
        const geom::Cube cube = cubeAt(n.level, n.coord);
        const Piece piece = clipPiece(t, index, cube);
        extendExtents(n.directions, piece, cube, n.extents);
        if (errorStop_) {
          const std::optional<dvec4> color = colorOf(piece, t, s);
          n.spread.add(n.sums, t.normal, color ? &*color : nullptr);
        }
      });
    }
    // 3. Contours and stops top down, which hands each cell the slabs of its ancestors.
    decide(0, {});
    if (callbacks_.planned) callbacks_.planned(cells_.size());
    // 4. The cells, `concurrency` at a time.
    std::atomic<std::size_t> next{0};
    std::mutex failedMutex;
    std::exception_ptr failed;  // the first error stops the rest and is rethrown here
    const auto work = [&] {
      try {
        for (std::size_t i; (i = next.fetch_add(1)) < cells_.size();) buildCell(cells_[i]);
      } catch (...) {
        std::lock_guard lock(failedMutex);
        if (!failed) failed = std::current_exception();
        next = cells_.size();
      }
    };
    {
      std::vector<std::jthread> workers;
      for (int t = 1; t < std::max(1, concurrency); ++t) workers.emplace_back(work);
      work();
    }
    if (failed) std::rethrow_exception(failed);

    // 5. The top's attributes from the cells' sums, bottom up in slot order as the in-core build adds them.
    VoxelTree tree;
    tree.hasColors = colors_;
    tree.hasNormals = true;
    tree.voxels.resize(1);
    const Aggregate all = assembleTop(0, tree.voxels, 0);
    if (all.weight == 0.0) throw std::runtime_error("mesh produced no voxels");
    tree.voxels = prune(tree.voxels);
    return tree;
  }

 private:
  // A voxel of the levels down to the cell level that some triangle overlaps.
  struct TopNode {
    int level = 0;
    glm::ivec3 coord{0};
    std::array<std::int32_t, 8> children{-1, -1, -1, -1, -1, -1, -1, -1};
    // Above the cells: the contour fit's and the error-driven stop's gatherings.
    ContourCandidates candidates;
    std::vector<Direction> directions;
    std::vector<Extent> extents;
    Aggregate sums;
    Spread spread;
    // Cells: where their triangles are binned, and the root of one an earlier run finished.
    std::uint32_t bucket = 0;
    std::optional<CellRoot> done;
  };
  // Decided: a voxel above the cells and its children (top voxels, or cells as ~index) in slot order.
  struct TopVoxel {
    VoxelRecord record;
    bool leaf = false;
    Aggregate leafAttributes;
    std::vector<std::int64_t> children;
  };
  struct Cell {
    glm::ivec3 coord;
    std::vector<geom::Slab> slabs;
    std::uint32_t bucket;
    bool done;  // by an earlier run: `root` is known
    CellRoot root;
  };

  bool hasPieces(const TopNode& n) const { return options_.contours && n.level > 0 && n.level < cellLevel_; }

  std::optional<dvec4> colorOf(const Piece& piece, const Triangle& t, const SourceTriangle& s) const {
    if (!colors_) return std::nullopt;
    return pieceColor(piece, t, source_.hasVertexColors() ? s.colors.data() : nullptr,
                      source_.hasUvs() ? s.uvs.data() : nullptr, materialAt(source_.materials(), s.material),
                      source_.textures());
  }

  // Streams the source once; every triangle visits the top voxels it overlaps, parents before children and
  // children in slot order, down to the cells (created as triangles reach them).
  template <class Visit>
  void streamThroughTop(const char* phase, Visit&& visit) {
    std::uint32_t index = 0;  // among the triangles not degenerate after the transform, as Voxelizer counts
    std::uint64_t read = 0;
    source_.read([&](std::span<const SourceTriangle> batch) {
      for (const SourceTriangle& s : batch)
        if (const std::optional<Triangle> t = makeTriangle(s.positions, transform_, index))
          descend(0, *t, index++, s, visit);
      read += batch.size();
      if (callbacks_.progress)
        callbacks_.progress(phase,
                            double(read) / double(std::max<std::uint64_t>(source_.triangleCount(), 1)));
    });
  }

  template <class Visit>
  void descend(std::uint32_t node, const Triangle& t, std::uint32_t index, const SourceTriangle& s,
               Visit& visit) {
    visit(node, t, index, s);
    const int level = nodes_[node].level;
    if (level == cellLevel_) return;
    const glm::ivec3 coord = nodes_[node].coord;
    for (std::uint8_t mask = overlappedChildren(t, cubeAt(level, coord)); mask;
         mask &= std::uint8_t(mask - 1)) {
      const int slot = std::countr_zero(unsigned(mask));
      std::int32_t child = nodes_[node].children[std::size_t(slot)];
      if (child < 0) {
        child = std::int32_t(nodes_.size());
        nodes_[node].children[std::size_t(slot)] = child;
        TopNode& c = nodes_.emplace_back();
        c.level = level + 1;
        c.coord = childCoordOf(coord, slot);
        if (c.level == cellLevel_) {
          c.bucket = partition_->addCell();
          if (callbacks_.finished) c.done = callbacks_.finished(c.coord);
        }
      }
      descend(std::uint32_t(child), t, index, s, visit);
    }
  }

  // Voxelizer::prepare for a top voxel, from the gathered candidates, extents and sums.
  std::size_t decide(std::uint32_t node, std::vector<geom::Slab> slabs) {
    const std::size_t self = top_.size();
    top_.emplace_back();
    const TopNode& n = nodes_[node];
    const geom::Cube cube = cubeAt(n.level, n.coord);
    VoxelRecord record;
    std::optional<ContourFit> contour;
    if (hasPieces(n))
      contour = chooseContour(cube, n.directions, n.extents, slabs, options_.innerContourMinReduction);
    if (contour) record.hasContour = true, record.contour = contour->bits;
    if (errorStop_ && contour && stopsRefining(options_, n.level, *contour, n.spread)) {
      setAttributes(record, n.sums, colors_);
      top_[self].record = record;
      top_[self].leaf = true;
      top_[self].leafAttributes = n.sums;
      return self;
    }
    if (contour) slabs.push_back(slabOf(cube, contour->bits));
    std::vector<std::int64_t> children;
    for (int slot = 0; slot < 8; ++slot) {
      const std::int32_t child = n.children[std::size_t(slot)];
      if (child < 0) continue;
      record.childMask |= std::uint8_t(1u << slot);
      const TopNode& c = nodes_[std::size_t(child)];
      std::vector<geom::Slab> childSlabs = slabsCutting(slabs, cubeAt(c.level, c.coord));
      if (c.level == cellLevel_) {
        children.push_back(~std::int64_t(cells_.size()));
        cells_.push_back(
            {c.coord, std::move(childSlabs), c.bucket, c.done.has_value(), c.done.value_or(CellRoot{})});
      } else {
        children.push_back(std::int64_t(decide(std::uint32_t(child), std::move(childSlabs))));
      }
    }
    top_[self].record = record;
    top_[self].children = std::move(children);
    return self;
  }

  void buildCell(Cell& cell) const {
    if (cell.done) return;
    // The cell's triangles as a mesh of their own: three corners each, in input order.
    Mesh mesh;
    {
      const std::vector<SourceTriangle> binned = partition_->read(cell.bucket);
      mesh.positions.reserve(3 * binned.size());
      mesh.triangles.reserve(binned.size());
      if (source_.hasVertexColors()) mesh.colors.reserve(3 * binned.size());
      if (source_.hasUvs()) mesh.uvs.reserve(3 * binned.size());
      for (const SourceTriangle& s : binned) {
        const std::uint32_t base = std::uint32_t(mesh.positions.size());
        mesh.triangles.emplace_back(base, base + 1, base + 2);
        mesh.positions.insert(mesh.positions.end(), s.positions.begin(), s.positions.end());
        if (source_.hasVertexColors())
          mesh.colors.insert(mesh.colors.end(), s.colors.begin(), s.colors.end());
        if (source_.hasUvs()) mesh.uvs.insert(mesh.uvs.end(), s.uvs.begin(), s.uvs.end());
        if (source_.materials().size() > 1) mesh.triangleMaterials.push_back(s.material);
      }
    }
    partition_->remove(cell.bucket);
    mesh.materials = source_.materials();
    mesh.textures = source_.textures();
    Aggregate sums;
    VoxelTree tree =
        Voxelizer(mesh, transform_, options_, colors_).runCell(cellLevel_, cell.coord, cell.slabs, sums);
    mesh = Mesh{};
    cell.root = {tree.voxels[0], {sums.weight, sums.color, sums.normal}};
    callbacks_.built(cell.coord, std::move(tree), cell.root);
  }

  // Writes top voxel `t` at out[self] and its children's records after it, depth first like buildInto;
  // cells become leaves carrying their roots' contour and attributes. Returns the voxel's sums.
  Aggregate assembleTop(std::size_t t, std::vector<VoxelRecord>& out, std::size_t self) const {
    const TopVoxel& v = top_[t];
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
        sum.add(assembleTop(std::size_t(c), out, first + k));
        continue;
      }
      const CellRoot& cell = cells_[std::size_t(~c)].root;
      VoxelRecord leaf = cell.record;
      leaf.childMask = 0;
      leaf.firstChild = cell.sums.weight == 0.0 ? kDeadVoxel : 0;  // a cell whose voxels all died is pruned
      out[first + k] = leaf;
      sum.add(Aggregate{cell.sums.weight, cell.sums.color, cell.sums.normal});
    }
    if (!markIfDead(out[self], sum)) setAttributes(out[self], sum, colors_);
    return sum;
  }

  const TriangleSource& source_;
  const SceneTransform transform_;
  const BuildOptions& options_;
  const int cellLevel_;
  const CellCallbacks& callbacks_;
  const bool colors_, errorStop_;
  std::vector<TopNode> nodes_;
  CellPartition* partition_ = nullptr;  // during run()
  std::vector<TopVoxel> top_;
  std::vector<Cell> cells_;
};

}  // namespace

SceneTransform fitSceneCube(glm::dvec3 lower, glm::dvec3 upper) {
  const double extent = std::max({upper.x - lower.x, upper.y - lower.y, upper.z - lower.z});
  if (!(extent > 0.0)) throw std::runtime_error("mesh has no extent: all vertices coincide");
  SceneTransform t;
  t.size = extent * (1.0 + 2.0 * kSceneMargin);
  t.origin = 0.5 * (lower + upper) - 0.5 * t.size;
  return t;
}

SceneTransform fitSceneCube(const Mesh& mesh) {
  if (mesh.triangles.empty()) throw std::runtime_error("mesh has no triangles");
  dvec3 lo(1e308), hi(-1e308);
  for (const glm::uvec3& t : mesh.triangles)
    for (int k = 0; k < 3; ++k)
      lo = glm::min(lo, mesh.positions[t[k]]), hi = glm::max(hi, mesh.positions[t[k]]);
  return fitSceneCube(lo, hi);
}

VoxelTree voxelize(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options,
                   BuildStats* stats) {
  checkLevels(options);
  const auto start = std::chrono::steady_clock::now();
  VoxelTree tree = Voxelizer(mesh, transform, options, mesh.hasColor()).run(stats);
  if (stats) stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return tree;
}

VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        int concurrency, const std::filesystem::path& scratch) {
  checkLevels(options);
  if (cellLevel < 1 || cellLevel >= options.levels)
    throw std::invalid_argument("cell level must be in [1, levels - 1] = [1, " +
                                std::to_string(options.levels - 1) + "], got " + std::to_string(cellLevel));
  if (!callbacks.built) throw std::invalid_argument("voxelizeCells: no callback for built cells");
  return CellVoxelizer(source, transform, options, cellLevel, callbacks).run(scratch, concurrency);
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
  octree.parameters = storedParameters(options);
  const VoxelTree tree = voxelize(mesh, octree.transform, options, stats);
  octree.block = layoutBlock(tree, options.layout, stats ? &stats->layout : nullptr);
  if (stats) stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return octree;
}

}  // namespace svo
