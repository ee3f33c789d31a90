// The in-core voxelizer (top-down, paper sec. 5.2-5.4 for contours and attributes); the out-of-core build
// runs it once per cell.
#pragma once

#include <atomic>
#include <exception>
#include <mutex>

#include <tbb/parallel_for.h>

#include "voxel_kernels.hpp"

namespace svo::voxel {

// Levels above this run their children as parallel tasks (8^3 = 512 subtrees keep 2-64 cores busy).
constexpr int kParallelDepth = 3;

// The in-core voxelizer: every triangle of `mesh` in memory. The out-of-core build runs one per cell, over
// the cell's triangles.
class Voxelizer {
 public:
  Voxelizer(const Mesh& mesh, const SceneTransform& transform, const BuildOptions& options, bool colors)
      : mesh_(mesh), corners_(cornerNormals(mesh)), options_(options), colors_(colors) {
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
    std::vector<dvec3> normals(spread ? pieces.size() : 0);  // kept for the spread's second pass only
    for (std::size_t i = 0; i < pieces.size(); ++i) {
      const Triangle& t = triangles_[pieces[i].triangle];
      if (colors_) colors[i] = colorOf(pieces[i]);
      const dvec3 normal = pieceNormal(pieces[i], t, corners_[t.source]);
      if (spread) normals[i] = normal;
      accumulate(a, pieceWeight(pieces[i], cube), normal, colors_ ? &colors[i] : nullptr);
    }
    if (spread)
      for (std::size_t i = 0; i < pieces.size(); ++i)
        spread->add(a, normals[i], colors_ ? &colors[i] : nullptr);
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
  const std::vector<std::array<glm::vec3, 3>> corners_;  // shading normals by source triangle
  const BuildOptions& options_;
  const bool colors_;
  std::vector<Triangle> triangles_;
  mutable std::atomic<double> done_{0.0};
  mutable std::atomic<bool> deadFound_{false};
};

}  // namespace svo::voxel
