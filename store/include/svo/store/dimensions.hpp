// Dimensional analysis of a store's voxels (paper sec. 4): how the data a view needs grows with the view's
// extent and its resolution.
//
// Levels, not scales: a cube of *cube level* c has edge 2^-c of the scene cube, a voxel of *voxel level* L
// edge 2^-L (the paper's l = -c and s = -L). N(c, L) is the mean count of non-empty voxels of level L inside
// a cube of level c around a point of the content. The paper leaves the average over cube positions open;
// here the points are the voxels of the finest level F (each one point), and each point's cube is the cube
// of the octree's level-c grid that holds it:
//   N(c, L) = sum over the level-c voxels x of n_F(x) n_L(x)  /  sum over them of n_F(x),
// n_L(x) being the level-L voxels inside x. Weighting by content, not by occupied cubes, is what a viewer
// sees: a camera stands near content, and a cube holding more content is looked at more. (Counting each
// occupied cube once would give N(c, L) = V(L) / V(c) from the per-level totals V, whose local dimension
// does not depend on the cube and whose global one does not depend on the voxels.) Grid cubes, not cubes
// centred on each point, are what the pager loads, and they make the mean exact in one pass over the slices.
//
// From N (the paper's definitions, in levels; each needs the levels it names to lie in [c, F]):
//   D_local(c, L)  = log2 N(c, L) / N(c, L - 1)       voxels halved: 3 for a volume, 2 a surface, 1 a line
//   D_global(c, L) = log2 N(c - 1, L) / N(c, L)       cube doubled
//   D_scale(c, L)  = log2 N(c - 1, L - 1) / N(c, L)   both: D_global(c, L) - D_local(c - 1, L)
// Doubling a view's distance doubles its extent and its voxels (c - 1, L - 1): data x 2^D_scale; doubling
// its image size halves its voxels (L + 1): data x 2^D_local(c, L + 1).
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "svo/store/store_reader.hpp"

namespace svo {

class VoxelDimensions {
 public:
  // From the sums S(c, L) = sum over level-c voxels x of n_F(x) n_L(x), for 0 <= c <= L <= F (row c,
  // column L of a (F + 1)^2 matrix; the rest unused), and the voxels per level V(0..F). Throws
  // std::invalid_argument when the sizes disagree or a level holds no voxel.
  VoxelDimensions(std::vector<double> sums, std::vector<std::uint64_t> voxels);

  int finestLevel() const { return finest_; }
  std::uint64_t voxels(int level) const { return voxels_.at(std::size_t(level)); }
  // N(c, L) for 0 <= c <= L <= F. A cube no larger than the voxels (c >= L) holds one of them.
  double count(int cubeLevel, int voxelLevel) const;
  // NaN where a level it needs lies outside [0, F] or the voxels would exceed the cube.
  double local(int cubeLevel, int voxelLevel) const;
  double global(int cubeLevel, int voxelLevel) const;
  double scale(int cubeLevel, int voxelLevel) const;

  // The data a view holds in a cube of level c when it resolves level L: every level down to L (a view
  // loads the coarser levels too), sum over L' <= L of N(c, L') weights[L'] (`weights`: what a voxel of each
  // level 0 to F weighs, its bytes say; empty: 1, voxels). Fractional levels interpolate log2 of it linearly
  // between whole ones; c < 0 is a cube larger than the scene, which holds all of it (as c = 0), and L is
  // clamped to [0, F]: the store has nothing finer.
  double viewData(double cubeLevel, double voxelLevel, std::span<const double> weights = {}) const;

 private:
  double sum(int c, int l) const { return sums_[std::size_t(c) * std::size_t(finest_ + 1) + std::size_t(l)]; }
  double viewDataAt(int c, int l, std::span<const double> weights) const;  // whole levels in [0, F]

  int finest_ = 0;
  std::vector<double> sums_;
  std::vector<std::uint64_t> voxels_;
};

// Measures N over every voxel of the store: one depth-first walk over the slice hierarchy
// (StoreReader::walk, so every slice is checked as `svo verify` checks it), holding one chain of slices and
// a count per level below each of their voxels. `progress` receives the fraction of slices walked. Throws
// what the walk throws.
VoxelDimensions measureDimensions(const StoreReader& reader,
                                  const std::function<void(double)>& progress = nullptr);

}  // namespace svo
