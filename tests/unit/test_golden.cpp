// Golden image: the bunny built at 8 levels and rendered at 256x256 must match the committed PNG
// (tests/data/bunny_golden.png). Tolerance: per-channel 8-bit differences above kPixelTolerance are allowed
// on at most kMaxDifferingFraction of the pixels (silhouette pixels flip with float rounding across
// compilers), and the mean absolute difference stays below kMeanTolerance. Regenerate with
// SVO_UPDATE_GOLDEN=1 after an intended change, and look at the image before committing it.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>

#include "svo/builder/build.hpp"
#include "svo/client/render.hpp"

namespace fs = std::filesystem;

namespace {

constexpr float kPixelTolerance = 8.0f / 255.0f;  // one visible step of 8-bit shading
constexpr double kMaxDifferingFraction = 0.005;   // 0.5% of pixels (silhouette flips)
constexpr double kMeanTolerance = 1.0 / 255.0;    // the image as a whole within one 8-bit step

fs::path bunnyPath() {
  if (const char* env = std::getenv("SVO_BUNNY"); env && *env) return env;
  return fs::path(SVO_SOURCE_DIR) / "build" / "data" / "bunny.ply";
}

TEST(Golden, Bunny) {
  const fs::path bunny = bunnyPath();
  if (!fs::exists(bunny)) GTEST_SKIP() << "no bunny at " << bunny << " (run tools/scripts/fetch-data.sh)";
  svo::BuildOptions options;
  options.levels = 8;
  const svo::Octree octree = svo::buildOctree(svo::loadMesh(bunny), options);
  const svo::Camera camera = svo::Camera::framing(octree.transform, {-0.35, -0.25, -1.0}, 256, 256);
  const svo::Frame frame = svo::render(octree, camera, {});
  const fs::path golden = fs::path(SVO_TEST_DATA) / "bunny_golden.png";
  const fs::path actual = fs::temp_directory_path() / "svo_bunny_actual.png";
  svo::writeFrame(actual, frame, false);
  if (std::getenv("SVO_UPDATE_GOLDEN")) fs::copy_file(actual, golden, fs::copy_options::overwrite_existing);
  ASSERT_TRUE(fs::exists(golden)) << golden;

  OIIO::ImageBuf expected(golden.string()), got(actual.string());
  ASSERT_TRUE(expected.read() && got.read()) << got.geterror() << expected.geterror();
  ASSERT_EQ(got.roi(), expected.roi());
  // CompareResults::error also turns true when any pixel fails kPixelTolerance, which the fraction below
  // allows: read errors are checked above instead.
  const auto cmp = OIIO::ImageBufAlgo::compare(got, expected, kPixelTolerance, 1.0f);
  const double pixels = 256.0 * 256.0;
  EXPECT_LE(double(cmp.nfail) / pixels, kMaxDifferingFraction) << "differing pixels: " << cmp.nfail;
  EXPECT_LE(cmp.meanerror, kMeanTolerance);
  fs::remove(actual);
}

}  // namespace
