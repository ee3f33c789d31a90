#include "svo/store/dimensions.hpp"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <stdexcept>
#include <string>
#include <utility>

namespace svo {

VoxelDimensions::VoxelDimensions(std::vector<double> sums, std::vector<std::uint64_t> voxels)
    : finest_(int(voxels.size()) - 1), sums_(std::move(sums)), voxels_(std::move(voxels)) {
  if (voxels_.empty() || sums_.size() != voxels_.size() * voxels_.size())
    throw std::invalid_argument("dimensions: " + std::to_string(sums_.size()) + " sums for " +
                                std::to_string(voxels_.size()) + " levels");
  for (std::size_t l = 0; l < voxels_.size(); ++l)
    if (voxels_[l] == 0) throw std::invalid_argument("dimensions: level " + std::to_string(l) + " is empty");
}

double VoxelDimensions::count(int cubeLevel, int voxelLevel) const {
  if (voxelLevel < 0 || voxelLevel > finest_ || cubeLevel < 0)
    throw std::out_of_range("dimensions: N(" + std::to_string(cubeLevel) + ", " + std::to_string(voxelLevel) +
                            ") outside the levels 0 to " + std::to_string(finest_));
  // A cube inside a voxel of level L holds that one voxel.
  if (cubeLevel >= voxelLevel) return 1.0;
  return sum(cubeLevel, voxelLevel) / double(voxels_[std::size_t(finest_)]);
}

double VoxelDimensions::local(int c, int l) const {
  if (c < 0 || c > l - 1 || l > finest_) return NAN;
  return std::log2(count(c, l) / count(c, l - 1));
}

double VoxelDimensions::global(int c, int l) const {
  if (c < 1 || c > l || l > finest_) return NAN;
  return std::log2(count(c - 1, l) / count(c, l));
}

double VoxelDimensions::scale(int c, int l) const {
  if (c < 1 || c > l || l > finest_) return NAN;
  return std::log2(count(c - 1, l - 1) / count(c, l));
}

double VoxelDimensions::viewDataAt(int c, int l, std::span<const double> weights) const {
  double total = 0.0;
  for (int k = 0; k <= l; ++k) total += count(c, k) * (weights.empty() ? 1.0 : weights[std::size_t(k)]);
  return total;
}

double VoxelDimensions::viewData(double cubeLevel, double voxelLevel, std::span<const double> weights) const {
  if (!weights.empty() && weights.size() != voxels_.size())
    throw std::invalid_argument("dimensions: " + std::to_string(weights.size()) + " weights for " +
                                std::to_string(voxels_.size()) + " levels");
  const double c = std::clamp(cubeLevel, 0.0, double(finest_));
  const double l = std::clamp(voxelLevel, 0.0, double(finest_));
  const int c0 = int(std::floor(c)), l0 = int(std::floor(l));
  const int c1 = std::min(c0 + 1, finest_), l1 = std::min(l0 + 1, finest_);
  const double fc = c - c0, fl = l - l0;
  const auto at = [&](int ci, int li) { return std::log2(viewDataAt(ci, li, weights)); };
  // Whole levels skip their neighbour, whose data may be 0 (log2: -inf) where a level weighs nothing.
  const auto lerp = [](double f, auto a, auto b) { return f == 0.0 ? a() : (1 - f) * a() + f * b(); };
  const auto alongL = [&](int ci) {
    return lerp(
        fl, [&] { return at(ci, l0); }, [&] { return at(ci, l1); });
  };
  return std::exp2(lerp(
      fc, [&] { return alongL(c0); }, [&] { return alongL(c1); }));
}

namespace {

// The walk's state: for each slice on the path from the root, a row of counts per voxel it decoded: row i,
// entry j = the voxels of level (the slice's) + j below voxel i, itself the one at j = 0.
class DimensionWalk {
 public:
  DimensionWalk(const StoreIndex& index, int finest)
      : index_(index),
        finest_(finest),
        sums_(std::size_t(finest + 1) * std::size_t(finest + 1), 0.0),
        voxels_(std::size_t(finest + 1), 0),
        rootRow_(std::size_t(finest + 1), 0) {
    rootRow_[0] = 1;
    voxels_[0] = 1;
  }

