// A level set's zero crossing (or a fog volume's threshold surface) voxelized straight from the grid
// (volume.hpp): the grid cells the surface crosses, the octree's finest voxels those cells' trilinear field
// changes sign in, each voxel's normal from the field's gradient and contour from the points where the
// surface crosses the voxel's (and its cells') edges, a fog volume's voxel its densest point as its color's
// alpha; coarser voxels as a voxel mask's, with contours fitted to their finest voxels' points.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <tuple>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <openvdb/openvdb.h>
#include <openvdb/tools/Interpolation.h>
#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <glm/geometric.hpp>

#include "svo/builder/volume.hpp"
#include "svo/store/format.hpp"
#include "volume_file.hpp"
#include "voxel_kernels.hpp"

namespace svo {

namespace fs = std::filesystem;

namespace {

using glm::dvec3;

// Finest voxels per task when their attributes are computed: large enough that a task's set-up (a grid
// accessor) is noise, small enough to balance two to sixteen threads.
constexpr std::size_t kLeavesPerTask = 4096;
// The gradient's central differences step this many grid voxels either way: the second-order stencil of the
// grid's own samples (OpenVDB's math::ISGradient<CD_2ND>), here on the trilinear field between them.
constexpr double kGradientStep = 1.0;

// The eight corners of a box, slot k = x + 2y + 4z, and its twelve edges as pairs of slots.
constexpr std::array<std::array<int, 2>, 12> kBoxEdges{
    {{0, 1}, {2, 3}, {4, 5}, {6, 7}, {0, 2}, {1, 3}, {4, 6}, {5, 7}, {0, 4}, {1, 5}, {2, 6}, {3, 7}}};
dvec3 cornerOf(const dvec3& lo, const dvec3& hi, int slot) {
  return {slot & 1 ? hi.x : lo.x, slot & 2 ? hi.y : lo.y, slot & 4 ? hi.z : lo.z};
}

// Inside is negative; zero counts as outside, so a surface through a plane of samples makes one layer of
// voxels (those below it), not two.
bool inside(double v) {
  return v < 0.0;
}

using Corners = std::array<double, 8>;

// The trilinear field of a cell's corner values at `p` in the cell's [0, 1]^3.
double trilinear(const Corners& v, const dvec3& p) {
  const double x00 = v[0] + (v[1] - v[0]) * p.x, x10 = v[2] + (v[3] - v[2]) * p.x;
  const double x01 = v[4] + (v[5] - v[4]) * p.x, x11 = v[6] + (v[7] - v[6]) * p.x;
  const double y0 = x00 + (x10 - x00) * p.y, y1 = x01 + (x11 - x01) * p.y;
  return y0 + (y1 - y0) * p.z;
}

bool changesSign(const Corners& v) {
  int in = 0;
  for (const double x : v) in += inside(x);
  return in > 0 && in < 8;
}

// The field at the corners of the box [lo, hi] of a cell: the trilinear field restricted to the box is the
// trilinear interpolation of these, so the surface crosses the box exactly when they change sign.
Corners boxCorners(const Corners& cell, const dvec3& lo, const dvec3& hi) {
  Corners out;
  for (int k = 0; k < 8; ++k) out[k] = trilinear(cell, cornerOf(lo, hi, k));
  return out;
}

// Where the surface crosses the box's edges (the field is linear along them), in the cell's coordinates.
template <class Emit>
void edgeCrossings(const Corners& box, const dvec3& lo, const dvec3& hi, Emit&& emit) {
  for (const auto& [a, b] : kBoxEdges)
    if (inside(box[a]) != inside(box[b])) {
      const double t = box[a] / (box[a] - box[b]);
      emit(glm::mix(cornerOf(lo, hi, a), cornerOf(lo, hi, b), t));
    }
}

// The grid's field, signed so that the inside (a level set's negative side, a fog volume's denser one) is
// negative, read through one accessor per thread.
template <class Grid>
class Field {
 public:
  Field(const Grid& grid, double isovalue, double sign)
      : accessor_(grid.getConstAccessor()), isovalue_(isovalue), sign_(sign) {}
  double at(const openvdb::Coord& ijk) const { return sign_ * (double(accessor_.getValue(ijk)) - isovalue_); }
  // The grid's value where the field is `field` (at's inverse).
  double valueOf(double field) const { return isovalue_ + sign_ * field; }
  Corners corners(const openvdb::Coord& lower) const {
    Corners v;
    for (int k = 0; k < 8; ++k) v[k] = at(lower.offsetBy(k & 1, k >> 1 & 1, k >> 2 & 1));
    return v;
  }
  // The gradient of the trilinear field by central differences, in index space (world space up to the voxel
  // width, the transform being cubic).
  dvec3 gradient(const dvec3& index) const {
    dvec3 g;
    for (int axis = 0; axis < 3; ++axis) {
      dvec3 lo = index, hi = index;
      lo[axis] -= kGradientStep, hi[axis] += kGradientStep;
      g[axis] = sample(hi) - sample(lo);
    }
    return g;
  }

