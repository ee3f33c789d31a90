// The out-of-core voxelizer: two streaming passes over a triangle source build the levels above the cell
// level; each cell is then voxelized from its binned triangles.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>

#include "cell_voxelizer.hpp"
#include "voxelizer.hpp"

namespace svo {
namespace {

using namespace voxel;

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

  VoxelTree run(const std::filesystem::path& scratch, const CellRunner& runner) {
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
    // 4. The cells an earlier run did not finish, largest first so that none is left to the end alone.
    std::vector<std::size_t> cellOf;
    for (std::size_t i = 0; i < cells_.size(); ++i)
      if (!cells_[i].done) cellOf.push_back(i);
    std::stable_sort(cellOf.begin(), cellOf.end(), [&](std::size_t a, std::size_t b) {
      return partition.trianglesIn(cells_[a].bucket) > partition.trianglesIn(cells_[b].bucket);
    });
    CellJobs jobs;
    jobs.cellLevel = cellLevel_;
    for (const std::size_t i : cellOf)
      jobs.tasks.push_back({cells_[i].coord, std::move(cells_[i].slabs), cells_[i].bucket,
                            partition.trianglesIn(cells_[i].bucket)});
    jobs.buildHere = [&](std::size_t t) {
      CellRoot root;
      VoxelTree tree = buildCell(source_, transform_, options_, cellLevel_, partition, jobs.tasks[t], root);
      callbacks_.built(jobs.tasks[t].coord, std::move(tree), root);
      return root;
    };
    jobs.builtElsewhere = callbacks_.builtElsewhere;
    const std::vector<CellRoot> roots = runner(jobs);
    if (roots.size() != cellOf.size()) throw std::logic_error("voxelizeCells: a cell runner lost cells");
    for (std::size_t k = 0; k < cellOf.size(); ++k) cells_[cellOf[k]].root = roots[k];

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

CellRunner localCellRunner(int concurrency) {
  return [concurrency](const CellJobs& jobs) {
    std::vector<CellRoot> roots(jobs.tasks.size());
    std::atomic<std::size_t> next{0};
    std::mutex failedMutex;
    std::exception_ptr failed;  // the first error stops the rest and is rethrown here
    const auto work = [&] {
      try {
        for (std::size_t i; (i = next.fetch_add(1)) < roots.size();) roots[i] = jobs.buildHere(i);
      } catch (...) {
        std::lock_guard lock(failedMutex);
        if (!failed) failed = std::current_exception();
        next = roots.size();
      }
    };
    {
      std::vector<std::jthread> workers;
      for (int t = 1; t < std::max(1, concurrency); ++t) workers.emplace_back(work);
      work();
    }
    if (failed) std::rethrow_exception(failed);
    return roots;
  };
}

VoxelTree buildCell(const TriangleSource& source, const SceneTransform& transform, const BuildOptions& options,
                    int cellLevel, CellPartition& partition, const CellTask& task, CellRoot& root) {
  // The cell's triangles as a mesh of their own: three corners each, in input order.
  Mesh mesh;
  {
    const std::vector<SourceTriangle> binned = partition.read(task.bucket);
    mesh.positions.reserve(3 * binned.size());
    mesh.triangles.reserve(binned.size());
    if (source.hasVertexColors()) mesh.colors.reserve(3 * binned.size());
    if (source.hasUvs()) mesh.uvs.reserve(3 * binned.size());
    for (const SourceTriangle& s : binned) {
      const std::uint32_t base = std::uint32_t(mesh.positions.size());
      mesh.triangles.emplace_back(base, base + 1, base + 2);
      mesh.positions.insert(mesh.positions.end(), s.positions.begin(), s.positions.end());
      if (source.hasVertexColors()) mesh.colors.insert(mesh.colors.end(), s.colors.begin(), s.colors.end());
      if (source.hasUvs()) mesh.uvs.insert(mesh.uvs.end(), s.uvs.begin(), s.uvs.end());
      if (source.materials().size() > 1) mesh.triangleMaterials.push_back(s.material);
    }
  }
  partition.remove(task.bucket);
  mesh.materials = source.materials();
  mesh.textures = source.textures();
  voxel::Aggregate sums;
  VoxelTree tree =
      voxel::Voxelizer(mesh, transform, options, source.hasColor()).runCell(cellLevel, task.coord, task.slabs, sums);
  root = {tree.voxels[0], {sums.weight, sums.color, sums.normal}};
  return tree;
}

VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        int concurrency, const std::filesystem::path& scratch) {
  return voxelizeCells(source, transform, options, cellLevel, callbacks, localCellRunner(concurrency), scratch);
}

VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        const CellRunner& runner, const std::filesystem::path& scratch) {
  checkLevels(options);
  if (cellLevel < 1 || cellLevel >= options.levels)
    throw std::invalid_argument("cell level must be in [1, levels - 1] = [1, " +
                                std::to_string(options.levels - 1) + "], got " + std::to_string(cellLevel));
  if (!callbacks.built) throw std::invalid_argument("voxelizeCells: no callback for built cells");
  return CellVoxelizer(source, transform, options, cellLevel, callbacks).run(scratch, runner);
}

}  // namespace svo
