// Normal estimation for point clouds (points.hpp): k nearest neighbours by nanoflann's k-d tree, the tangent
// plane by Eigen's symmetric 3x3 eigen-solver, orientation along a minimum spanning tree (Hoppe et al. 1992).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>
#include <numeric>
#include <queue>
#include <tuple>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Eigenvalues>
#include <glm/geometric.hpp>
#include <nanoflann.hpp>

#include "svo/builder/points.hpp"

namespace svo {

namespace {

// nanoflann's view of the positions.
struct CloudAdaptor {
  const std::vector<glm::dvec3>& points;
  std::size_t kdtree_get_point_count() const { return points.size(); }
  double kdtree_get_pt(std::uint32_t i, std::size_t dim) const { return points[i][int(dim)]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;  // nanoflann computes the bounds itself
  }
};
using KdTree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, CloudAdaptor>,
                                                   CloudAdaptor, 3, std::uint32_t>;
// Points per k-d tree leaf: nanoflann's default.
constexpr std::size_t kKdLeafSize = 10;

// The k nearest neighbours of every point (itself included), k per point, nearest first.
std::vector<std::uint32_t> nearestNeighbours(const std::vector<glm::dvec3>& points, std::size_t k) {
  const CloudAdaptor adaptor{points};
  const KdTree tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(kKdLeafSize));
  std::vector<std::uint32_t> neighbours(points.size() * k);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, points.size()), [&](const auto& range) {
    std::vector<double> distances(k);
    for (std::size_t i = range.begin(); i < range.end(); ++i) {
      const double query[3] = {points[i].x, points[i].y, points[i].z};
      std::uint32_t* out = neighbours.data() + i * k;
      const std::size_t found = tree.knnSearch(query, k, out, distances.data());
      std::fill(out + found, out + k, std::uint32_t(i));  // fewer points than k: pad with itself
    }
  });
  return neighbours;
}

// The unit normal of the plane through the points (the covariance's smallest-eigenvalue eigenvector).
glm::vec3 planeNormal(const std::vector<glm::dvec3>& points, const std::uint32_t* indices, std::size_t k) {
  glm::dvec3 mean(0.0);
  for (std::size_t j = 0; j < k; ++j) mean += points[indices[j]];
  mean /= double(k);
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  for (std::size_t j = 0; j < k; ++j) {
    const glm::dvec3 d = points[indices[j]] - mean;
    const Eigen::Vector3d e(d.x, d.y, d.z);
    covariance += e * e.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(covariance);
  const Eigen::Vector3d n = solver.eigenvectors().col(0);  // eigenvalues ascend
  const glm::vec3 out(float(n.x()), float(n.y()), float(n.z()));
  const float len = glm::length(out);
  return std::isfinite(len) && len > 0.0f ? out / len : glm::vec3(0.0f, 0.0f, 1.0f);
}

// The symmetric neighbour graph in compressed rows: the k-nearest-neighbour relation and its converse.
struct Graph {
  std::vector<std::uint64_t> first;  // per point, into `next`; one past the end at the back
  std::vector<std::uint32_t> next;
};

Graph symmetricGraph(const std::vector<std::uint32_t>& neighbours, std::size_t n, std::size_t k) {
  Graph g;
  g.first.assign(n + 1, 0);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < k; ++j)
      if (const std::uint32_t o = neighbours[i * k + j]; o != i) ++g.first[i + 1], ++g.first[o + 1];
  std::partial_sum(g.first.begin(), g.first.end(), g.first.begin());
  g.next.resize(g.first.back());
  std::vector<std::uint64_t> fill(g.first.begin(), g.first.end() - 1);
  for (std::size_t i = 0; i < n; ++i)
    for (std::size_t j = 0; j < k; ++j)
      if (const std::uint32_t o = neighbours[i * k + j]; o != i)
        g.next[fill[i]++] = o, g.next[fill[o]++] = std::uint32_t(i);
  return g;
}

