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

#include "point_voxelize.hpp"
#include "svo/builder/points.hpp"
#include "svo/store/format.hpp"
#include "voxel_kernels.hpp"

namespace svo {

namespace detail {

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

using PointOrder = std::vector<std::pair<std::uint64_t, std::uint32_t>>;  // (finest Morton code, point)

// The finest level: one node per run of points with one code.
std::vector<PointNode> finestNodes(const PointCloud& cloud, const PointOrder& order) {
  std::vector<PointNode> nodes;
  for (std::uint32_t i = 0; i < order.size(); ++i) {
    const std::uint32_t p = order[i].second;
    if (nodes.empty() || nodes.back().code != order[i].first) {
      nodes.push_back(PointNode{order[i].first, i, i});
      nodes.back().sums.first = cloud.normals[p];
    }
    PointNode& n = nodes.back();
    n.end = i + 1;
    ++n.sums.count;
    n.sums.normal += glm::dvec3(cloud.normals[p]);
    if (!cloud.colors.empty()) n.sums.color += glm::dvec4(cloud.colors[p]);
  }
  return nodes;
}

// A voxel's cube in the octree frame.
geom::Cube cubeOf(glm::ivec3 coord, int level) {
  const double size = std::ldexp(1.0, -level);
  return {1.0 + glm::dvec3(coord) * size, size};
}

double minCutAt(const BuildOptions& options, int level) {
  return level == options.levels ? options.leafContourMinReduction : options.innerContourMinReduction;
}

// The extent of a voxel's run of points.
PointExtent extentOf(const PointCloud& cloud, const PointOrder& order, Run run, const SliceVoxel& voxel,
                     int level, const SceneTransform& transform) {
  PointExtent extent;
  for (std::uint32_t i = run.begin; i < run.end; ++i)
    extend(extent, voxel, level, transform.toOctree(cloud.positions[order[i].second]));
  return extent;
}

// Contours from the root down, each voxel's decided against the slabs its ancestors' decisions left; out[0]
// is a voxel of `rootLevel`.
void addContours(const PointCloud& cloud, const PointOrder& order, const std::vector<std::vector<Run>>& runs,
                 const SceneTransform& transform, const BuildOptions& options, int rootLevel,
                 const PointBounds& rootBounds, VoxelLevels& levels) {
  std::vector<PointBounds> parentBounds{rootBounds};
  if (rootLevel > 0)  // the root keeps no contour (the store keeps its attributes only)
    decideContour(levels[0][0], rootLevel, rootBounds,
                  extentOf(cloud, order, runs[0][0], levels[0][0], rootLevel, transform),
                  minCutAt(options, rootLevel));
  for (std::size_t k = 1; k < levels.size(); ++k) {
    const int level = rootLevel + int(k);
    const std::vector<SliceVoxel>& parents = levels[k - 1];
    std::vector<SliceVoxel>& voxels = levels[k];
    std::vector<std::uint32_t> parentOf(voxels.size());
    for (std::uint32_t i = 0, p = 0; i < voxels.size(); ++i) {
      while (parents[p].coord != voxels[i].coord >> 1) ++p;
      parentOf[i] = p;
    }
    std::vector<PointBounds> bounds(voxels.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, voxels.size()), [&](const auto& range) {
      for (std::size_t i = range.begin(); i < range.end(); ++i) {
        bounds[i] =
            boundsOf(parentBounds[parentOf[i]], parents[parentOf[i]], level - 1, voxels[i].coord, level);
        decideContour(voxels[i], level, bounds[i],
                      extentOf(cloud, order, runs[k][i], voxels[i], level, transform),
                      minCutAt(options, level));
      }
    });
    parentBounds = std::move(bounds);
  }
}

// The points by their finest voxel's Morton code (then by index).
PointOrder sortedPoints(const PointCloud& cloud, const SceneTransform& transform, int levels) {
  PointOrder order(cloud.positions.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, order.size()), [&](const auto& range) {
    for (std::size_t i = range.begin(); i < range.end(); ++i)
      order[i] = {mortonOf(pointVoxel(transform, cloud.positions[i], levels)), std::uint32_t(i)};
  });
  tbb::parallel_sort(order.begin(), order.end());
  return order;
}

}  // namespace