 private:
  double sample(const dvec3& p) const {
    return sign_ *
           (double(openvdb::tools::BoxSampler::sample(accessor_, openvdb::Vec3d(p.x, p.y, p.z))) - isovalue_);
  }
  typename Grid::ConstAccessor accessor_;
  double isovalue_, sign_;
};

// A crossed grid cell: its lower corner sample.
using CellList = std::vector<openvdb::Coord>;

// The cells whose corners change sign (the surface lies in these only: elsewhere the trilinear field is a
// convex combination of same-signed values), found from the narrow band's voxels as lower corners (a crossed
// cell's corners lie within a voxel diagonal of the surface, inside any narrow band OpenVDB makes), and the
// bounds of their edge crossings in index space.
template <class Grid>
CellList crossedCells(const Grid& grid, const Field<Grid>& prototype, dvec3& lower, dvec3& upper) {
  std::vector<const typename Grid::TreeType::LeafNodeType*> leaves;
  grid.tree().getNodes(leaves);
  tbb::combinable<CellList> cells;
  tbb::combinable<std::pair<dvec3, dvec3>> bounds([] { return std::pair(dvec3(1e300), dvec3(-1e300)); });
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, leaves.size()), [&](const auto& range) {
    const Field<Grid> field = prototype;
    CellList& mine = cells.local();
    auto& [lo, hi] = bounds.local();
    for (std::size_t i = range.begin(); i < range.end(); ++i)
      for (auto it = leaves[i]->cbeginValueOn(); it; ++it) {
        const openvdb::Coord ijk = it.getCoord();
        const Corners v = field.corners(ijk);
        if (!changesSign(v)) continue;
        mine.push_back(ijk);
        const dvec3 base(ijk.x(), ijk.y(), ijk.z());
        edgeCrossings(v, dvec3(0.0), dvec3(1.0),
                      [&](const dvec3& p) { lo = glm::min(lo, base + p), hi = glm::max(hi, base + p); });
      }
  });
  CellList out;
  cells.combine_each([&](const CellList& c) { out.insert(out.end(), c.begin(), c.end()); });
  lower = dvec3(1e300), upper = dvec3(-1e300);
  bounds.combine_each(
      [&](const auto& b) { lower = glm::min(lower, b.first), upper = glm::max(upper, b.second); });
  return out;
}

// Grid index space against the octree's finest voxels: index = offset + u * ratio, u in finest voxel widths
// from the scene cube's corner.
struct Resampling {
  dvec3 offset{0.0};
  double ratio = 1.0;  // finest voxel width / grid voxel width
  int side = 1;        // finest voxels along the cube's edge
  // The finest voxel's box within the cell at `cell`, in the cell's [0, 1]^3; false when they only touch.
  bool overlap(const glm::ivec3& voxel, const openvdb::Coord& cell, dvec3& lo, dvec3& hi) const {
    const dvec3 c(cell.x(), cell.y(), cell.z());
    lo = glm::clamp(offset + dvec3(voxel) * ratio - c, 0.0, 1.0);
    hi = glm::clamp(offset + dvec3(voxel + 1) * ratio - c, 0.0, 1.0);
    return glm::all(glm::lessThan(lo, hi));
  }
  // Finest voxels (min, max inclusive, clamped to the cube) overlapping the index box [lo, hi].
  void voxelRange(const dvec3& lo, const dvec3& hi, glm::ivec3& first, glm::ivec3& last) const {
    first = glm::clamp(glm::ivec3(glm::floor((lo - offset) / ratio)), 0, side - 1);
    last = glm::clamp(glm::ivec3(glm::ceil((hi - offset) / ratio)) - 1, 0, side - 1);
  }
};

