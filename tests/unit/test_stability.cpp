// Every stiff and extreme case of tools/bench/stability.hpp at test size: no NaN or infinity, no ray at the
// iteration cap, no see-through, hit points within a voxel diagonal of the mesh, and every acceleration
// structure equal to the brute-force reference (the bounds are StabilityBounds', stated there).
#include <gtest/gtest.h>

#include <cstdio>

#include "stability.hpp"

namespace {

class Stability : public ::testing::TestWithParam<int> {};

const std::vector<svo::tools::StiffCase>& cases() {
  static const std::vector<svo::tools::StiffCase> all = svo::tools::stiffCases(1);
  return all;
}

TEST_P(Stability, CaseMeetsEveryBound) {
  const svo::tools::StiffCase& c = cases().at(std::size_t(GetParam()));
  const svo::tools::CaseResult r = svo::tools::evaluateCase(c);
  std::printf(
      "[ STIFF    ] %-16s %6zu rays, %5zu ref hits, see-through %zu (max %.3f vox), surface max %.3f "
      "mean %.3f diagonals, iterations max %d mean %.1f, %zu structures, accel err %.1e\n",
      r.name.c_str(), r.rays, r.referenceHits, r.seeThrough, r.maxSeeThrough, r.maxSurfaceError,
      r.meanSurfaceError, r.maxIterations, r.meanIterations, r.structures, r.maxAccelError);
  EXPECT_TRUE(r.pass()) << c.name << " (" << c.what << "): " << r.failure;
  EXPECT_EQ(r.nonFinite, 0u);
  EXPECT_EQ(r.capped, 0u);
  EXPECT_EQ(r.seeThrough, 0u);
  EXPECT_EQ(r.accelMismatches, 0u);
  EXPECT_GT(r.referenceHits, 0u) << "the case's rays must hit something";
  EXPECT_GT(r.casterHits, 0u);
}

INSTANTIATE_TEST_SUITE_P(Cases, Stability, ::testing::Range(0, int(svo::tools::stiffCases(1).size())),
                         [](const ::testing::TestParamInfo<int>& info) {
                           std::string name = cases().at(std::size_t(info.param)).name;
                           for (char& ch : name)
                             if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
                           return name;
                         });

}  // namespace
