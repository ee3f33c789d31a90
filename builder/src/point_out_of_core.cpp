// The out-of-core scan build (points.hpp, buildPointStore): the points streamed from the file in batches,
// binned per cell with a halo of their neighbours' points, normals estimated cell by cell, the levels above
// the cells made from the cells' sums, each cell's subtree built and spilled (cell_spill.hpp), then the
// store written as the mesh's out-of-core build writes it (StoreFileWriter::appendForest).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <fstream>
#include <functional>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <vector>

#include <glm/common.hpp>
#include <nlohmann/json.hpp>

#include "cell_spill.hpp"
#include "hasher.hpp"
#include "out_of_core.hpp"
#include "point_bins.hpp"
#include "point_voxelize.hpp"
#include "svo/builder/points.hpp"

namespace svo {
namespace {

using detail::BinnedPoint;
using detail::HaloPoint;
using detail::PointBins;
using detail::PointBounds;
using detail::PointExtent;
using detail::PointNode;

// Resident bytes per point of the cell being built, at its peak (normal estimation: the points, their 16
// neighbours each, the neighbour graph and its spanning tree; then the sorted points, nodes and levels).
// Measured: svo build's peak less the program's (147 MiB) per point of a 2M-point sphere in core, 12
// levels (0.85 GiB): 380 B; rounded up.
constexpr double kBytesPerCellPoint = 420.0;
// Besides the cells: the bins' buffers (64 MiB, point_bins.cpp), the level-9 histogram and the top levels.
constexpr double kFixedBytes = 96.0 * (1 << 20);
// The level whose cells the histogram counts points in, and so the deepest cell level: 2^9 cells a side
// is far past any memory bound's need (as the mesh build's kDeepestChosenCellLevel).
constexpr int kHistogramLevel = 9;
// The halo's width in point spacings: a point's 16 nearest neighbours lie within 2.3 spacings on an even
// surface; three times that covers density varying by a factor of 9 across a cell border.
constexpr double kHaloSpacings = 7.0;
// How long a build runs before it shows progress bars.
constexpr std::chrono::milliseconds kQuietStart{500};
// Work-folder format; a resume refuses a folder of another format.
constexpr int kWorkFormat = 1;

std::uint64_t keyOf(glm::ivec3 c) {
  return (std::uint64_t(c.z) << 42) | (std::uint64_t(c.y) << 21) | std::uint64_t(c.x);
}
glm::ivec3 coordOfKey(std::uint64_t k) {
  return glm::ivec3(int(k & 0x1FFFFF), int(k >> 21 & 0x1FFFFF), int(k >> 42));
}
// Morton order of cell coordinates (x lowest), as the levels keep their voxels.
bool mortonBefore(glm::ivec3 a, glm::ivec3 b) {
  for (int bit = kMaxPointLevels - 1; bit >= 0; --bit)
    for (int axis = 2; axis >= 0; --axis) {
      const int x = a[axis] >> bit & 1, y = b[axis] >> bit & 1;
      if (x != y) return x < y;
    }
  return false;
}

// What the first pass over the file finds.
struct Survey {
  PointFileInfo file;
  glm::dvec3 lower{std::numeric_limits<double>::max()}, upper{-std::numeric_limits<double>::max()};
  std::uint64_t fingerprint = 0;
};

Survey survey(const std::filesystem::path& input, const std::function<void(double)>& progress) {
  Survey s;
  Hasher hash;
  s.file = readPointCloud(input, [&](const PointCloud& batch, std::uint64_t, double fraction) {
    for (const glm::dvec3& p : batch.positions)
      s.lower = glm::min(s.lower, p), s.upper = glm::max(s.upper, p);
    hash.add(batch.positions.data(), batch.positions.size()).add(batch.normals.data(), batch.normals.size());
    hash.add(batch.colors.data(), batch.colors.size());
    progress(fraction);
  });
  s.fingerprint = hash.digest();
  return s;
}

// The occupied cells of the cell level, in Morton order, and the points in each.
struct Cells {
  int level = 0;
  std::vector<glm::ivec3> coords;
  std::vector<std::uint64_t> points;
  std::unordered_map<std::uint64_t, std::uint32_t> index;  // by keyOf(coord)
  std::optional<std::uint32_t> find(glm::ivec3 c) const {
    const auto it = index.find(keyOf(c));
    return it == index.end() ? std::nullopt : std::optional(it->second);
  }
};

Cells cellsOf(const std::unordered_map<std::uint64_t, std::uint64_t>& histogram, int level) {
  std::unordered_map<std::uint64_t, std::uint64_t> counts;
  for (const auto& [k, n] : histogram) counts[keyOf(coordOfKey(k) >> (kHistogramLevel - level))] += n;
  Cells cells;
  cells.level = level;
  for (const auto& [k, n] : counts) cells.coords.push_back(coordOfKey(k));
  std::sort(cells.coords.begin(), cells.coords.end(), mortonBefore);
  for (std::uint32_t i = 0; i < cells.coords.size(); ++i) {
    cells.index[keyOf(cells.coords[i])] = i;
    cells.points.push_back(counts[keyOf(cells.coords[i])]);
  }
  return cells;
}

// The shallowest cell level whose fullest cell fits the memory left after the program and the buffers.
int chooseCellLevel(const std::filesystem::path& input,
                    const std::unordered_map<std::uint64_t, std::uint64_t>& histogram, int levels,
                    const OutOfCoreOptions& ooc) {
  const double perCell = double(ooc.memoryBytes) - double(ooc.processBytes) - kFixedBytes;
  const int deepest = std::min(levels - 1, kHistogramLevel);
  std::uint64_t fullest = 0;
  for (int level = 1; level <= deepest; ++level) {
    const Cells cells = cellsOf(histogram, level);
    fullest = *std::max_element(cells.points.begin(), cells.points.end());
    if (kBytesPerCellPoint * double(fullest) <= perCell) return level;
  }
  throw std::runtime_error(
      input.string() + ": " + ooc.memoryOrigin + ": " + std::to_string(ooc.memoryBytes >> 20) +
      " MiB is too small for " + std::to_string(levels) +
      " levels of this scan (its fullest "
      "cell of level " +
      std::to_string(deepest) + " holds " + std::to_string(fullest) + " points, about " +
      std::to_string(std::llround(kBytesPerCellPoint * double(fullest) / (1 << 20))) + " MiB)");
}

// Every point into its cell's bin, and into the halo of each neighbouring cell whose cube it lies within
// `halo` (world units) of. Returns the highest point's cell (largest z, the first such in the file).
std::uint32_t binPoints(const std::filesystem::path& input, const SceneTransform& transform,
                        const Cells& cells, double halo, PointBins& bins,
                        const std::function<void(double)>& progress) {
  std::vector<std::uint32_t> counts(cells.coords.size(), 0);
  const double cellsPerUnit = std::ldexp(1.0, cells.level) / transform.size;
  const double width = halo * cellsPerUnit;  // in cell widths
  double highest = -std::numeric_limits<double>::infinity();
  std::uint32_t highestCell = 0;
  readPointCloud(input, [&](const PointCloud& batch, std::uint64_t, double fraction) {
    for (std::size_t i = 0; i < batch.positions.size(); ++i) {
      BinnedPoint p;
      p.position = batch.positions[i];
      if (!batch.normals.empty()) p.normal = batch.normals[i];
      if (!batch.colors.empty()) p.color = batch.colors[i];
      const glm::ivec3 coord = detail::pointVoxel(transform, p.position, cells.level);
      const std::optional<std::uint32_t> found = cells.find(coord);
      if (!found) throw std::runtime_error(input.string() + ": the file changed while it was being built");
      const std::uint32_t cell = *found;
      if (p.position.z > highest) highest = p.position.z, highestCell = cell;
      bins.appendOwn(cell, p);
      const glm::dvec3 f =
          (transform.toOctree(p.position) - 1.0) * std::ldexp(1.0, cells.level) - glm::dvec3(coord);
      glm::ivec3 lo(0), hi(0);
      for (int a = 0; a < 3; ++a) lo[a] = f[a] < width ? -1 : 0, hi[a] = f[a] > 1.0 - width ? 1 : 0;
      for (int dz = lo.z; dz <= hi.z; ++dz)
        for (int dy = lo.y; dy <= hi.y; ++dy)
          for (int dx = lo.x; dx <= hi.x; ++dx)
            if (dx || dy || dz)
              if (const auto n = cells.find(coord + glm::ivec3(dx, dy, dz)))
                bins.appendHalo(*n, HaloPoint{p, cell, counts[cell]});
      ++counts[cell];
    }
    progress(fraction);
  });
  bins.flush();
  return highestCell;
}

// The cells in the order their normals are estimated: breadth first over face, edge and corner neighbours
// from the highest point's cell, then from the highest unreached cell of each further group (so that a
// cell's normals are oriented from its already oriented neighbours' halo points, as Hoppe's spanning tree
// grows from the highest point).
std::vector<std::uint32_t> normalOrder(const Cells& cells, std::uint32_t first) {
  std::vector<std::uint32_t> order;
  std::vector<bool> seen(cells.coords.size(), false);
  std::deque<std::uint32_t> queue{first};
  seen[first] = true;
  for (std::uint32_t next = 0;;) {
    while (!queue.empty()) {
      const std::uint32_t c = queue.front();
      queue.pop_front();
      order.push_back(c);
      for (int d = 0; d < 27; ++d)
        if (const auto n = cells.find(cells.coords[c] + glm::ivec3(d % 3 - 1, d / 3 % 3 - 1, d / 9 - 1)))
          if (!seen[*n]) seen[*n] = true, queue.push_back(*n);
    }
    while (next < seen.size() && seen[next]) ++next;
    if (next == seen.size()) return order;
    seen[next] = true, queue.push_back(next);
  }
}

PointCloud cloudOf(const std::vector<BinnedPoint>& points, bool colors) {
  PointCloud c;
  c.positions.reserve(points.size());
  c.normals.reserve(points.size());
  for (const BinnedPoint& p : points) {
    c.positions.push_back(p.position), c.normals.push_back(p.normal);
    if (colors) c.colors.push_back(p.color);
  }
  return c;
}

// A cell's normals: its own points' and its halo's estimated together, the halo points of cells done
// before fixed at their final normals (so that they orient this cell's), the own points' written.
std::uint64_t estimateCellNormals(const PointBins& bins, std::uint32_t cell) {
  PointCloud cloud = cloudOf(bins.readOwn(cell), false);
  const std::size_t own = cloud.positions.size();
  std::vector<HaloPoint> halo = bins.readHalo(cell);
  std::stable_sort(halo.begin(), halo.end(),
                   [](const HaloPoint& a, const HaloPoint& b) { return a.owner < b.owner; });
  for (std::size_t i = 0; i < halo.size();) {
    std::size_t end = i;
    while (end < halo.size() && halo[end].owner == halo[i].owner) ++end;
    const std::vector<glm::vec3> done =
        bins.hasNormals(halo[i].owner) ? bins.readNormals(halo[i].owner) : std::vector<glm::vec3>();
    for (; i < end; ++i) {
      cloud.positions.push_back(halo[i].point.position);
      cloud.normals.push_back(halo[i].index < done.size() ? done[halo[i].index] : halo[i].point.normal);
    }
  }
  const NormalEstimate e = estimateNormals(cloud);
  cloud.normals.resize(own);
  bins.writeNormals(cell, cloud.normals);
  return e.estimated;
}

// A cell's own points with their final normals.
PointCloud cellCloud(const PointBins& bins, std::uint32_t cell, bool colors) {
  PointCloud cloud = cloudOf(bins.readOwn(cell), colors);
  cloud.normals = bins.readNormals(cell);
  if (cloud.normals.size() != cloud.positions.size())
    throw std::runtime_error("cell " + std::to_string(cell) + ": its normals do not match its points");
  return cloud;
}

// The levels above the cells (0 to the cell level), made from the cells' roots as the in-core build makes
// them from the points: the cells' sums added in Morton order, contours from their points' extents.
class TopLevels {
 public:
  TopLevels(std::vector<PointNode> cellRoots, int cellLevel, bool colors) : cellLevel_(cellLevel) {
    levels_.resize(std::size_t(cellLevel) + 1);
    index_.resize(levels_.size());
    for (int level = cellLevel; level >= 0; --level) {
      for (const PointNode& n : cellRoots) {
        levels_[std::size_t(level)].push_back(detail::voxelOf(n, colors));
        index_[std::size_t(level)][keyOf(levels_[std::size_t(level)].back().coord)] =
            std::uint32_t(levels_[std::size_t(level)].size() - 1);
      }
      if (level > 0) cellRoots = detail::parentNodes(cellRoots);
    }
    for (SliceVoxel& cell : levels_.back()) cell.childMask = 0;  // leaves here: the cells hold the rest
    extents_.resize(levels_.size());
    for (std::size_t l = 0; l < levels_.size(); ++l) extents_[l].resize(levels_[l].size());
  }
  // The indices of a cell's ancestors at levels 1 to the cell level - 1, for extend.
  std::vector<std::uint32_t> ancestorsOf(glm::ivec3 cell) const {
    std::vector<std::uint32_t> out;
    for (int level = 1; level < cellLevel_; ++level) out.push_back(at(level, cell >> (cellLevel_ - level)));
    return out;
  }
  // A point of a cell with these ancestors extends their extents.
  void extend(const std::vector<std::uint32_t>& ancestors, glm::dvec3 octreePoint) {
    for (int level = 1; level < cellLevel_; ++level) {
      const std::uint32_t i = ancestors[std::size_t(level) - 1];
      detail::extend(extents_[std::size_t(level)][i], levels_[std::size_t(level)][i], level, octreePoint);
    }
  }
  // Contours from the root down to the cells' parents, and the bounds each cell's root is decided under.
  std::vector<PointBounds> decideContours(const BuildOptions& options) {
    std::vector<PointBounds> parentBounds(1);
    for (int level = 1; level <= cellLevel_; ++level) {
      std::vector<SliceVoxel>& voxels = levels_[std::size_t(level)];
      const std::vector<SliceVoxel>& parents = levels_[std::size_t(level) - 1];
      std::vector<PointBounds> bounds(voxels.size());
      for (std::size_t i = 0; i < voxels.size(); ++i) {
        const std::uint32_t p = at(level - 1, voxels[i].coord >> 1);
        bounds[i] = detail::boundsOf(parentBounds[p], parents[p], level - 1, voxels[i].coord, level);
        if (level < cellLevel_)
          detail::decideContour(voxels[i], level, bounds[i], extents_[std::size_t(level)][i],
                                options.innerContourMinReduction);
      }
      parentBounds = std::move(bounds);
    }
    return parentBounds;
  }
  // The cell's root as its subtree decided it (its contour).
  void setCellRoot(std::size_t cell, const VoxelRecord& root) {
    levels_.back()[cell].hasContour = root.hasContour;
    levels_.back()[cell].contour = root.contour;
  }
  VoxelTree tree(bool colors) const { return treeOfLevels(levels_, colors, true); }