glm::ivec3 pointVoxel(const SceneTransform& transform, glm::dvec3 world, int level) {
  const glm::dvec3 u = (transform.toOctree(world) - 1.0) * std::ldexp(1.0, level);
  return glm::clamp(glm::ivec3(glm::floor(u)), glm::ivec3(0), glm::ivec3((1 << level) - 1));
}

std::vector<PointNode> parentNodes(const std::vector<PointNode>& children) {
  std::vector<PointNode> parents;
  for (const PointNode& c : children) {
    if (parents.empty() || parents.back().code != c.code >> 3) {
      parents.push_back(PointNode{c.code >> 3, c.begin});
      parents.back().sums.first = c.sums.first;
    }
    PointNode& p = parents.back();
    p.end = c.end;
    p.childMask |= std::uint8_t(1u << (c.code & 7u));
    p.sums.count += c.sums.count;
    p.sums.color += c.sums.color, p.sums.normal += c.sums.normal;
  }
  return parents;
}

SliceVoxel voxelOf(const PointNode& node, bool colors) {
  SliceVoxel v;
  v.coord = coordOf(node.code);
  v.childMask = node.childMask;
  if (colors) v.color = encodeColor(glm::vec4(node.sums.color / double(node.sums.count)));
  // Normals that cancel out (a thin sheet seen from both sides) leave the first point's.
  glm::dvec3 n = node.sums.normal;
  if (!(glm::dot(n, n) > 1e-24)) n = glm::dvec3(node.sums.first);
  if (!(glm::dot(n, n) > 1e-24)) n = glm::dvec3(0.0, 0.0, 1.0);
  v.normal = latticeNormal(glm::vec3(glm::normalize(n)));
  return v;
}

PointBounds boundsOf(const PointBounds& parent, const SliceVoxel& parentVoxel, int parentLevel,
                     glm::ivec3 coord, int level) {
  const geom::Cube cube = cubeOf(coord, level);
  std::array<geom::Slab, geom::kMaxHullSlabs + 1> all;
  std::size_t n = 0;
  for (std::uint8_t k = 0; k < parent.count; ++k) all[n++] = parent.slabs[k];
  if (parentVoxel.hasContour) all[n++] = slabOf(cubeOf(parentVoxel.coord, parentLevel), parentVoxel.contour);
  PointBounds out;
  for (std::size_t k = 0; k < n; ++k)
    if (geom::slabCutsCube(all[k], cube)) {
      if (out.count == out.slabs.size())  // the oldest gives way
        std::move(out.slabs.begin() + 1, out.slabs.end(), out.slabs.begin()), --out.count;
      out.slabs[out.count++] = all[k];
    }
  return out;
}

void extend(PointExtent& extent, const SliceVoxel& voxel, int level, glm::dvec3 octreePoint) {
  const glm::ivec3 qn = quantizeContourNormal(glm::dvec3(normalDirection(voxel.normal)));
  const geom::Cube cube = cubeOf(voxel.coord, level);
  const double d =
      glm::dot(glm::dvec3(qn) / double(kContourNormalScale), octreePoint - cube.centre()) / cube.size;
  extent.lo = std::min(extent.lo, d), extent.hi = std::max(extent.hi, d);
}

void decideContour(SliceVoxel& voxel, int level, const PointBounds& bounds, PointExtent extent,
                   double minCut) {
  const glm::ivec3 qn = quantizeContourNormal(glm::dvec3(normalDirection(voxel.normal)));
  const std::vector<Direction> direction{{qn, glm::dvec3(qn) / double(kContourNormalScale)}};
  const std::vector<Extent> extents{{extent.lo - kSlabMargin, extent.hi + kSlabMargin}};
  const std::optional<ContourFit> fit =
      chooseContour(cubeOf(voxel.coord, level), direction, extents,
                    {bounds.slabs.begin(), bounds.slabs.begin() + bounds.count}, minCut);
  voxel.hasContour = fit.has_value();
  voxel.contour = fit ? fit->bits : 0;
}

