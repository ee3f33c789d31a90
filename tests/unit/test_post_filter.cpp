// The post-process filter (sec. 6.3) against analytic images: its kernel's shape, pixels it must leave alone
// bit for bit, constant and linear images it must reproduce, blocky images it must bring closer to the
// smooth image they sample, and neighbours (background, fine voxels) whose colours it must not borrow.
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <stdexcept>
#include <utility>

#include <gtest/gtest.h>

#include "svo/client/post_filter.hpp"

namespace svo {
namespace {

constexpr float kMiss = std::numeric_limits<float>::infinity();

// A frame of `width` x `height` hits at depth 1 whose colour and voxel size come from the functions.
template <class Colour, class VoxelPixels>
Frame makeFrame(int width, int height, Colour colour, VoxelPixels voxelPixels) {
  Frame f;
  f.width = width, f.height = height;
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      f.color.push_back(glm::vec4(colour(x, y), 1.0f));
      f.depth.push_back(1.0f);
      f.voxelPixels.push_back(voxelPixels(x, y));
    }
  return f;
}

double rmseAgainst(const Frame& f, const auto& truth, int margin) {
  double sum = 0.0;
  int n = 0;
  for (int y = margin; y < f.height - margin; ++y)
    for (int x = margin; x < f.width - margin; ++x) {
      const double d = double(f.color[std::size_t(y) * f.width + x].r) - truth(x + 0.5, y + 0.5);
      sum += d * d, ++n;
    }
  return std::sqrt(sum / n);
}

TEST(PostFilter, KernelIsTheSortedSymmetricDiscOfSec63) {
  const std::vector<FilterSample>& k = postFilterKernel();
  ASSERT_EQ(k.size(), 97u);  // the pixel itself and 96 around it
  EXPECT_EQ(k[0].dx, 0);
  EXPECT_EQ(k[0].dy, 0);
  double area = 0.0;
  std::map<std::pair<int, int>, float> weightAt;
  for (std::size_t i = 0; i < k.size(); ++i) {
    EXPECT_FLOAT_EQ(k[i].distance, float(std::hypot(k[i].dx, k[i].dy)));
    EXPECT_LE(k[i].distance, 24.0f);
    EXPECT_GT(k[i].weight, 0.0f);
    if (i > 0) EXPECT_LE(k[i - 1].distance, k[i].distance);
    weightAt[{k[i].dx, k[i].dy}] += k[i].weight;
    area += k[i].weight;
  }
  // Mirrored pairs: every offset's weight equals its mirror's.
  for (const auto& [offset, weight] : weightAt)
    EXPECT_FLOAT_EQ(weight, weightAt.at({-offset.first, -offset.second}));
  // The weights are areas that tile the 24-pixel disc.
  EXPECT_NEAR(area, std::numbers::pi * 24.0 * 24.0, 1e-3 * area);
  // Density falling with the square root of distance: half the radius holds 2^-1.5 of the samples.
  std::size_t inner = 0;
  for (const FilterSample& s : k) inner += s.distance <= 12.0f;
  EXPECT_NEAR(double(inner), 97.0 / std::pow(2.0, 1.5), 3.0);
}

TEST(PostFilter, PixelsAskingForARadiusOfOnePixelOrLessKeepTheirColourBitForBit) {
  std::mt19937 random(7);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  Frame f = makeFrame(
      97, 61, [&](int, int) { return glm::vec3(unit(random), unit(random), unit(random)); },
      [&](int, int) { return unit(random) / kPostFilterRadiusPerVoxel; });  // radius <= 1 pixel
  for (std::size_t i = 0; i < f.depth.size(); i += 5) f.depth[i] = kMiss, f.voxelPixels[i] = 0.0f;
  const Frame before = f;
  postFilter(f);
  ASSERT_EQ(f.color.size(), before.color.size());
  EXPECT_EQ(std::memcmp(f.color.data(), before.color.data(), f.color.size() * sizeof(glm::vec4)), 0);
}

TEST(PostFilter, AConstantImageStaysConstantWhateverTheVoxelSizes) {
  std::mt19937 random(3);
  std::uniform_real_distribution<float> size(0.5f, 80.0f);
  const glm::vec3 grey(0.3f, 0.5f, 0.7f);
  Frame f = makeFrame(
      64, 48, [&](int, int) { return grey; }, [&](int, int) { return size(random); });
  postFilter(f);
  for (const glm::vec4& c : f.color) {
    EXPECT_NEAR(c.r, grey.r, 1e-6);
    EXPECT_NEAR(c.g, grey.g, 1e-6);
    EXPECT_NEAR(c.b, grey.b, 1e-6);
    EXPECT_EQ(c.a, 1.0f);
  }
}

TEST(PostFilter, ALinearRampIsNotShiftedAwayFromTheImageBorder) {
  const auto ramp = [](int x, int y) { return glm::vec3(0.01f * x + 0.003f * y, 0.02f * y, 0.5f); };
  for (const float voxelPixels : {4.0f, 16.0f, 48.0f}) {
    Frame f = makeFrame(80, 80, ramp, [&](int, int) { return voxelPixels; });
    postFilter(f);
    for (int y = 24; y < 56; ++y)
      for (int x = 24; x < 56; ++x) {
        const glm::vec4 c = f.color[std::size_t(y) * 80 + x];
        EXPECT_NEAR(c.r, ramp(x, y).r, 1e-5) << "voxels of " << voxelPixels << " px at " << x << "," << y;
        EXPECT_NEAR(c.g, ramp(x, y).g, 1e-5) << "voxels of " << voxelPixels << " px at " << x << "," << y;
      }
  }
}

TEST(PostFilter, BlocksOfCoarseVoxelsComeCloserToTheSmoothImageTheySample) {
  // A smooth image seen through voxels of `block` pixels: each block shows the image at its centre.
  const auto smooth = [](double x, double y) { return 0.5 + 0.4 * std::sin(x / 19.0) * std::cos(y / 23.0); };
  for (const int block : {4, 8, 16}) {
    const auto blocky = [&](int x, int y) {
      const double cx = (x / block + 0.5) * block, cy = (y / block + 0.5) * block;
      return glm::vec3(float(smooth(cx, cy)));
    };
    Frame f = makeFrame(256, 192, blocky, [&](int, int) { return float(block); });
    const double before = rmseAgainst(f, smooth, 24);
    postFilter(f);
    const double after = rmseAgainst(f, smooth, 24);
    // The default blur removes at least a third of nearest sampling's error on this image.
    EXPECT_LT(after, 0.7 * before) << block << " px voxels: RMSE " << before << " -> " << after;
  }
}

TEST(PostFilter, NeighboursAskingForNoBlurLendNoColour) {
  // Coarse voxels (colours in [0, 1]) beside a background and beside fine voxels, both of a colour of 10:
  // any of it in a coarse pixel shows as a value above 1.
  const auto coarseColour = [](int x, int y) {
    return glm::vec3(0.5f + 0.4f * std::sin(0.3f * x + 0.2f * y));
  };
  for (const bool background : {true, false}) {
    Frame f = makeFrame(
        96, 64, [&](int x, int y) { return x < 40 ? glm::vec3(10.0f) : coarseColour(x, y); },
        // Fine voxels ask for a radius of 0.9 pixels: no blur.
        [&](int x, int) { return x < 40 ? 0.9f / kPostFilterRadiusPerVoxel : 30.0f; });
    if (background)
      for (int y = 0; y < 64; ++y)
        for (int x = 0; x < 40; ++x)
          f.depth[std::size_t(y) * 96 + x] = kMiss, f.voxelPixels[y * 96 + x] = 0.0f;
    const Frame before = f;
    postFilter(f);
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 96; ++x) {
        const std::size_t i = std::size_t(y) * 96 + x;
        if (x < 40) {
          EXPECT_EQ(f.color[i], before.color[i]) << "the neighbour itself changed at " << x << "," << y;
        } else {
          EXPECT_LE(f.color[i].r, 1.0f)
              << (background ? "background" : "fine voxels") << " blurred into " << x << "," << y;
        }
      }
    // Far from the border, the coarse pixels are blurred.
    EXPECT_NE(f.color[32 * 96 + 80], before.color[32 * 96 + 80]);
  }
}

TEST(PostFilter, RejectsAFrameWhoseArraysDoNotMatchAndBadOptions) {
  Frame f = makeFrame(
      8, 8, [](int, int) { return glm::vec3(0.5f); }, [](int, int) { return 4.0f; });
  Frame shortDepth = f;
  shortDepth.depth.pop_back();
  EXPECT_THROW(postFilter(shortDepth), std::invalid_argument);
  Frame noSizes = f;
  noSizes.voxelPixels.clear();
  EXPECT_THROW(postFilter(noSizes), std::invalid_argument);
  EXPECT_THROW(postFilter(f, {.radiusPerVoxel = 0.0f}), std::invalid_argument);
  EXPECT_THROW(postFilter(f, {.radiusPerVoxel = std::numeric_limits<float>::quiet_NaN()}),
               std::invalid_argument);
  EXPECT_THROW(postFilter(f, {.threads = -1}), std::invalid_argument);
  Frame empty;
  EXPECT_NO_THROW(postFilter(empty));
}

}  // namespace
}  // namespace svo