// Hoppe et al.'s orientation: Prim's minimum spanning tree over the graph with edge cost 1 - |ni.nj| (nearly
// parallel planes first), each point turned to agree with the tree neighbour it is reached from. The
// points in `fixed` (normals from the file) start the tree; each component without one starts at its
// highest point, turned to +z. Returns the number of flipped normals and of seeds.
std::pair<std::size_t, std::size_t> orient(std::vector<glm::vec3>& normals, const std::vector<bool>& fixed,
                                           const std::vector<glm::dvec3>& points, const Graph& g) {
  const std::size_t n = points.size();
  std::vector<bool> reached(n, false);
  // The cheapest edge seen into each point: only a cheaper one is queued (Prim's key decrease, lazily).
  std::vector<float> best(n, std::numeric_limits<float>::infinity());
  using Entry = std::tuple<float, std::uint32_t, std::uint32_t>;  // cost, point, reached from
  std::priority_queue<Entry, std::vector<Entry>, std::greater<>> frontier;
  std::size_t flipped = 0, seeds = 0;
  const auto reach = [&](std::uint32_t i) {
    reached[i] = true;
    for (std::uint64_t e = g.first[i]; e < g.first[i + 1]; ++e)
      if (const std::uint32_t o = g.next[e]; !reached[o]) {
        const float cost = 1.0f - std::abs(glm::dot(normals[i], normals[o]));
        if (cost < best[o]) best[o] = cost, frontier.emplace(cost, o, i);
      }
  };
  const auto grow = [&] {
    while (!frontier.empty()) {
      const auto [cost, i, from] = frontier.top();
      frontier.pop();
      if (reached[i]) continue;
      if (!fixed[i] && glm::dot(normals[i], normals[from]) < 0.0f) normals[i] = -normals[i], ++flipped;
      reach(i);
    }
  };
  for (std::uint32_t i = 0; i < n; ++i)
    if (fixed[i]) reach(i);
  if (std::find(fixed.begin(), fixed.end(), true) != fixed.end()) ++seeds;
  grow();
  std::vector<std::uint32_t> byHeight(n);
  std::iota(byHeight.begin(), byHeight.end(), 0u);
  std::stable_sort(byHeight.begin(), byHeight.end(),
                   [&](std::uint32_t a, std::uint32_t b) { return points[a].z > points[b].z; });
  for (const std::uint32_t seed : byHeight) {
    if (reached[seed]) continue;
    if (normals[seed].z < 0.0f) normals[seed] = -normals[seed], ++flipped;
    ++seeds;
    reach(seed);
    grow();
  }
  return {flipped, seeds};
}

}  // namespace

double estimatePointSpacing(const std::vector<glm::dvec3>& sample, std::uint64_t total) {
  if (sample.size() < 2 || total < sample.size()) return 0.0;
  const std::size_t k = std::min<std::size_t>(std::size_t(kNormalNeighbours), sample.size());
  const CloudAdaptor adaptor{sample};
  const KdTree tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(kKdLeafSize));
  std::vector<double> spacing(sample.size());
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, sample.size()), [&](const auto& range) {
    std::vector<std::uint32_t> indices(k);
    std::vector<double> squared(k);
    for (std::size_t i = range.begin(); i < range.end(); ++i) {
      const double query[3] = {sample[i].x, sample[i].y, sample[i].z};
      const std::size_t found = tree.knnSearch(query, k, indices.data(), squared.data());
      // pi r^2 holds found - 1 other points: each owns pi r^2 / (found - 1) of the surface.
      spacing[i] = std::sqrt(std::numbers::pi * squared[found - 1] / double(found - 1));
    }
  });
  const auto middle = spacing.begin() + std::ptrdiff_t(spacing.size() / 2);
  std::nth_element(spacing.begin(), middle, spacing.end());
  return *middle * std::sqrt(double(sample.size()) / double(total));
}

double estimatePointSpacing(const PointCloud& cloud) {
  const std::size_t n = cloud.positions.size(), stride = std::max<std::size_t>(1, n / kSpacingSamples);
  std::vector<glm::dvec3> sample;
  sample.reserve(n / stride + 1);
  for (std::size_t i = 0; i < n; i += stride) sample.push_back(cloud.positions[i]);
  return estimatePointSpacing(sample, n);
}

int levelsForSpacing(double spacing, const SceneTransform& transform) {
  if (!(spacing > 0.0)) return kMaxPointLevels;
  const double level = std::floor(std::log2(transform.size / (kVoxelsPerSpacing * spacing)));
  return int(std::clamp(level, 1.0, double(kMaxPointLevels)));
}

NormalEstimate estimateNormals(PointCloud& cloud, int neighbours) {
  const std::size_t n = cloud.positions.size();
  NormalEstimate report;
  if (cloud.normals.size() != n) cloud.normals.assign(n, glm::vec3(0.0f));
  std::vector<bool> fixed(n);
  for (std::size_t i = 0; i < n; ++i) fixed[i] = glm::dot(cloud.normals[i], cloud.normals[i]) > 0.0f;
  report.estimated = std::size_t(std::count(fixed.begin(), fixed.end(), false));
  if (report.estimated == 0) return report;
  const std::size_t k = std::clamp<std::size_t>(std::size_t(std::max(neighbours, 1)), 1, n);
  const std::vector<std::uint32_t> knn = nearestNeighbours(cloud.positions, k);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, n), [&](const auto& range) {
    for (std::size_t i = range.begin(); i < range.end(); ++i)
      if (!fixed[i]) cloud.normals[i] = planeNormal(cloud.positions, knn.data() + i * k, k);
  });
  const Graph graph = symmetricGraph(knn, n, k);
  std::tie(report.flipped, report.components) = orient(cloud.normals, fixed, cloud.positions, graph);
  return report;
}

}  // namespace svo