VoxelLevels pointLevels(const PointCloud& cloud, const SceneTransform& transform, const BuildOptions& options,
                        int rootLevel, const PointBounds& rootBounds, PointNode* root) {
  const int levels = options.levels;
  const auto order = sortedPoints(cloud, transform, levels);
  // Level by level from the finest up: a level's nodes make its voxels, then its parents' nodes, and go.
  const bool colors = !cloud.colors.empty();
  const std::size_t depth = std::size_t(levels - rootLevel);
  VoxelLevels out(depth + 1);
  std::vector<std::vector<Run>> runs(depth + 1);
  std::vector<PointNode> in = finestNodes(cloud, order);
  for (std::size_t k = depth + 1; k-- > 0;) {
    out[k].resize(in.size());
    runs[k].resize(in.size());
    tbb::parallel_for(tbb::blocked_range<std::size_t>(0, in.size()), [&](const auto& range) {
      for (std::size_t i = range.begin(); i < range.end(); ++i) {
        out[k][i] = voxelOf(in[i], colors);
        runs[k][i] = {in[i].begin, in[i].end};
      }
    });
    if (k > 0) in = parentNodes(in);
    if (options.progress) options.progress(double(depth + 1 - k) / double(depth + 1));
  }
  if (in.size() != 1) throw std::logic_error("pointLevels: the points span several voxels of the root level");
  if (root) *root = in[0];
  if (options.contours) addContours(cloud, order, runs, transform, options, rootLevel, rootBounds, out);
  return out;
}

PointNode pointRoot(const PointCloud& cloud, const SceneTransform& transform, int levels, int rootLevel) {
  std::vector<PointNode> nodes = finestNodes(cloud, sortedPoints(cloud, transform, levels));
  for (int level = levels; level > rootLevel; --level) nodes = parentNodes(nodes);
  if (nodes.size() != 1)
    throw std::logic_error("pointRoot: the points span several voxels of the root level");
  return nodes[0];
}

}  // namespace detail

SceneTransform fitSceneCube(const PointCloud& cloud) {
  if (cloud.positions.empty()) throw std::runtime_error("no points");
  glm::dvec3 lo(cloud.positions.front()), hi(lo);
  for (const glm::dvec3& p : cloud.positions) lo = glm::min(lo, p), hi = glm::max(hi, p);
  if (!(glm::any(glm::greaterThan(hi, lo))))
    throw std::runtime_error("the points have no extent: all coincide");
  return fitSceneCube(lo, hi);
}

void checkPointBuild(const PointCloud& cloud, const BuildOptions& options) {
  if (options.levels < 1 || options.levels > kMaxPointLevels)
    throw std::runtime_error("point clouds build 1 to " + std::to_string(kMaxPointLevels) + " levels, not " +
                             std::to_string(options.levels));
  if (cloud.positions.empty()) throw std::runtime_error("no points");
  if (cloud.positions.size() > std::size_t(UINT32_MAX)) throw std::runtime_error("more than 2^32 - 1 points");
  if (cloud.normals.size() != cloud.positions.size())
    throw std::runtime_error("voxelizePoints needs a normal per point (estimateNormals)");
}

VoxelTree voxelizePoints(const PointCloud& cloud, const SceneTransform& transform,
                         const BuildOptions& options, BuildStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  checkPointBuild(cloud, options);
  VoxelTree tree =
      treeOfLevels(detail::pointLevels(cloud, transform, options, 0, {}), !cloud.colors.empty(), true);
  if (stats) {
    addTreeStats(tree, 0, *stats);
    stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return tree;
}

}  // namespace svo
