// The view query (store/schedule.hpp) on a real store with split cubes, against a brute-force reference over
// the voxels themselves: every slice holding a parent voxel that looks wider than the target from the eye is
// wanted (no holes), parents always come before their slices, a far eye wants only coarse levels, and in view
// beats out of view.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <map>
#include <random>
#include <set>

#include <glm/common.hpp>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/store/schedule.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;

namespace {

struct StoreFixture {
  svotest::TempFile file{"svo_schedule", ".svo"};
  std::unique_ptr<svo::StoreReader> reader;
  std::vector<svotest::LeafVoxel> leaves;
};

const StoreFixture& store() {
  static const StoreFixture f = [] {
    StoreFixture s;
    svo::BuildOptions options;
    options.levels = 7;
    svo::StoreWriteOptions write;
    write.sliceBytes = 2048;  // small: cubes split
    svo::writeOctree(s.file.path, svo::buildOctree(svotest::makeSphere({0, 0, 0}, 1.0, 16, 16), options),
                     write);
    s.reader = std::make_unique<svo::StoreReader>(s.file.path);
    return s;
  }();
  return f;
}

// Every voxel (not only leaves) per level, from the loaded tree: coordinates by breadth-first walk.
std::vector<std::vector<glm::ivec3>> voxelsByLevel(const svo::VoxelTree& tree) {
  std::vector<std::vector<glm::ivec3>> levels;
  std::vector<std::tuple<std::uint32_t, int, glm::ivec3>> stack{{0u, 0, glm::ivec3(0)}};
  while (!stack.empty()) {
    const auto [v, level, coord] = stack.back();
    stack.pop_back();
    if (levels.size() <= std::size_t(level)) levels.resize(level + 1);
    levels[level].push_back(coord);
    const svo::VoxelRecord& r = tree.voxels[v];
    for (std::uint32_t c = r.firstChild, slot = 0; slot < 8; ++slot)
      if (r.childMask >> slot & 1u)
        stack.push_back({c++, level + 1, coord * 2 + glm::ivec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1)});
  }
  return levels;
}

double distanceToCube(const glm::dvec3& p, const glm::dvec3& lo, double size) {
  const glm::dvec3 d = glm::max(glm::max(lo - p, p - (lo + size)), glm::dvec3(0.0));
  return glm::length(d);
}

TEST(Schedule, NoHolesParentsFirstAndSorted) {
  const StoreFixture& f = store();
  const auto& slices = f.reader->slices();
  ASSERT_GT(slices.size(), 8u);
  const auto levels = voxelsByLevel(f.reader->loadTree());
  for (const glm::dvec3 eye :
       {glm::dvec3(1.5, 1.5, 2.6), glm::dvec3(1.02, 1.03, 1.01), glm::dvec3(1.5, 1.5, 1.5)}) {
    svo::ViewQuery view;
    view.eye = eye;
    view.pixelAngle = 2e-3;
    const auto wanted = svo::scheduleSlices(f.reader->index(), view);
    std::map<std::uint32_t, std::size_t> rank;
    for (std::size_t i = 0; i < wanted.size(); ++i) rank[wanted[i].slice] = i;
    for (std::size_t i = 1; i < wanted.size(); ++i) EXPECT_GE(wanted[i - 1].priority, wanted[i].priority);
    for (const auto& r : wanted) {
      const std::uint32_t parent = slices[r.slice].parentSlice;
      if (parent == svo::SliceInfo::kNoSlice) continue;
      ASSERT_TRUE(rank.count(parent)) << "slice " << r.slice << " wanted without its parent slice " << parent;
      EXPECT_LT(rank[parent], rank[r.slice]);
    }
    // Reference: a slice is needed when one of its cube's parent voxels looks wider than the target.
    std::size_t needed = 0;
    for (std::uint32_t i = 0; i < slices.size(); ++i) {
      const svo::SliceInfo& s = slices[i];
      const int parentLevel = s.voxelLevel - 1;
      const double size = std::ldexp(1.0, -parentLevel);
      bool need = false;
      for (const glm::ivec3& c : levels.at(std::size_t(parentLevel))) {
        if ((c >> (parentLevel - s.cubeLevel)) != s.cubeCoord) continue;
        const glm::dvec3 lo = glm::dvec3(1.0) + glm::dvec3(c) * size;
        const double d = std::max(distanceToCube(eye, lo, size), 0.5 * size);
        need |= size / (d * view.pixelAngle) > view.lodPixels;
      }
      needed += need;
      if (need)
        EXPECT_TRUE(rank.count(i)) << "slice " << i << " (level " << s.voxelLevel
                                   << ") is needed but not wanted";
    }
    EXPECT_GT(needed, 0u);
  }
}