// The finest voxels the surface crosses, in Morton order.
template <class Grid>
std::vector<glm::ivec3> crossedVoxels(const CellList& cells, const Field<Grid>& prototype,
                                      const Resampling& grid) {
  tbb::combinable<std::vector<glm::ivec3>> found;
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, cells.size()), [&](const auto& range) {
    const Field<Grid> field = prototype;
    std::vector<glm::ivec3>& mine = found.local();
    for (std::size_t i = range.begin(); i < range.end(); ++i) {
      const openvdb::Coord& k = cells[i];
      const Corners v = field.corners(k);
      const dvec3 base(k.x(), k.y(), k.z());
      glm::ivec3 first, last;
      grid.voxelRange(base, base + 1.0, first, last);
      for (int z = first.z; z <= last.z; ++z)
        for (int y = first.y; y <= last.y; ++y)
          for (int x = first.x; x <= last.x; ++x) {
            dvec3 lo, hi;
            if (grid.overlap({x, y, z}, k, lo, hi) && changesSign(boxCorners(v, lo, hi)))
              mine.emplace_back(x, y, z);
          }
    }
  });
  std::vector<glm::ivec3> out;
  found.combine_each([&](const auto& f) { out.insert(out.end(), f.begin(), f.end()); });
  // A voxel comes once per grid cell it crosses in: repeats go first, by an order cheaper than Morton's.
  tbb::parallel_sort(out.begin(), out.end(), [](const glm::ivec3& a, const glm::ivec3& b) {
    return std::tie(a.z, a.y, a.x) < std::tie(b.z, b.y, b.x);
  });
  out.erase(std::unique(out.begin(), out.end()), out.end());
  tbb::parallel_sort(out.begin(), out.end(), mortonLess);
  return out;
}

// The points where the surface crosses the edges of each finest voxel's pieces of grid cells, in voxel
// widths from its centre, quantized to 1/kPointScale of a voxel (far below the contours' 1/42 steps) and
// without repeats: a finest voxel's points are the kLeavesPerTask-voxel chunk i / kLeavesPerTask's, from
// end[i - 1] (0 at a chunk's start) to end[i].
constexpr double kPointScale = 65534.0;  // offsets in [-1/2, 1/2] fill int16
using SurfacePoint = std::array<std::int16_t, 3>;
struct SurfacePoints {
  std::vector<std::vector<SurfacePoint>> chunks;
  std::vector<std::uint32_t> end;
  template <class Visit>
  void forEach(std::size_t leaf, Visit&& visit) const {
    const std::vector<SurfacePoint>& chunk = chunks[leaf / kLeavesPerTask];
    for (std::uint32_t k = leaf % kLeavesPerTask == 0 ? 0 : end[leaf - 1]; k < end[leaf]; ++k)
      visit(dvec3(chunk[k][0], chunk[k][1], chunk[k][2]) / kPointScale);
  }
};

// The finest voxels (Morton order) with their normals and colors, and their surface points. With
// `densities` (a fog volume), a voxel's color carries the highest density the trilinear field reaches in its
// cube as alpha: exact, as a trilinear field's extremes over a box lie at its corners.
template <class Grid>
SurfacePoints leafAttributes(const Field<Grid>& prototype, const Resampling& grid,
                             const openvdb::math::Transform& transform,
                             const volume_file::Vec3Sampler& colors, bool densities,
                             std::vector<SliceVoxel>& leaves) {
  const std::size_t count = leaves.size(), tasks = (count + kLeavesPerTask - 1) / kLeavesPerTask;
  SurfacePoints out;
  out.chunks.resize(tasks);
  out.end.resize(count);
  tbb::parallel_for(std::size_t(0), tasks, [&](std::size_t task) {
    const Field<Grid> field = prototype;
    std::vector<SurfacePoint>& chunk = out.chunks[task];
    for (std::size_t i = task * kLeavesPerTask; i < std::min(count, (task + 1) * kLeavesPerTask); ++i) {
      SliceVoxel& leaf = leaves[i];
      const dvec3 centre = dvec3(leaf.coord) + 0.5;
      const dvec3 boxLo = grid.offset + dvec3(leaf.coord) * grid.ratio, boxHi = boxLo + grid.ratio;
      const glm::ivec3 firstCell(glm::floor(boxLo)), lastCell = glm::ivec3(glm::ceil(boxHi)) - 1;
      const std::size_t begin = chunk.size();
      dvec3 sum(0.0);
      double densest = -std::numeric_limits<double>::infinity();
      for (int z = firstCell.z; z <= lastCell.z; ++z)
        for (int y = firstCell.y; y <= lastCell.y; ++y)
          for (int x = firstCell.x; x <= lastCell.x; ++x) {
            const openvdb::Coord k(x, y, z);
            const Corners v = field.corners(k);
            const bool crossed = changesSign(v);
            dvec3 lo, hi;
            if ((!crossed && !densities) || !grid.overlap(leaf.coord, k, lo, hi)) continue;
            const Corners box = boxCorners(v, lo, hi);
            if (densities)
              for (const double f : box) densest = std::max(densest, field.valueOf(f));
            if (!crossed) continue;
            edgeCrossings(box, lo, hi, [&](const dvec3& p) {
              const dvec3 local =
                  glm::clamp((dvec3(x, y, z) + p - grid.offset) / grid.ratio - centre, -0.5, 0.5);
              sum += local;
              const glm::ivec3 q(glm::round(local * kPointScale));
              chunk.push_back({std::int16_t(q.x), std::int16_t(q.y), std::int16_t(q.z)});
            });
          }
      const double n = double(std::max<std::size_t>(chunk.size() - begin, 1));
      std::sort(chunk.begin() + std::ptrdiff_t(begin), chunk.end());
      chunk.erase(std::unique(chunk.begin() + std::ptrdiff_t(begin), chunk.end()), chunk.end());
      out.end[i] = std::uint32_t(chunk.size());
      const dvec3 surface = grid.offset + (centre + sum / n) * grid.ratio;
      const dvec3 g = field.gradient(surface);
      const double length = glm::length(g);
      leaf.normal = latticeNormal(length > 0.0 && std::isfinite(length) ? glm::vec3(g / length)
                                                                        : glm::vec3(0.0f, 0.0f, 1.0f));
      if (colors || densities) {
        const openvdb::Vec3d world = transform.indexToWorld(openvdb::Vec3d(surface.x, surface.y, surface.z));
        leaf.color = volume_file::colorWithDensity(colors, {world.x(), world.y(), world.z()},
                                                   densities ? densest : 1.0);
      }
    }
    chunk.shrink_to_fit();
  });
  return out;
}