  void enter(std::uint32_t slice, std::span<const SliceVoxel> voxels) {
    const int level = index_.slices()[slice].voxelLevel;
    if (level > finest_) index_.fail("slice " + std::to_string(slice) + " lies below the finest level");
    Frame& f = path_.emplace_back(Frame{voxels.data(), level, {}});
    f.rows.assign(voxels.size() * width(level), 0);
    for (std::size_t i = 0; i < voxels.size(); ++i) f.rows[i * width(level)] = 1;
    voxels_[std::size_t(level)] += voxels.size();
  }

  // Every slice below has added its counts: the rows are complete. Adds them to the sums, then to the
  // parents' rows (the slice above's, or the root's), each parent's children following in Morton order.
  void leave(std::span<const SliceVoxel> parents, std::span<const SliceVoxel> voxels) {
    Frame& f = path_.back();
    const std::size_t w = width(f.level), finestEntry = std::size_t(finest_ - f.level);
    double* sums = &sums_[std::size_t(f.level) * std::size_t(finest_ + 1) + std::size_t(f.level)];
    for (std::size_t i = 0; i < voxels.size(); ++i) {
      const std::uint64_t* row = &f.rows[i * w];
      const double weight = double(row[finestEntry]);
      if (weight != 0.0)
        for (std::size_t j = 0; j < w; ++j) sums[j] += weight * double(row[j]);
    }
    std::uint64_t* target = rootRow_.data();
    if (path_.size() >= 2) {
      Frame& above = path_[path_.size() - 2];
      target = above.rows.data() + std::size_t(parents.data() - above.voxels) * (w + 1);
    }
    std::size_t child = 0;
    for (std::size_t p = 0; p < parents.size(); ++p, target += w + 1)
      for (int k = std::popcount(unsigned(parents[p].childMask)); k > 0; --k, ++child)
        for (std::size_t j = 0; j < w; ++j) target[j + 1] += f.rows[child * w + j];
    assert(child == voxels.size());
    path_.pop_back();
  }

  VoxelDimensions result() {
    for (int l = 0; l <= finest_; ++l)
      sums_[std::size_t(l)] += double(rootRow_[std::size_t(finest_)]) * double(rootRow_[std::size_t(l)]);
    return VoxelDimensions(std::move(sums_), std::move(voxels_));
  }

 private:
  struct Frame {
    const SliceVoxel* voxels;
    int level;
    std::vector<std::uint64_t> rows;
  };
  std::size_t width(int level) const { return std::size_t(finest_ - level + 1); }

  const StoreIndex& index_;
  int finest_;
  std::vector<double> sums_;
  std::vector<std::uint64_t> voxels_;
  std::vector<std::uint64_t> rootRow_;
  std::vector<Frame> path_;
};

}  // namespace

VoxelDimensions measureDimensions(const StoreReader& reader, const std::function<void(double)>& progress) {
  const StoreIndex& index = reader.index();
  int finest = reader.header().parameters.levels;
  while (finest > 0 && index.slicesOfLevel(finest).empty()) --finest;
  if (finest == 0) index.fail("the store holds no voxels");
  DimensionWalk walk(index, finest);
  std::size_t walked = 0;
  const double total = double(reader.slices().size());
  reader.walk(
      [&](std::uint32_t slice, std::span<const SliceVoxel>, std::span<const SliceVoxel> voxels) {
        walk.enter(slice, voxels);
        if (progress) progress(double(++walked) / total);
      },
      [&](std::uint32_t, std::span<const SliceVoxel> parents, std::span<const SliceVoxel> voxels) {
        walk.leave(parents, voxels);
      });
  return walk.result();
}

}  // namespace svo