TEST(Schedule, FarEyeWantsOnlyCoarseLevelsAndViewBeatsOutside) {
  const auto& slices = store().reader->slices();
  svo::ViewQuery far;
  far.eye = {1.5, 1.5, 200.0};
  far.pixelAngle = 1e-3;
  // Level L's parents are 2^-(L-1) wide; from ~198 away they look 2^-(L-1) / 0.198 pixels: wanted up to L
  // = 3.
  const StoreFixture& f = store();
  for (const auto& r : svo::scheduleSlices(f.reader->index(), far)) EXPECT_LE(slices[r.slice].voxelLevel, 3);
  // A frustum holding only x < 1.5: the x > 1.5 half waits behind every visible slice of the same level.
  svo::ViewQuery half;
  half.eye = {1.5, 1.5, 1.5};
  half.pixelAngle = 2e-3;
  half.frustum = {{-1.0, 0.0, 0.0, -1.5}};  // -x >= -1.5
  const auto wanted = svo::scheduleSlices(f.reader->index(), half);
  std::size_t inside = 0, outside = 0;
  for (const auto& r : wanted) (r.inFrustum ? inside : outside)++;
  EXPECT_GT(inside, 0u);
  EXPECT_GT(outside, 0u);
  for (std::size_t i = 0; i < wanted.size(); ++i)
    for (std::size_t j = i + 1; j < wanted.size(); ++j)
      if (!wanted[i].inFrustum && wanted[j].inFrustum &&
          slices[wanted[i].slice].voxelLevel == slices[wanted[j].slice].voxelLevel &&
          slices[wanted[i].slice].voxelLevel > 2)
        ADD_FAILURE() << "out-of-view slice " << wanted[i].slice << " ranks before in-view slice "
                      << wanted[j].slice;
}

// The walk against a scan of every slice, written here from the query's definition: the same wanted slices,
// priorities and order, while it looks only at the wanted slices, their child slices and the root.
TEST(Schedule, HierarchyWalkEqualsAScanOfEverySliceAndLooksAtFewer) {
  const StoreFixture& f = store();
  const svo::StoreIndex& index = f.reader->index();
  const auto& slices = index.slices();
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> coord(-1.0, 4.0), angle(2e-4, 4e-3), logDistance(-3.0, 6.0);
  std::size_t fewer = 0;
  for (int trial = 0; trial < 40; ++trial) {
    svo::ViewQuery view;
    // From inside the scene cube out to where only the coarsest levels are wanted.
    const glm::dvec3 direction = glm::normalize(glm::dvec3(coord(rng), coord(rng), coord(rng)) - 1.5);
    view.eye = glm::dvec3(1.5) + direction * std::exp(logDistance(rng));
    view.pixelAngle = angle(rng);
    if (trial % 2) view.frustum = {{coord(rng) - 1.5, coord(rng) - 1.5, 1.0, coord(rng)}};
    // The scan: each slice's own pixels, its priority capped by every ancestor's, wanted when its parent
    // voxels look wider than the target.
    std::vector<double> priority(slices.size());
    std::vector<std::tuple<double, int, std::uint32_t>> expected;
    for (std::uint32_t i = 0; i < slices.size(); ++i) {
      const svo::SliceBox box = svo::sliceBox(slices[i]);
      const double voxel = std::ldexp(1.0, 1 - slices[i].voxelLevel);
      const glm::dvec3 outside =
          glm::max(glm::max(box.lower - view.eye, view.eye - box.upper), glm::dvec3(0.0));
      const double nearest = std::max(glm::length(outside), 0.5 * voxel);
      const glm::dvec3 extent = box.upper - box.lower;
      bool inView = true;
      for (const auto& plane : view.frustum) {
        double best = -plane[3];
        for (int a = 0; a < 3; ++a) best += plane[a] * (plane[a] > 0.0 ? box.upper[a] : box.lower[a]);
        inView = inView && best >= 0.0;
      }
      priority[i] = voxel / ((nearest + 0.5 * std::max({extent.x, extent.y, extent.z})) * view.pixelAngle) *
                    (inView ? 1.0 : view.outsideWeight);
      if (slices[i].parentSlice != svo::SliceInfo::kNoSlice)
        priority[i] = std::min(priority[i], priority[slices[i].parentSlice]);
      if (voxel / (nearest * view.pixelAngle) > view.lodPixels)
        expected.emplace_back(-priority[i], slices[i].voxelLevel, i);
    }
    std::sort(expected.begin(), expected.end());
    std::size_t visited = 0;
    const auto wanted = svo::scheduleSlices(index, view, &visited);
    ASSERT_EQ(wanted.size(), expected.size()) << "trial " << trial;
    std::size_t bound = index.rootSlices().size();
    for (std::size_t k = 0; k < wanted.size(); ++k) {
      EXPECT_EQ(wanted[k].slice, std::get<2>(expected[k])) << "trial " << trial << ", rank " << k;
      EXPECT_DOUBLE_EQ(wanted[k].priority, -std::get<0>(expected[k]));
      bound += index.childSlices(wanted[k].slice).size();
    }
    EXPECT_LE(visited, bound);
    fewer += visited < slices.size();
  }
  EXPECT_GT(fewer, 0u);  // some views leave whole subtrees unvisited
}

}  // namespace