 private:
  std::uint32_t at(int level, glm::ivec3 coord) const {
    const auto it = index_[std::size_t(level)].find(keyOf(coord));
    if (it == index_[std::size_t(level)].end())
      throw std::logic_error("TopLevels: a cell without an ancestor");
    return it->second;
  }
  int cellLevel_;
  VoxelLevels levels_;
  std::vector<std::unordered_map<std::uint64_t, std::uint32_t>> index_;  // by keyOf(coord), per level
  std::vector<std::vector<PointExtent>> extents_;
};

using Progress = std::function<void(const char* phase, double fraction)>;

// The top's contours need every cell's points: their extents along the top voxels' normals.
std::vector<PointBounds> topContours(const PointBins& bins, const Cells& cells,
                                     const SceneTransform& transform, const BuildOptions& options,
                                     TopLevels& top, const Progress& progress) {
  if (!options.contours) return std::vector<PointBounds>(cells.coords.size());
  for (std::uint32_t c = 0; c < cells.coords.size() && cells.level > 1; ++c) {
    const std::vector<std::uint32_t> ancestors = top.ancestorsOf(cells.coords[c]);
    for (const BinnedPoint& p : bins.readOwn(c)) top.extend(ancestors, transform.toOctree(p.position));
    progress("contours", double(c + 1) / double(cells.coords.size()));
  }
  return top.decideContours(options);
}

// The store from the top and the spilled cells, as the mesh's out-of-core build writes it.
void writePointStore(const TopLevels& top, const Cells& cells, const SceneTransform& transform,
                     const BuildOptions& options, const StoreWriteOptions& write, bool colors,
                     const std::filesystem::path& work, const std::filesystem::path& store,
                     OutOfCoreReport& report, const Progress& progress) {
  StoreWriteOptions writeOptions = write;
  writeOptions.progress = [&](double f) { progress("write", f); };
  StoreFileWriter writer(store, writeOptions);
  const VoxelTree topTree = top.tree(colors);
  appendSpilledForest(writer, topTree, cells.level, work, report);
  writer.finish({transform, storedParameters(options), colors, true, topTree.voxels[0].color,
                 topTree.voxels[0].normal});
}

// Normals, the top, the cells' subtrees (spilled) and the store, from the binned points.
void buildCells(const PointBins& bins, const Cells& cells, std::uint32_t firstCell,
                const SceneTransform& transform, const BuildOptions& options, const StoreWriteOptions& write,
                const OutOfCoreOptions& ooc, const std::filesystem::path& store,
                const std::filesystem::path& work, bool reuse, PointStoreReport& report,
                const Progress& progress, const std::function<void(const char*)>& endPhase) {
  const bool colors = report.file.colors;
  const std::size_t count = cells.coords.size();
  std::uint64_t total = 0, done = 0;
  for (const std::uint64_t p : cells.points) total += p;
  const auto step = [&](const char* phase, std::uint32_t c) {
    done += cells.points[c];
    progress(phase, double(done) / double(std::max<std::uint64_t>(total, 1)));
  };
  // Normals, cell after cell from the highest point's (kept from an interrupted run where written).
  for (const std::uint32_t c : normalOrder(cells, firstCell)) {
    if (!(reuse && bins.hasNormals(c))) report.normalsEstimated += estimateCellNormals(bins, c);
    step("normals", c);
  }
  endPhase("normals");
  // The cells' sums make the levels above them, whose contours need the cells' points once more.
  std::vector<PointNode> roots(count);
  done = 0;
  for (std::uint32_t c = 0; c < count; ++c) {
    roots[c] = detail::pointRoot(cellCloud(bins, c, colors), transform, options.levels, cells.level);
    step("top", c);
  }
  TopLevels top(std::move(roots), cells.level, colors);
  const std::vector<PointBounds> bounds = topContours(bins, cells, transform, options, top, progress);
  endPhase("top");
  // Each cell's subtree, spilled (kept from an interrupted run where complete).
  done = 0;
  std::uint64_t voxels = 0;
  for (std::uint32_t c = 0; c < count; ++c) {
    const std::filesystem::path path = cellPath(work, cells.coords[c]);
    if (const std::optional<CellFileHeader> h = reuse ? readCellHeader(path, nullptr) : std::nullopt) {
      top.setCellRoot(c, h->root);
      ++report.build.cellsReused;
      voxels += h->recordCount;
    } else {
      detail::PointNode root;
      const VoxelTree tree = treeOfLevels(
          detail::pointLevels(cellCloud(bins, c, colors), transform, options, cells.level, bounds[c], &root),
          colors, true);
      writeCell(path, tree,
                CellRoot{tree.voxels[0], {double(root.sums.count), root.sums.color, root.sums.normal}});
      top.setCellRoot(c, tree.voxels[0]);
      voxels += tree.voxels.size();
      if (ooc.cellSpilled) ooc.cellSpilled(cells.coords[c]);
    }
    step("cells", c);
    if (ooc.cellProgress) ooc.cellProgress(c + 1, count, voxels);
  }
  endPhase("cells");
  writePointStore(top, cells, transform, options, write, colors, work, store, report.build, progress);
  endPhase("write");
}

// What a resume must agree on: the points (hashed) and every option that changes the voxels or the slices.
nlohmann::json manifestOf(const Survey& survey, const BuildOptions& options, const StoreWriteOptions& write,
                          int cellLevel, double halo) {
  return {{"format", kWorkFormat},
          {"input", "points"},
          {"pointsHash", std::to_string(survey.fingerprint)},
          {"points", survey.file.points},
          {"levels", options.levels},
          {"contours", options.contours},
          {"leafContourMinReduction", options.leafContourMinReduction},
          {"innerContourMinReduction", options.innerContourMinReduction},
          {"cellLevel", cellLevel},
          {"halo", halo},
          {"sliceBytes", write.sliceBytes}};
}

// The work folder's manifest from an interrupted run, when resuming and there is one.
std::optional<nlohmann::json> oldManifest(const OutOfCoreOptions& ooc, const std::filesystem::path& path,
                                          const std::filesystem::path& work) {
  if (!ooc.resume || !std::filesystem::exists(path)) return std::nullopt;
  std::optional<nlohmann::json> old;
  try {
    std::ifstream(path) >> old.emplace();
  } catch (const std::exception&) {
    throw std::runtime_error(path.string() + ": unreadable; delete " + work.string() + " or drop --resume");
  }
  return old;
}

// Keeps the work folder of the interrupted run of this build (true), or starts a fresh one.
bool openWorkFolder(const std::optional<nlohmann::json>& old, const nlohmann::json& manifest,
                    const std::filesystem::path& work, const std::filesystem::path& manifestPath) {
  if (old) {
    for (const auto& [key, value] : manifest.items())
      if (!old->contains(key) || (*old)[key] != value)
        throw std::runtime_error("--resume: " + work.string() + " holds a build with another " + key +
                                 "; delete it or drop --resume");
    return true;
  }
  std::filesystem::remove_all(work);
  std::filesystem::create_directories(work);
  std::ofstream out(manifestPath);
  if (!(out << manifest.dump(2) << "\n").flush())
    throw std::runtime_error(manifestPath.string() + ": cannot write (disk full?)");
  return false;
}

}  // namespace

std::uint64_t estimateInCorePointBuildBytes(std::uint64_t points) {
  return std::uint64_t(kInCoreBytesPerPoint * double(points));
}

PointBuildPlan planPointBuild(std::uint64_t points, std::uint64_t processBytes, std::uint64_t share) {
  PointBuildPlan plan;
  plan.inCoreBytes = processBytes + estimateInCorePointBuildBytes(points);
  plan.outOfCore = plan.inCoreBytes > share;
  return plan;
}

PointStoreReport buildPointStore(const std::filesystem::path& input, BuildOptions options,
                                 const StoreWriteOptions& write, const OutOfCoreOptions& ooc,
                                 const std::filesystem::path& store, const PointLevelChoice& chooseLevels) {
  const auto start = std::chrono::steady_clock::now();
  auto phase = start;
  PointStoreReport report;
  // Bars appear once the build has run a while: a small scan's error stays one line.
  const auto progress = [&](const char* name, double f) {
    if (ooc.progress && std::chrono::steady_clock::now() - start > kQuietStart)
      ooc.progress(name, std::min(1.0, f));
  };
  const auto endPhase = [&](const char* name) {
    progress(name, 1.0);
    const auto now = std::chrono::steady_clock::now();
    report.build.phaseSeconds[name] = std::chrono::duration<double>(now - phase).count();
    phase = now;
  };
  // 1. The file's bounds and fingerprint, then a sample for the spacing and the points per cell.
  const Survey surveyed = survey(input, [&](double f) { progress("read", f); });
  endPhase("read");
  report.file = surveyed.file;
  if (!glm::any(glm::greaterThan(surveyed.upper, surveyed.lower)))
    throw std::runtime_error(input.string() + ": the points have no extent: all coincide");
  const SceneTransform transform = fitSceneCube(surveyed.lower, surveyed.upper);
  const std::uint64_t n = surveyed.file.points;
  const std::uint64_t stride = std::max<std::uint64_t>(1, n / kSpacingSamples);
  std::vector<glm::dvec3> sample;
  std::unordered_map<std::uint64_t, std::uint64_t> histogram;
  readPointCloud(input, [&](const PointCloud& batch, std::uint64_t first, double fraction) {
    for (std::size_t i = 0; i < batch.positions.size(); ++i) {
      if ((first + i) % stride == 0) sample.push_back(batch.positions[i]);
      ++histogram[keyOf(detail::pointVoxel(transform, batch.positions[i], kHistogramLevel))];
    }
    progress("plan", fraction);
  });
  report.spacing = estimatePointSpacing(sample, n);
  options.levels = report.levels = chooseLevels(report.spacing, transform);
  if (options.levels < 2 || options.levels > kMaxPointLevels)
    throw std::runtime_error("out of core, point clouds build 2 to " + std::to_string(kMaxPointLevels) +
                             " levels, not " + std::to_string(options.levels));
  const std::filesystem::path work = workFolderOf(ooc, store), manifestPath = work / "manifest.json";
  const std::optional<nlohmann::json> old = oldManifest(ooc, manifestPath, work);
  int cellLevel = ooc.cellLevel;
  if (cellLevel == 0 && old && old->contains("cellLevel") && (*old)["cellLevel"].is_number_integer())
    cellLevel = (*old)["cellLevel"].get<int>();  // a resume keeps the interrupted run's cells
  if (cellLevel == 0) cellLevel = chooseCellLevel(input, histogram, options.levels, ooc);
  if (cellLevel < 1 || cellLevel >= options.levels || cellLevel > kHistogramLevel)
    throw std::runtime_error("the cell level must be in [1, " +
                             std::to_string(std::min(options.levels - 1, kHistogramLevel)) + "], not " +
                             std::to_string(cellLevel));
  report.build.cellLevel = cellLevel;
  const Cells cells = cellsOf(histogram, cellLevel);
  std::unordered_map<std::uint64_t, std::uint64_t>().swap(histogram);
  endPhase("plan");
  const double halo = kHaloSpacings * report.spacing;
  const bool reuse =
      openWorkFolder(old, manifestOf(surveyed, options, write, cellLevel, halo), work, manifestPath);

  // 2. The points binned per cell, with halos (kept from an interrupted run once complete).
  const std::filesystem::path binned = work / "points" / "complete";
  const bool binnedBefore = reuse && std::filesystem::exists(binned);
  if (!binnedBefore) std::filesystem::remove_all(work / "points");  // a part binned before would repeat
  PointBins bins(work / "points", cells.coords.size());
  std::uint32_t firstCell = 0;
  if (binnedBefore) {
    std::ifstream(binned) >> firstCell;
  } else {
    firstCell = binPoints(input, transform, cells, halo, bins, [&](double f) { progress("bin", f); });
    if (!(std::ofstream(binned) << firstCell << "\n").flush())
      throw std::runtime_error(binned.string() + ": cannot write (disk full?)");
  }
  endPhase("bin");
  buildCells(bins, cells, firstCell, transform, options, write, ooc, store, work, reuse, report, progress,
             endPhase);
  std::error_code ignored;
  std::filesystem::remove_all(work, ignored);
  report.build.stats.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return report;
}

}  // namespace svo
