// The out-of-core voxelizer. One pass over the source bins each triangle into the cells it overlaps and into
// the octants below the root it overlaps; two passes over each octant's triangles gather the contour
// candidates, extents and attribute sums of the levels above the cells; the top is decided from those, and
// each cell is voxelized from its binned triangles. The processes of a job share the pass over the source
// (each reads and bins only its share of the triangles) and the octants (each gathers some), then rank 0
// decides the top.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <map>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <tuple>

#include "cell_voxelizer.hpp"
#include "process_messages.hpp"
#include "voxelizer.hpp"

namespace svo {
namespace {

using namespace voxel;

// Triangles between two progress reports of the octants' passes.
constexpr std::uint64_t kProgressEvery = 1 << 16;

std::filesystem::path rankFolder(const std::filesystem::path& scratch, int rank) {
  return scratch / ("rank-" + std::to_string(rank));
}
std::filesystem::path cellsFolder(const std::filesystem::path& scratch, int rank) {
  return rankFolder(scratch, rank) / "cells";
}
std::filesystem::path octantsFolder(const std::filesystem::path& scratch, int rank) {
  return rankFolder(scratch, rank) / "octants";
}

// A voxel above the cells, or a cell, by level and coordinates.
using NodeKey = std::tuple<int, int, int, int>;
NodeKey keyOf(int level, glm::ivec3 coord) {
  return {level, coord.x, coord.y, coord.z};
}

// What a process's pass over its share of the input found: the voxels above the cells its triangles reach,
// the cells with where it binned them, and its triangles per octant.
struct BinnedCell {
  std::int32_t coord[3];
  std::uint32_t bucket;
  std::uint64_t triangles;
};
struct TopVisit {
  std::int32_t level, coord[3];
};
// A voxel the pass over the input reached: above the cells, or a cell with where its triangles went.
struct BinNode {
  int level = 0;
  glm::ivec3 coord{0};
  std::array<std::int32_t, 8> children{-1, -1, -1, -1, -1, -1, -1, -1};
  std::uint32_t bucket = 0;
  std::uint64_t triangles = 0;
};
// A gathered voxel above the cells: what deciding its contour and stop needs.
struct GatheredHeader {
  std::int32_t level, coord[3];
  Aggregate sums;
  Spread spread;
};

// Node `node`'s child in `slot`, created when missing; and whether it was.
template <class Node>
std::pair<std::uint32_t, bool> childNode(std::vector<Node>& nodes, std::uint32_t node, int slot) {
  const std::int32_t child = nodes[node].children[std::size_t(slot)];
  if (child >= 0) return {std::uint32_t(child), false};
  const auto created = std::uint32_t(nodes.size());
  nodes[node].children[std::size_t(slot)] = std::int32_t(created);
  Node& c = nodes.emplace_back();
  c.level = nodes[node].level + 1;
  c.coord = childCoordOf(nodes[node].coord, slot);
  return {created, true};
}

// The out-of-core voxelizer of one process (see the top of this file). Equal to Voxelizer's tree: the same
// triangles reach each voxel in the same order, and the contour fit and the attributes see the same pieces.
class CellVoxelizer {
 public:
  CellVoxelizer(const TriangleSource& source, const SceneTransform& transform, const BuildOptions& options,
                int cellLevel, const CellCallbacks& callbacks, const TopSharing& sharing,
                std::filesystem::path scratch)
      : source_(source),
        transform_(transform),
        options_(options),
        cellLevel_(cellLevel),
        callbacks_(callbacks),
        sharing_(sharing),
        scratch_(std::move(scratch)),
        colors_(source.hasColor()),
        errorStop_(options.geometryError > 0.0f && options.contours) {}