// Each voxel's contour from the root down, as the mesh builder keeps one (chooseContour): the slab along its
// normal holding its finest voxels' crossing points, kept where it trims enough off its cube as its
// ancestors' contours bound it (sec. 5.3).
void addContours(const SurfacePoints& points, const BuildOptions& options, VoxelLevels& levels) {
  const int finest = int(levels.size()) - 1;
  const std::vector<SliceVoxel>& leaves = levels.back();
  std::vector<std::vector<geom::Slab>> parentSlabs(1);  // the root keeps no contour
  for (int level = 1; level <= finest; ++level) {
    const std::vector<SliceVoxel>& parents = levels[std::size_t(level) - 1];
    std::vector<SliceVoxel>& voxels = levels[std::size_t(level)];
    const int shift = finest - level;
    // Voxel i's finest voxels are leaves first[i] .. first[i + 1] (both levels in Morton order).
    std::vector<std::size_t> first(voxels.size() + 1, leaves.size());
    for (std::size_t j = 0, i = 0; j < leaves.size(); ++j)
      if (j == 0 || (leaves[j].coord >> shift) != (leaves[j - 1].coord >> shift)) first[i++] = j;
    std::vector<std::uint32_t> parentOf(voxels.size());
    for (std::uint32_t i = 0, p = 0; i < voxels.size(); ++i) {
      while (parents[p].coord != voxels[i].coord >> 1) ++p;
      parentOf[i] = p;
    }
    const double minCut =
        level == finest ? options.leafContourMinReduction : options.innerContourMinReduction;
    const double width = std::ldexp(1.0, shift);  // in finest voxels
    std::vector<std::vector<geom::Slab>> slabs(voxels.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, voxels.size()), [&](const auto& range) {
      for (std::size_t i = range.begin(); i < range.end(); ++i) {
        SliceVoxel& v = voxels[i];
        const SliceVoxel& parent = parents[parentOf[i]];
        const geom::Cube cube = voxel::cubeAt(level, v.coord);
        std::vector<geom::Slab> bounding = parentSlabs[parentOf[i]];
        if (parent.hasContour)
          bounding.push_back(voxel::slabOf(voxel::cubeAt(level - 1, parent.coord), parent.contour));
        slabs[i] = voxel::slabsCutting(bounding, cube);
        const glm::ivec3 q = quantizeContourNormal(dvec3(normalDirection(v.normal)));
        const std::vector<voxel::Direction> direction{{q, dvec3(q) / double(kContourNormalScale)}};
        std::vector<voxel::Extent> extent(1);
        const dvec3 centre = (dvec3(v.coord) + 0.5) * width;
        for (std::size_t j = first[i]; j < first[i + 1]; ++j) {
          const dvec3 leafCentre = dvec3(leaves[j].coord) + 0.5 - centre;
          points.forEach(j, [&](const dvec3& p) {
            const double d = glm::dot(direction[0].normal, leafCentre + p) / width;
            extent[0].lo = std::min(extent[0].lo, d), extent[0].hi = std::max(extent[0].hi, d);
          });
        }
        const std::optional<voxel::ContourFit> fit =
            voxel::chooseContour(cube, direction, extent, slabs[i], minCut);
        v.hasContour = fit.has_value();
        v.contour = fit ? fit->bits : 0;
      }
    });
    parentSlabs = std::move(slabs);
  }
}

