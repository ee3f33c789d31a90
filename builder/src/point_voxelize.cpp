// Point clouds into octree levels (points.hpp): points sorted by their finest voxel's Morton code, so that
// every voxel of every level owns one contiguous run of them; voxels made bottom-up by merging runs, then
// each voxel's attributes and contour from its run, and the levels handed to treeOfLevels as a voxel mask's
// are.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <glm/geometric.hpp>

#include "svo/builder/points.hpp"
#include "svo/store/format.hpp"

namespace svo {

namespace {

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

// The slab along the voxel's stored normal that holds its points, when it trims at least `minCut` (voxel
// widths) off the cube's extent along that normal (as the mesh builder's chooseContour measures a cut).
bool fitContour(const PointCloud& cloud, const PointOrder& order, const Node& node, int level,
                const SceneTransform& transform, std::uint32_t normalBits, double minCut,
                std::uint32_t& bits) {
  const glm::ivec3 qn = quantizeContourNormal(glm::dvec3(normalDirection(normalBits)));
  const glm::dvec3 n = glm::dvec3(qn) / double(kContourNormalScale);
  const double voxel = std::ldexp(1.0, -level);
  const glm::dvec3 centre = 1.0 + (glm::dvec3(coordOf(node.code)) + 0.5) * voxel;
  double lo = 1e300, hi = -1e300;
  for (std::uint32_t i = node.begin; i < node.end; ++i) {
    const double d = glm::dot(n, transform.toOctree(cloud.positions[order[i].second]) - centre) / voxel;
    lo = std::min(lo, d), hi = std::max(hi, d);
  }
  if (!encodeContour(qn, lo, hi, bits)) return false;
  const Contour c = decodeContour(bits);
  const double hullHi = 0.5 * (std::abs(n.x) + std::abs(n.y) + std::abs(n.z)), hullLo = -hullHi;
  const double slabLo = c.position - 0.5 * c.thickness, slabHi = c.position + 0.5 * c.thickness;
  const double cut = std::max(0.0, slabLo - hullLo) + std::max(0.0, hullHi - slabHi);
  return cut > 0.0 && cut >= minCut;
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
  std::vector<Node> in = finestNodes(cloud, order);
  for (int level = levels; level >= 0; --level) {
    std::vector<SliceVoxel>& voxels = out[std::size_t(level)];
    voxels.resize(in.size());
    const double minCut =
        level == levels ? options.leafContourMinReduction : options.innerContourMinReduction;
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
        // The scene's root keeps no contour (the store keeps its attributes only).
        v.hasContour = options.contours && level > 0 &&
                       fitContour(cloud, order, node, level, transform, v.normal, minCut, v.contour);
      }
    });
    if (level > 0) in = parentNodes(in);
    if (options.progress) options.progress(double(levels + 1 - level) / double(levels + 1));
  }
  VoxelTree tree = treeOfLevels(out, colors, true);
  if (stats) {
    addTreeStats(tree, 0, *stats);
    stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
  return tree;
}

}  // namespace svo