  // Every process: its share binned and its octants gathered, the results exchanged; rank 0 keeps them all
  // as its top nodes. Returns false where the job failed (rank 0 throws why).
  bool share() {
    const std::vector<std::string> binned = exchange([&] { return bin(); });
    if (binned.empty()) return false;
    std::vector<std::array<std::uint64_t, 8>> octantTriangles;
    for (const std::string& m : binned) {
      MessageReader in(m);
      octantTriangles.push_back(in.get<std::array<std::uint64_t, 8>>());
    }
    const std::vector<std::string> gathered = exchange([&] { return gatherOctants(octantTriangles); });
    if (gathered.empty()) return false;
    if (sharing_.rank == 0) merge(binned, gathered);
    return true;
  }

  // Rank 0, after share(): the top decided, the cells built by `runner`, the top's attributes from theirs.
  VoxelTree run(const CellRunner& runner) {
    // 3. Contours and stops top down, which hands each cell the slabs of its ancestors.
    decide(0, {});
    if (callbacks_.planned) callbacks_.planned(cells_.size());
    // 4. The cells an earlier run did not finish, largest first so that none is left to the end alone.
    std::vector<std::size_t> cellOf;
    for (std::size_t i = 0; i < cells_.size(); ++i)
      if (!cells_[i].done) cellOf.push_back(i);
    std::stable_sort(cellOf.begin(), cellOf.end(),
                     [&](std::size_t a, std::size_t b) { return cells_[a].triangles > cells_[b].triangles; });
    CellJobs jobs;
    jobs.cellLevel = cellLevel_;
    for (const std::size_t i : cellOf)
      jobs.tasks.push_back(
          {cells_[i].coord, std::move(cells_[i].slabs), cells_[i].parts, cells_[i].triangles});
    const BinnedTriangles binned(scratch_, sharing_.ranks, source_);
    jobs.buildHere = [&](std::size_t t) {
      CellRoot root;
      VoxelTree tree = buildCell(source_, transform_, options_, cellLevel_, binned, jobs.tasks[t], root);
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
    std::vector<CellPart> parts;
    std::uint64_t triangles = 0;
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
    std::vector<CellPart> parts;
    std::uint64_t triangles;
    bool done;  // by an earlier run: `root` is known
    CellRoot root;
  };

  bool hasPieces(int level) const { return options_.contours && level > 0 && level < cellLevel_; }
  bool gathersOctants() const { return options_.contours && cellLevel_ > 1; }

  std::optional<dvec4> colorOf(const Piece& piece, const Triangle& t, const SourceTriangle& s) const {
    if (!colors_) return std::nullopt;
    return pieceColor(piece, t, source_.hasVertexColors() ? s.colors.data() : nullptr,
                      source_.hasUvs() ? s.uvs.data() : nullptr, materialAt(source_.materials(), s.material),
                      source_.textures());
  }

  void progress(const char* phase, double fraction) const {
    if (callbacks_.progress) callbacks_.progress(phase, fraction);
  }

  // Runs `work` (this process's message) and exchanges the messages, each led by its process's failure
  // (empty: none). Alone, a failure is simply thrown. Returns nothing when some process failed: rank 0
  // throws its own failure as it is, or the first other's, naming the process.
  std::vector<std::string> exchange(const std::function<std::string()>& work) {
    if (sharing_.ranks == 1) return {work()};
    std::string message;
    std::exception_ptr failure;
    std::string why;
    try {
      message = work();
    } catch (const std::exception& e) {
      failure = std::current_exception();
      why = e.what();
    }
    MessageWriter out;
    out.putAll(std::vector<char>(why.begin(), why.end()));
    std::vector<std::string> all = sharing_.exchange(out.take() + message);
    std::string first;
    for (std::size_t r = 0; r < all.size() && first.empty(); ++r) {
      MessageReader in(all[r]);
      const std::vector<char> error = in.getAll<char>();
      if (!error.empty()) first = sharing_.describe(int(r)) + ": " + std::string(error.begin(), error.end());
      all[r].erase(0, sizeof(std::uint64_t) + error.size());
    }
    if (first.empty()) return all;
    if (sharing_.rank == 0) {
      if (failure) std::rethrow_exception(failure);
      throw std::runtime_error(first);
    }
    return {};
  }

  // 1. This process's share of the triangles, in input order, binned into the cells and octants they
  // overlap (the voxels above the cells they reach are recorded). Its message: triangles per octant, the
  // voxels reached, the cells binned.
  std::string bin() {
    CellPartition cells(cellsFolder(scratch_, sharing_.rank), source_.hasVertexColors(), source_.hasUvs(),
                        source_.materials().size() > 1);
    std::optional<CellPartition> octants;
    if (gathersOctants()) {
      octants.emplace(octantsFolder(scratch_, sharing_.rank), source_.hasVertexColors(), source_.hasUvs(),
                      source_.materials().size() > 1, true);
      for (int slot = 0; slot < 8; ++slot) octants->addCell();
    }
    std::array<std::uint64_t, 8> octantTriangles{};
    std::vector<BinNode> nodes(1);  // the root
    const std::uint64_t total = source_.triangleCount();
    const std::uint64_t first = total * std::uint64_t(sharing_.rank) / std::uint64_t(sharing_.ranks);
    const std::uint64_t last = total * std::uint64_t(sharing_.rank + 1) / std::uint64_t(sharing_.ranks);
    // Down the voxels a triangle overlaps, parents before children and children in slot order.
    const auto binDown = [&](const auto& self, std::uint32_t node, const Triangle& t,
                             const SourceTriangle& s) -> void {
      const int level = nodes[node].level;
      const glm::ivec3 coord = nodes[node].coord;
      for (std::uint8_t mask = overlappedChildren(t, cubeAt(level, coord)); mask;
           mask &= std::uint8_t(mask - 1)) {
        const int slot = std::countr_zero(unsigned(mask));
        const auto [child, created] = childNode(nodes, node, slot);
        BinNode& c = nodes[child];
        if (created && c.level == cellLevel_) c.bucket = cells.addCell();
        if (c.level == cellLevel_) {
          cells.append(c.bucket, s);
          ++c.triangles;
          continue;
        }
        if (level == 0 && octants)
          octants->append(std::uint32_t(slot), s, t.source), ++octantTriangles[std::size_t(slot)];
        self(self, child, t, s);
      }
    };
    std::uint64_t ordinal = first;
    source_.readRange(first, last, [&](std::span<const SourceTriangle> batch) {
      for (const SourceTriangle& s : batch) {
        const std::uint64_t at = ordinal++;
        // Ordered by their place in the input, as Voxelizer orders them (ties between equal pieces).
        if (const std::optional<Triangle> t = makeTriangle(s.positions, transform_, std::uint32_t(at)))
          binDown(binDown, 0, *t, s);
      }
      progress("partition", double(ordinal - first) / double(std::max<std::uint64_t>(last - first, 1)));
    });
    cells.flush();
    cells.keep();  // read by whichever process builds each cell; the scratch folder goes with the build
    if (octants) octants->flush(), octants->keep();
    MessageWriter out;
    out.put(octantTriangles);
    std::vector<TopVisit> visits;
    std::vector<BinnedCell> binned;
    for (const BinNode& n : nodes) {
      if (n.level == cellLevel_)
        binned.push_back({{n.coord.x, n.coord.y, n.coord.z}, n.bucket, n.triangles});
      else if (n.level > 0)
        visits.push_back({n.level, {n.coord.x, n.coord.y, n.coord.z}});
    }
    out.putAll(visits);
    out.putAll(binned);
    return out.take();
  }
  // Visits the top voxels a triangle overlaps below `node`, parents before children and children in slot
  // order, down to the level above the cells (creating them as triangles reach them).
  template <class Visit>
  void gatherDown(std::vector<TopNode>& nodes, std::uint32_t node, const Triangle& t, const SourceTriangle& s,
                  Visit& visit) const {
    visit(nodes[node], t, s);
    const int level = nodes[node].level;
    if (level + 1 == cellLevel_) return;
    const glm::ivec3 coord = nodes[node].coord;
    for (std::uint8_t mask = overlappedChildren(t, cubeAt(level, coord)); mask;
         mask &= std::uint8_t(mask - 1)) {
      const int slot = std::countr_zero(unsigned(mask));
      gatherDown(nodes, childNode(nodes, node, slot).first, t, s, visit);
    }
  }

  // 2. The octants this process gathers (the i-th octant any triangle overlaps goes to process i mod ranks),
  // from every process's triangles there in rank order, which is input order: the contour candidates and
  // sums of its voxels above the cells, then where the pieces lie along each candidate. Its message: per
  // voxel its sums, spread, directions and extents.
  std::string gatherOctants(const std::vector<std::array<std::uint64_t, 8>>& octantTriangles) {
    MessageWriter out;
    if (!gathersOctants()) return out.take();
    std::vector<int> mine;
    std::uint64_t toRead = 0, read = 0;
    for (int slot = 0, present = 0; slot < 8; ++slot) {
      std::uint64_t triangles = 0;
      for (const auto& counts : octantTriangles) triangles += counts[std::size_t(slot)];
      if (triangles > 0 && present++ % sharing_.ranks == sharing_.rank)
        mine.push_back(slot), toRead += 2 * triangles;
    }
    std::vector<CellPartition> octants;
    for (int r = 0; r < sharing_.ranks; ++r)
      octants.push_back(CellPartition::attach(octantsFolder(scratch_, r), source_.hasVertexColors(),
                                              source_.hasUvs(), source_.materials().size() > 1, true));
    for (const int slot : mine) {
      std::vector<TopNode> nodes(1);
      nodes[0].level = 1;
      nodes[0].coord = childCoordOf(glm::ivec3(0), slot);
      const auto stream = [&](auto&& visit) {
        for (int r = 0; r < sharing_.ranks; ++r) {
          if (octantTriangles[std::size_t(r)][std::size_t(slot)] == 0) continue;
          octants[std::size_t(r)].forEach(
              std::uint32_t(slot), [&](const SourceTriangle& s, std::uint32_t order) {
                const std::optional<Triangle> t = makeTriangle(s.positions, transform_, order);
                if (!t) throw std::logic_error("voxelizeCells: a binned triangle became degenerate");
                gatherDown(nodes, 0, *t, s, visit);
                if (++read % kProgressEvery == 0) progress("contours", double(read) / double(toRead));
              });
        }
      };
      stream([&](TopNode& n, const Triangle& t, const SourceTriangle& s) {
        const geom::Cube cube = cubeAt(n.level, n.coord);
        const Piece piece = clipPiece(t, t.source, cube);
        n.candidates.add(piece, t.normal, pieceWeight(piece, cube));
        if (errorStop_) {
          const std::optional<dvec4> color = colorOf(piece, t, s);
          accumulate(n.sums, pieceWeight(piece, cube), pieceNormal(piece, t, s.normals),
                     color ? &*color : nullptr);
        }
      });
      for (TopNode& n : nodes)
        n.directions = n.candidates.directions(), n.extents.resize(n.directions.size());
      stream([&](TopNode& n, const Triangle& t, const SourceTriangle& s) {
        const geom::Cube cube = cubeAt(n.level, n.coord);
        const Piece piece = clipPiece(t, t.source, cube);
        extendExtents(n.directions, piece, cube, n.extents);
        if (errorStop_) {
          const std::optional<dvec4> color = colorOf(piece, t, s);
          n.spread.add(n.sums, pieceNormal(piece, t, s.normals), color ? &*color : nullptr);
        }
      });
      for (const TopNode& n : nodes) {
        out.put(GatheredHeader{n.level, {n.coord.x, n.coord.y, n.coord.z}, n.sums, n.spread});
        out.putAll(n.directions);
        out.putAll(n.extents);
      }
    }
    progress("contours", 1.0);
    return out.take();
  }

  // Rank 0: the top nodes from every process's messages, the cells with their parts in rank order.
  void merge(const std::vector<std::string>& binned, const std::vector<std::string>& gathered) {
    std::map<NodeKey, std::uint32_t> nodeOf;
    std::map<NodeKey, std::vector<std::pair<int, BinnedCell>>> cells;
    for (std::size_t r = 0; r < binned.size(); ++r) {
      MessageReader in(binned[r]);
      in.get<std::array<std::uint64_t, 8>>();
      for (const TopVisit& v : in.getAll<TopVisit>())
        nodeOf[keyOf(v.level, {v.coord[0], v.coord[1], v.coord[2]})];
      for (const BinnedCell& c : in.getAll<BinnedCell>())
        cells[keyOf(cellLevel_, {c.coord[0], c.coord[1], c.coord[2]})].push_back({int(r), c});
    }
    nodes_.assign(1, TopNode{});  // the root
    nodeOf[keyOf(0, glm::ivec3(0))] = 0;
    // A node below an existing parent (keys come parents first: by level).
    const auto link = [&](const NodeKey& key) -> TopNode& {
      const auto [level, x, y, z] = key;
      const glm::ivec3 coord(x, y, z);
      const std::uint32_t parent = nodeOf.at(keyOf(level - 1, coord >> 1));
      const std::uint32_t self = std::uint32_t(nodes_.size());
      nodes_[parent].children[std::size_t(childSlot(coord))] = std::int32_t(self);
      nodeOf[key] = self;
      TopNode& n = nodes_.emplace_back();
      n.level = level, n.coord = coord;
      return n;
    };
    for (auto& [key, index] : nodeOf)
      if (std::get<0>(key) > 0) link(key);
    for (const auto& [key, parts] : cells) {
      TopNode& cell = link(key);
      for (const auto& [rank, c] : parts) {
        cell.parts.push_back({rank, c.bucket});
        cell.triangles += c.triangles;
      }
      if (callbacks_.finished) cell.done = callbacks_.finished(cell.coord);
    }
    for (const std::string& m : gathered) {
      MessageReader in(m);
      while (!in.done()) {
        const auto header = in.get<GatheredHeader>();
        TopNode& n =
            nodes_[nodeOf.at(keyOf(header.level, {header.coord[0], header.coord[1], header.coord[2]}))];
        n.sums = header.sums, n.spread = header.spread;
        n.directions = in.getAll<Direction>();
        n.extents = in.getAll<Extent>();
      }
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
    if (hasPieces(n.level))
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
        cells_.push_back({c.coord, std::move(childSlabs), c.parts, c.triangles, c.done.has_value(),
                          c.done.value_or(CellRoot{})});
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
  const TopSharing& sharing_;
  const std::filesystem::path scratch_;
  const bool colors_, errorStop_;
  std::vector<TopNode> nodes_;
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

BinnedTriangles::BinnedTriangles(const std::filesystem::path& scratch, int ranks,
                                 const TriangleSource& source) {
  for (int r = 0; r < ranks; ++r)
    partitions_.push_back(CellPartition::attach(cellsFolder(scratch, r), source.hasVertexColors(),
                                                source.hasUvs(), source.materials().size() > 1));
}

std::vector<SourceTriangle> BinnedTriangles::take(const CellTask& task) const {
  std::vector<SourceTriangle> out;
  out.reserve(task.triangles);
  for (const CellPart& part : task.parts) {
    const CellPartition& partition = partitions_.at(std::size_t(part.rank));
    partition.forEach(part.bucket, [&](const SourceTriangle& t, std::uint32_t) { out.push_back(t); });
    partition.remove(part.bucket);
  }
  return out;
}

VoxelTree buildCell(const TriangleSource& source, const SceneTransform& transform,
                    const BuildOptions& options, int cellLevel, const BinnedTriangles& binned,
                    const CellTask& task, CellRoot& root) {
  // The cell's triangles as a mesh of their own: three corners each, in input order.
  Mesh mesh;
  {
    const std::vector<SourceTriangle> triangles = binned.take(task);
    mesh.positions.reserve(3 * triangles.size());
    mesh.triangles.reserve(triangles.size());
    mesh.normals.reserve(3 * triangles.size());
    if (source.hasVertexColors()) mesh.colors.reserve(3 * triangles.size());
    if (source.hasUvs()) mesh.uvs.reserve(3 * triangles.size());
    for (const SourceTriangle& s : triangles) {
      const std::uint32_t base = std::uint32_t(mesh.positions.size());
      mesh.triangles.emplace_back(base, base + 1, base + 2);
      mesh.positions.insert(mesh.positions.end(), s.positions.begin(), s.positions.end());
      mesh.normals.insert(mesh.normals.end(), s.normals.begin(), s.normals.end());
      if (source.hasVertexColors()) mesh.colors.insert(mesh.colors.end(), s.colors.begin(), s.colors.end());
      if (source.hasUvs()) mesh.uvs.insert(mesh.uvs.end(), s.uvs.begin(), s.uvs.end());
      if (source.materials().size() > 1) mesh.triangleMaterials.push_back(s.material);
    }
  }
  mesh.materials = source.materials();
  mesh.textures = source.textures();
  voxel::Aggregate sums;
  VoxelTree tree = voxel::Voxelizer(mesh, transform, options, source.hasColor())
                       .runCell(cellLevel, task.coord, task.slabs, sums);
  root = {tree.voxels[0], {sums.weight, sums.color, sums.normal}};
  return tree;
}

namespace {

void checkCellLevel(const BuildOptions& options, int cellLevel) {
  checkLevels(options);
  if (cellLevel < 1 || cellLevel >= options.levels)
    throw std::invalid_argument("cell level must be in [1, levels - 1] = [1, " +
                                std::to_string(options.levels - 1) + "], got " + std::to_string(cellLevel));
}

}  // namespace

VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        int concurrency, const std::filesystem::path& scratch) {
  return voxelizeCells(source, transform, options, cellLevel, callbacks, localCellRunner(concurrency),
                       scratch);
}

VoxelTree voxelizeCells(const TriangleSource& source, const SceneTransform& transform,
                        const BuildOptions& options, int cellLevel, const CellCallbacks& callbacks,
                        const CellRunner& runner, const std::filesystem::path& scratch,
                        const TopSharing& sharing) {
  checkCellLevel(options, cellLevel);
  if (!callbacks.built) throw std::invalid_argument("voxelizeCells: no callback for built cells");
  // Each process's partitions go with the build, whatever its outcome (a resume bins the input again).
  std::filesystem::remove_all(scratch);
  std::filesystem::create_directories(scratch);
  struct RemoveScratch {
    const std::filesystem::path& scratch;
    ~RemoveScratch() {
      std::error_code ignored;
      std::filesystem::remove_all(scratch, ignored);
    }
  } removeScratch{scratch};
  if (sharing.start) sharing.start(cellLevel);
  CellVoxelizer voxelizer(source, transform, options, cellLevel, callbacks, sharing, scratch);
  voxelizer.share();  // rank 0 throws where the job failed
  return voxelizer.run(runner);
}

bool shareTopLevels(const TriangleSource& source, const SceneTransform& transform,
                    const BuildOptions& options, int cellLevel, const std::filesystem::path& scratch,
                    const TopSharing& sharing) {
  checkCellLevel(options, cellLevel);
  return CellVoxelizer(source, transform, options, cellLevel, {}, sharing, scratch).share();
}

}  // namespace svo