// The grid's surface as octree levels; the grid and the color grid are let go once the finest voxels have
// their attributes.
template <class Grid>
SurfaceVolume voxelizeGrid(const fs::path& path, typename Grid::Ptr grid, double isovalue,
                           VolumeGridKind kind, volume_file::Vec3Sampler colors,
                           const BuildOptions& options) {
  // A fog volume's denser side is inside: its field is the threshold less the density.
  const bool fog = kind == VolumeGridKind::FogVolume;
  const double sign = fog ? -1.0 : 1.0;
  const double voxelSize = volume_file::cubicVoxelSize(path, *grid);
  const auto progress = [&](double f) {
    if (options.progress) options.progress(f);
  };
  SurfaceVolume out;
  VoxelLevels levels(std::size_t(options.levels) + 1);
  SurfacePoints points;
  {
    const Field<Grid> field(*grid, isovalue, sign);
    dvec3 lower, upper;
    const CellList cells = crossedCells(*grid, field, lower, upper);
    if (cells.empty())
      volume_file::fail(path, fmt::format("grid '{}' has no surface (no {} crossing in its active voxels)",
                                          grid->getName(), sign > 0.0 ? "zero" : "density threshold"));
    progress(0.2);
    const openvdb::math::Transform& transform = grid->transform();
    const auto world = [&](const dvec3& index) {
      const openvdb::Vec3d w = transform.indexToWorld(openvdb::Vec3d(index.x, index.y, index.z));
      return dvec3(w.x(), w.y(), w.z());
    };
    out.transform = fitSceneCube(world(lower), world(upper));
    Resampling resampling;
    resampling.side = 1 << options.levels;
    resampling.ratio = out.transform.size / double(resampling.side) / voxelSize;
    resampling.offset = (out.transform.origin - world(dvec3(0.0))) / voxelSize;
    for (const glm::ivec3& c : crossedVoxels(cells, field, resampling))
      levels.back().push_back(SliceVoxel{c});
    progress(0.4);
    points = leafAttributes(field, resampling, transform, colors, fog, levels.back());
  }
  const bool hasColors =
      fog ? volume_file::keepDensityWhereItVaries(levels.back(), bool(colors)) : bool(colors);
  grid.reset(), colors = volume_file::Vec3Sampler(nullptr);
  progress(0.7);
  volume_file::addCoarserLevels(levels, hasColors, true);
  if (options.contours) addContours(points, options, levels);
  points = {};
  progress(0.9);
  out.tree = treeOfLevels(levels, hasColors, true);
  progress(1.0);
  return out;
}

}  // namespace

SurfaceVolume voxelizeVolumeSurface(const fs::path& path, const VolumeImportOptions& import,
                                    const BuildOptions& options, BuildStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  voxel::checkLevels(options);
  // The grids it needs; the file's others go with the reader.
  auto [surface, colorValues] = [&] {
    const volume_file::Reader file(path);
    return std::pair(volume_file::readSurfaceGrid(file, import), volume_file::colorGrid(file, import));
  }();
  openvdb::GridBase::Ptr grid = std::move(surface.grid);
  volume_file::Vec3Sampler colors(std::move(colorValues));
  // The typed pointer is the grid's only owner: voxelizeGrid lets it go before the octree levels are made.
  SurfaceVolume out;
  if (auto floats = openvdb::gridPtrCast<openvdb::FloatGrid>(grid)) {
    grid.reset();
    out = voxelizeGrid<openvdb::FloatGrid>(path, std::move(floats), surface.isovalue, surface.kind,
                                           std::move(colors), options);
  } else {
    auto doubles = openvdb::gridPtrCast<openvdb::DoubleGrid>(grid);
    grid.reset();
    out = voxelizeGrid<openvdb::DoubleGrid>(path, std::move(doubles), surface.isovalue, surface.kind,
                                            std::move(colors), options);
  }
  if (stats) {
    addTreeStats(out.tree, 0, *stats);
    stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return out;
}

}  // namespace svo
