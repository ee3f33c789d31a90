// Point clouds into octree levels (points.hpp): points sorted by their finest voxel's Morton code, so that
// every voxel of every level owns one contiguous run of them; voxels made bottom-up by merging runs, then
// each voxel's attributes and contour from its run, and the levels handed to treeOfLevels as a voxel mask's
// are.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <glm/geometric.hpp>

#include "svo/builder/points.hpp"
#include "svo/store/format.hpp"
#include "voxel_kernels.hpp"

namespace svo {

namespace {

using voxel::chooseContour;
using voxel::ContourFit;
using voxel::Direction;
using voxel::Extent;
using voxel::slabOf;

// How far (voxel widths) a contour's slab reaches past its voxel's points on either side. The points are
// samples: between them the surface leaves a slab fitted to them exactly, and rays pass through the cracks
// between neighbouring voxels' slabs to the far side. Measured on a 2M-point sphere at 9 levels, 256^2
// pixels differing from the cube voxels' image (cracks): 0.125, 0.25, 0.5 -> 92, 63, 22 pixels, 0.5 leaving
// the silhouette's differences only.
constexpr double kSlabMargin = 0.5;

std::uint64_t spreadBits(std::uint32_t v) {
  std::uint64_t out = 0;
  for (int b = 0; b < kMaxPointLevels; ++b) out |= std::uint64_t((v >> b) & 1u) << (3 * b);
  return out;
}
std::uint32_t gatherBits(std::uint64_t v) {
  std::uint32_t out = 0;
  for (int b = 0; b < kMaxPointLevels; ++b) out |= std::uint32_t((v >> (3 * b)) & 1u) << b;
  return out;
}
// Morton code with x in bit 0, y in bit 1, z in bit 2 of each level (mortonLess's order).
std::uint64_t mortonOf(glm::ivec3 c) {
  return spreadBits(std::uint32_t(c.x)) | spreadBits(std::uint32_t(c.y)) << 1 |
         spreadBits(std::uint32_t(c.z)) << 2;
}
glm::ivec3 coordOf(std::uint64_t code) {
  return glm::ivec3(int(gatherBits(code)), int(gatherBits(code >> 1)), int(gatherBits(code >> 2)));
}

// A voxel's points: a run of the sorted points.
struct Run {
  std::uint32_t begin = 0, end = 0;
};

// A voxel of one level: its Morton code at that level, its run of sorted points and the sums over them.
struct Node {
  std::uint64_t code = 0;
  std::uint32_t begin = 0, end = 0;
  std::uint8_t childMask = 0;
  glm::dvec4 color{0.0};
  glm::dvec3 normal{0.0};
};

// The finest level: one node per run of points with one code.
using PointOrder = std::vector<std::pair<std::uint64_t, std::uint32_t>>;  // (finest Morton code, point)

std::vector<Node> finestNodes(const PointCloud& cloud, const PointOrder& order) {
  std::vector<Node> nodes;
  for (std::uint32_t i = 0; i < order.size(); ++i) {
    if (nodes.empty() || nodes.back().code != order[i].first) nodes.push_back(Node{order[i].first, i, i});
    Node& n = nodes.back();
    n.end = i + 1;
    const std::uint32_t p = order[i].second;
    n.normal += glm::dvec3(cloud.normals[p]);
    if (!cloud.colors.empty()) n.color += glm::dvec4(cloud.colors[p]);
  }
  return nodes;
}

// The level above: children with one parent code merged, their sums added.
std::vector<Node> parentNodes(const std::vector<Node>& children) {
  std::vector<Node> parents;
  for (const Node& c : children) {
    if (parents.empty() || parents.back().code != c.code >> 3) parents.push_back(Node{c.code >> 3, c.begin});
    Node& p = parents.back();
    p.end = c.end;
    p.childMask |= std::uint8_t(1u << (c.code & 7u));
    p.color += c.color, p.normal += c.normal;
  }
  return parents;
}

// A voxel's cube in the octree frame.
geom::Cube cubeOf(glm::ivec3 coord, int level) {
  const double size = std::ldexp(1.0, -level);
  return {1.0 + glm::dvec3(coord) * size, size};
}

// The slabs that bound a voxel's shape from above (sec. 5.3): its ancestors' contours that still cut its
// cube, the finest few, as many as the hull uses.
struct Bounds {
  std::array<geom::Slab, geom::kMaxHullSlabs> slabs;
  std::uint8_t count = 0;
};

Bounds boundsOf(const Bounds& parent, const SliceVoxel& parentVoxel, int parentLevel,
                const geom::Cube& cube) {
  std::array<geom::Slab, geom::kMaxHullSlabs + 1> all;
  std::size_t n = 0;
  for (std::uint8_t k = 0; k < parent.count; ++k) all[n++] = parent.slabs[k];
  if (parentVoxel.hasContour) all[n++] = slabOf(cubeOf(parentVoxel.coord, parentLevel), parentVoxel.contour);
  Bounds out;
  for (std::size_t k = 0; k < n; ++k)
    if (geom::slabCutsCube(all[k], cube)) {
      if (out.count == out.slabs.size())  // the oldest gives way
        std::move(out.slabs.begin() + 1, out.slabs.end(), out.slabs.begin()), --out.count;
      out.slabs[out.count++] = all[k];
    }
  return out;
}

// The voxel's contour, as the mesh builder chooses one (chooseContour): the slab along its stored normal that
// holds its points, kept where it trims at least `minCut` voxel widths off its ancestor-bounded hull.
std::optional<ContourFit> fitContour(const PointCloud& cloud, const PointOrder& order, Run run,
                                     const SliceVoxel& voxel, const geom::Cube& cube, const Bounds& bounds,
                                     const SceneTransform& transform, double minCut) {
  const glm::ivec3 qn = quantizeContourNormal(glm::dvec3(normalDirection(voxel.normal)));
  const std::vector<Direction> direction{{qn, glm::dvec3(qn) / double(kContourNormalScale)}};
  std::vector<Extent> extent(1);
  const glm::dvec3 centre = cube.centre();
  for (std::uint32_t i = run.begin; i < run.end; ++i) {
    const glm::dvec3 p = transform.toOctree(cloud.positions[order[i].second]);
    const double d = glm::dot(direction[0].normal, p - centre) / cube.size;
    extent[0].lo = std::min(extent[0].lo, d), extent[0].hi = std::max(extent[0].hi, d);
  }
  extent[0].lo -= kSlabMargin, extent[0].hi += kSlabMargin;
  return chooseContour(cube, direction, extent, {bounds.slabs.begin(), bounds.slabs.begin() + bounds.count},
                       minCut);
}

// Contours from the root down, each voxel's decided against the slabs its ancestors' decisions left.
void addContours(const PointCloud& cloud, const PointOrder& order, const std::vector<std::vector<Run>>& runs,
                 const SceneTransform& transform, const BuildOptions& options, VoxelLevels& levels) {
  std::vector<Bounds> parentBounds(1);  // the root keeps no contour (the store keeps its attributes only)
  for (int level = 1; level < int(levels.size()); ++level) {
    const std::vector<SliceVoxel>& parents = levels[std::size_t(level) - 1];
    std::vector<SliceVoxel>& voxels = levels[std::size_t(level)];
    std::vector<std::uint32_t> parentOf(voxels.size());
    for (std::uint32_t i = 0, p = 0; i < voxels.size(); ++i) {
      while (parents[p].coord != voxels[i].coord >> 1) ++p;
      parentOf[i] = p;
    }
    const double minCut =
        level == int(levels.size()) - 1 ? options.leafContourMinReduction : options.innerContourMinReduction;
    std::vector<Bounds> bounds(voxels.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, voxels.size()), [&](const auto& range) {
      for (std::size_t i = range.begin(); i < range.end(); ++i) {
        const geom::Cube cube = cubeOf(voxels[i].coord, level);
        bounds[i] = boundsOf(parentBounds[parentOf[i]], parents[parentOf[i]], level - 1, cube);
        const std::optional<ContourFit> fit = fitContour(cloud, order, runs[std::size_t(level)][i], voxels[i],
                                                         cube, bounds[i], transform, minCut);
        voxels[i].hasContour = fit.has_value();
        voxels[i].contour = fit ? fit->bits : 0;
      }
    });
    parentBounds = std::move(bounds);
  }
}

// The points by their finest voxel's Morton code (then by index).
PointOrder sortedPoints(const PointCloud& cloud, const SceneTransform& transform, int levels) {
  const double side = std::ldexp(1.0, levels);
  const int last = (1 << levels) - 1;
  PointOrder order(cloud.positions.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, order.size()), [&](const auto& range) {
    for (std::size_t i = range.begin(); i < range.end(); ++i) {
      const glm::dvec3 u = (transform.toOctree(cloud.positions[i]) - 1.0) * side;
      const glm::ivec3 c = glm::clamp(glm::ivec3(glm::floor(u)), glm::ivec3(0), glm::ivec3(last));
      order[i] = {mortonOf(c), std::uint32_t(i)};
    }
  });
  tbb::parallel_sort(order.begin(), order.end());
  return order;
}

}  // namespace

SceneTransform fitSceneCube(const PointCloud& cloud) {
  if (cloud.positions.empty()) throw std::runtime_error("no points");
  glm::dvec3 lo(cloud.positions.front()), hi(lo);
  for (const glm::dvec3& p : cloud.positions) lo = glm::min(lo, p), hi = glm::max(hi, p);
  if (!(glm::any(glm::greaterThan(hi, lo))))
    throw std::runtime_error("the points have no extent: all coincide");
  return fitSceneCube(lo, hi);
}

VoxelTree voxelizePoints(const PointCloud& cloud, const SceneTransform& transform,
                         const BuildOptions& options, BuildStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  const int levels = options.levels;
  if (levels < 1 || levels > kMaxPointLevels)
    throw std::runtime_error("point clouds build 1 to " + std::to_string(kMaxPointLevels) + " levels, not " +
                             std::to_string(levels));
  if (cloud.positions.empty()) throw std::runtime_error("no points");
  if (cloud.positions.size() > std::size_t(UINT32_MAX)) throw std::runtime_error("more than 2^32 - 1 points");
  if (cloud.normals.size() != cloud.positions.size())
    throw std::runtime_error("voxelizePoints needs a normal per point (estimateNormals)");
  const auto order = sortedPoints(cloud, transform, levels);

  // Level by level from the finest up: a level's nodes make its voxels, then its parents' nodes, and go.
  const bool colors = !cloud.colors.empty();
  VoxelLevels out(std::size_t(levels) + 1);
  std::vector<std::vector<Run>> runs(std::size_t(levels) + 1);
  std::vector<Node> in = finestNodes(cloud, order);
  for (int level = levels; level >= 0; --level) {
    std::vector<SliceVoxel>& voxels = out[std::size_t(level)];
    voxels.resize(in.size());
    runs[std::size_t(level)].resize(in.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, in.size()), [&](const auto& range) {
      for (std::size_t i = range.begin(); i < range.end(); ++i) {
        const Node& node = in[i];
        SliceVoxel& v = voxels[i];
        v.coord = coordOf(node.code);
        v.childMask = node.childMask;
        const double count = double(node.end - node.begin);
        if (colors) v.color = encodeColor(glm::vec4(node.color / count));
        // Normals that cancel out (a thin sheet seen from both sides) leave the first point's.
        glm::dvec3 n = node.normal;
        if (!(glm::dot(n, n) > 1e-24)) n = glm::dvec3(cloud.normals[order[node.begin].second]);
        if (!(glm::dot(n, n) > 1e-24)) n = glm::dvec3(0.0, 0.0, 1.0);
        v.normal = latticeNormal(glm::vec3(glm::normalize(n)));
        runs[std::size_t(level)][i] = {node.begin, node.end};
      }
    });
    if (level > 0) in = parentNodes(in);
    if (options.progress) options.progress(double(levels + 1 - level) / double(levels + 1));
  }
  if (options.contours) addContours(cloud, order, runs, transform, options, out);
  runs = {};
  VoxelTree tree = treeOfLevels(out, colors, true);
  if (stats) {
    addTreeStats(tree, 0, *stats);
    stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return tree;
}

}  // namespace svo
