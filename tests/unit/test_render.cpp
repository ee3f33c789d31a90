// Frame rendering (render, castTile) of known octrees against analytic depth, shading and voxel size, and PNG
// / EXR output read back through OpenImageIO.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <OpenImageIO/imageio.h>
#include <gtest/gtest.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/render.hpp"

namespace svo {
namespace {

namespace fs = std::filesystem;
using svotest::errorOf;
using svotest::TempDir;

// ---------------------------------------------------------------------------------------------------------
// render

// The whole scene cube filled: a root with eight leaf children, all colored `color`, optionally with a
// normal attachment holding `normal` everywhere, in either attribute layout.
Octree solidCube(const SceneTransform& scene, glm::vec4 color, std::optional<glm::vec3> normal,
                 AttributeLayout attributes = AttributeLayout::Raw) {
  VoxelTree tree;
  tree.hasColors = true;
  tree.hasNormals = normal.has_value();
  tree.voxels.resize(9);
  tree.voxels[0].firstChild = 1;
  tree.voxels[0].childMask = 0xff;
  for (VoxelRecord& v : tree.voxels) {
    v.color = encodeColor(color);
    if (normal) v.normal = encodeNormal(*normal);
  }
  Octree octree;
  octree.transform = scene;
  LayoutOptions layout;
  layout.attributes = attributes;
  octree.block = layoutBlock(tree, layout);
  return octree;
}

// The brief's Phong model, recomputed here in double for a face with normal n seen along `view`.
glm::dvec3 expectedShade(glm::dvec3 albedo, glm::dvec3 n, glm::dvec3 view, glm::dvec3 light) {
  light = glm::normalize(light);
  if (glm::dot(n, view) > 0.0) n = -n;
  const double diffuse = std::max(0.0, glm::dot(n, -light));
  const glm::dvec3 r = light - 2.0 * glm::dot(n, light) * n;
  const double specular = std::pow(std::max(0.0, glm::dot(r, -view)), 32.0);
  return albedo * (0.15 + 0.75 * diffuse) + glm::dvec3(0.25 * specular);
}

class RenderLayouts : public ::testing::TestWithParam<AttributeLayout> {};

// Pure red and an axis normal are exact in both attribute layouts (an RGB565 endpoint, a cube face's centre).
TEST_P(RenderLayouts, SolidCubeFaceOnHasAnalyticDepthShadingAndVoxelSize) {
  const SceneTransform scene{{-2.0, 1.0, 3.0}, 4.0};  // world cube [-2,2] x [1,5] x [3,7]
  const glm::vec4 red(1.0f, 0.0f, 0.0f, 1.0f);
  const Octree octree = solidCube(scene, red, glm::vec3(0.0f, 0.0f, 1.0f), GetParam());
  // Face-on to the +z face (z = 7) from 10 units away, narrow view so the corners miss.
  Camera camera{
      .eye = {0.0, 3.0, 17.0}, .target = {0.0, 3.0, 7.0}, .fovYDegrees = 30.0, .width = 64, .height = 48};
  RenderOptions options;
  options.lodPixels = 0.0f;
  const Frame frame = render(octree, camera, options);
  ASSERT_EQ(frame.width, 64);
  ASSERT_EQ(frame.height, 48);
  ASSERT_EQ(frame.color.size(), 64u * 48u);

  int hits = 0;
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const std::size_t i = std::size_t(y) * camera.width + x;
      glm::dvec3 origin, direction;
      camera.pixelRay(x, y, origin, direction);
      const double t = (7.0 - origin.z) / direction.z;
      const glm::dvec3 p = origin + t * direction;
      const bool inside = std::abs(p.x) < 2.0 && p.y > 1.0 && p.y < 5.0;
      // Pixels whose ray grazes the face's edge may go either way in float.
      const bool nearEdge =
          std::abs(std::abs(p.x) - 2.0) < 1e-3 || std::abs(p.y - 1.0) < 1e-3 || std::abs(p.y - 5.0) < 1e-3;
      if (nearEdge) continue;
      if (!inside) {
        EXPECT_EQ(frame.color[i].a, 0.0f) << x << "," << y;
        EXPECT_EQ(frame.color[i], glm::vec4(options.background, 0.0f));
        EXPECT_TRUE(std::isinf(frame.depth[i]));
        EXPECT_EQ(frame.voxelPixels[i], 0.0f);
        continue;
      }
      ++hits;
      ASSERT_EQ(frame.color[i].a, 1.0f) << x << "," << y;
      EXPECT_NEAR(frame.depth[i], t, 1e-4 * t) << x << "," << y;
      // Leaf voxels are half the cube: 2 world units.
      EXPECT_NEAR(frame.voxelPixels[i], 2.0 / (t * camera.pixelAngle()), 1e-3 * frame.voxelPixels[i]);
      const glm::dvec3 shade =
          expectedShade({1.0, 0.0, 0.0}, {0.0, 0.0, 1.0}, direction, glm::dvec3(options.lightDirection));
      EXPECT_NEAR(frame.color[i].r, shade.r, 1e-4) << x << "," << y;
      EXPECT_NEAR(frame.color[i].g, shade.g, 1e-4) << x << "," << y;
      EXPECT_NEAR(frame.color[i].b, shade.b, 1e-4) << x << "," << y;
    }
  }
  EXPECT_GT(hits, 64 * 48 / 4);
  EXPECT_GT(frame.meanIterations, 0.0);
  EXPECT_GE(frame.seconds, 0.0);
}
INSTANTIATE_TEST_SUITE_P(Attributes, RenderLayouts,
                         ::testing::Values(AttributeLayout::Raw, AttributeLayout::Compressed),
                         [](const auto& info) { return std::string(nameOf(info.param)); });

// `levels` levels of random children with random colors and normals (one in `inheritOneIn` equal to its
// parent's, so that it inherits, and where `familyInheritsOneIn` > 0, all children of one parent in that
// many), in either attribute layout.
Octree randomTree(AttributeLayout attributes, int levels = 3, unsigned inheritOneIn = 3,
                  unsigned familyInheritsOneIn = 0) {
  std::mt19937 rng(11);
  VoxelTree tree;
  tree.hasColors = tree.hasNormals = true;
  tree.voxels.resize(1);
  std::uniform_real_distribution<float> unit(-1.0f, 1.0f);
  const auto randomize = [&](VoxelRecord& v, const VoxelRecord& parent, bool family = false) {
    const bool inherit = family || rng() % inheritOneIn == 0;
    v.color = inherit ? parent.color : std::uint32_t(rng()) | 0xff000000u;
    v.normal = inherit ? parent.normal : encodeNormal(glm::normalize(glm::vec3(unit(rng), unit(rng), 1.0f)));
  };
  randomize(tree.voxels[0], tree.voxels[0]);
  std::vector<std::uint32_t> level{0};
  for (int depth = 0; depth < levels; ++depth) {
    std::vector<std::uint32_t> next;
    for (const std::uint32_t p : level) {
      const auto mask = std::uint8_t(rng() | 1u);
      tree.voxels[p].firstChild = std::uint32_t(tree.voxels.size());
      tree.voxels[p].childMask = mask;
      const bool family = familyInheritsOneIn > 0 && rng() % familyInheritsOneIn == 0;
      for (int slot = 0; slot < 8; ++slot)
        if (mask >> slot & 1u) {
          next.push_back(std::uint32_t(tree.voxels.size()));
          VoxelRecord child;
          randomize(child, tree.voxels[p], family);
          tree.voxels.push_back(child);
        }
    }
    level = std::move(next);
  }
  Octree octree;
  octree.transform = {{0.0, 0.0, 0.0}, 2.0};
  LayoutOptions layout;
  layout.attributes = attributes;
  octree.block = layoutBlock(tree, layout);
  return octree;
}

TEST_P(RenderLayouts, PrefetchingAttributesChangesNoPixel) {
  const Octree octree = randomTree(GetParam());
  const Camera camera = Camera::framing(octree.transform, {0.3, -0.2, -1.0}, 64, 48);
  RenderOptions options;
  options.lodPixels = 0.0f;
  const Frame plain = render(octree, camera, options);
  options.prefetchAttributes = true;
  const Frame prefetched = render(octree, camera, options);
  int hits = 0;
  for (std::size_t i = 0; i < plain.color.size(); ++i) {
    hits += plain.color[i].a == 1.0f;
    ASSERT_EQ(plain.color[i], prefetched.color[i]) << i;
    ASSERT_EQ(plain.depth[i], prefetched.depth[i]) << i;
  }
  EXPECT_GT(hits, 64 * 48 / 10);
}

// The renderer's attribute readers keep a parent's look-up and the values decoded for its children; over a
// frame's hits in castTile's order, each hit still gets the value a fresh look-up gives it, on a tree where
// many values are inherited from one or more levels up.
TEST_P(RenderLayouts, KeptLookUpsChangeNoHitsValue) {
  const Octree octree = randomTree(GetParam(), 5, 4, 2);
  const BlockView block = octree.block.view();
  const Camera camera = Camera::framing(octree.transform, {0.3, -0.2, -1.0}, 256, 192);
  const PixelRays rays(octree.transform, camera, 0.0f);
  SiblingAttribute colors(block, AttachmentType::Color), normals(block, AttachmentType::Normal);
  const bool units = GetParam() == AttributeLayout::Compressed;
  int hits = 0, inheritedFromAbove = 0;  // hits whose parent's own entry or unit does not hold their value
  castTile(block, rays, PixelTile{0, 0, 256, 192}, false, CastOptions{},
           [&](int x, int y, const OctreeRay&, const CastHit& hit) {
             ++hits;
             inheritedFromAbove +=
                 units ? !BlockView::unit(hit.parent, AttachmentType::ColorUnits)
                       : !BlockView::attribute(hit.parent, hit.childSlot, AttachmentType::Color);
             ASSERT_EQ(colors.color(hit), hitColor(block, hit)) << x << "," << y;
             ASSERT_EQ(normals.normal(hit), hitNormal(block, hit)) << x << "," << y;
           });
  EXPECT_GT(hits, 256 * 192 / 20);
  EXPECT_GT(inheritedFromAbove, hits / 40);
}

// castTile with a lag hands out every ray of a tile once, kLag packets after onPacket saw it (the last
// packets after one onPacket(nullptr, 0) each), with the hit castTile without a lag gives: on a tile of many
// packets and on one smaller than the lag.
TEST_P(RenderLayouts, LaggedTilesHandOutEveryRayOnceAfterItsPacket) {
  const Octree octree = randomTree(GetParam());
  const BlockView block = octree.block.view();
  const Camera camera = Camera::framing(octree.transform, {0.3, -0.2, -1.0}, 64, 48);
  const PixelRays rays(octree.transform, camera, 0.0f);
  constexpr int kLag = 3;
  for (const PixelTile tile : {PixelTile{16, 16, 48, 40}, PixelTile{40, 20, 48, 24}}) {
    std::map<std::pair<int, int>, CastHit> expected;
    const std::uint64_t expectedIterations = castTile(
        block, rays, tile, false, CastOptions{},
        [&](int x, int y, const OctreeRay&, const CastHit& hit) {
          expected[{x, y}] = hit;
        },
        [&](int x, int y, const CastHit& miss) {
          expected[{x, y}] = miss;
        });
    ASSERT_EQ(expected.size(), std::size_t(tile.x1 - tile.x0) * std::size_t(tile.y1 - tile.y0));

    std::vector<int> calls;                             // ray count of each onPacket call
    std::map<std::pair<int, int>, int> handedOutAfter;  // pixel -> onPacket calls made by then
    const auto record = [&](int x, int y, const CastHit& hit) {
      const std::pair<int, int> pixel{x, y};
      ASSERT_FALSE(handedOutAfter.contains(pixel)) << x << "," << y;
      handedOutAfter[pixel] = int(calls.size());
      const CastHit& want = expected.at(pixel);
      EXPECT_EQ(hit.hit, want.hit);
      EXPECT_EQ(hit.t, want.t);
      EXPECT_EQ(hit.parent, want.parent);
      EXPECT_EQ(hit.childSlot, want.childSlot);
    };
    const std::uint64_t iterations = castTile<kLag>(
        block, rays, tile, false, CastOptions{},
        [&](int x, int y, const OctreeRay&, const CastHit& hit) { record(x, y, hit); },
        [&](int x, int y, const CastHit& miss) { record(x, y, miss); },
        [&](const CastHit*, int count) { calls.push_back(count); });
    EXPECT_EQ(iterations, expectedIterations);
    ASSERT_EQ(handedOutAfter.size(), expected.size());
    // Packets are the tile's 8x4 blocks, row by row; the calls are theirs, then one without rays per packet
    // still held (kLag, or all of them when the tile has fewer).
    const int packetsAcross = (tile.x1 - tile.x0 + 7) / 8;
    const int packets = packetsAcross * ((tile.y1 - tile.y0 + 3) / 4);
    const int held = std::min(packets, kLag);
    ASSERT_EQ(int(calls.size()), packets + held);
    for (int c = 0; c < packets + held; ++c) EXPECT_EQ(calls[std::size_t(c)] == 0, c >= packets) << c;
    for (const auto& [pixel, callsMade] : handedOutAfter) {
      const int packet = (pixel.second - tile.y0) / 4 * packetsAcross + (pixel.first - tile.x0) / 8;
      EXPECT_EQ(callsMade, packet + held + 1) << pixel.first << "," << pixel.second;
    }
  }
}

// A frame rendered into again, at another size and without diagnostics, holds what a fresh frame holds: no
// pixel, diagnostic or timing of the previous one is left over.
TEST_P(RenderLayouts, RenderingIntoAUsedFrameEqualsAFreshOne) {
  const Octree octree = randomTree(GetParam());
  const BlockView block = octree.block.view();
  RenderOptions first;
  first.diagnostics = true;
  first.filter = true;
  Frame reused;
  render(block, octree.transform, Camera::framing(octree.transform, {-0.5, 0.4, -1.0}, 80, 60), first,
         reused);
  ASSERT_FALSE(reused.iterations.empty());
  const Camera camera = Camera::framing(octree.transform, {0.3, -0.2, -1.0}, 64, 48);
  RenderOptions options;
  options.lodPixels = 0.0f;
  render(block, octree.transform, camera, options, reused);
  const Frame fresh = render(block, octree.transform, camera, options);
  EXPECT_EQ(reused.width, fresh.width);
  EXPECT_EQ(reused.height, fresh.height);
  EXPECT_EQ(reused.color, fresh.color);
  EXPECT_EQ(reused.depth, fresh.depth);
  EXPECT_EQ(reused.voxelPixels, fresh.voxelPixels);
  EXPECT_TRUE(reused.iterations.empty());
  EXPECT_TRUE(reused.lodStopped.empty());
  EXPECT_EQ(reused.filterSeconds, 0.0);
  EXPECT_EQ(reused.meanIterations, fresh.meanIterations);
  EXPECT_GT(std::count_if(fresh.color.begin(), fresh.color.end(), [](glm::vec4 c) { return c.a == 1.0f; }),
            64 * 48 / 10);
}

// Every pixel of a frame is written by the frame: in one that held other values at the same size, a ray
// that misses the cube shows the background with alpha 0, infinite depth and no voxel size, and one that
// hits shows the cube's depth, in tiles whose rays were cast and in those the beam pass skipped alike. At
// 301 x 251 pixels on two threads the frame is cleared in pieces that start off a 16-byte boundary.
TEST(Render, EveryPixelOfAUsedFrameIsWrittenAgain) {
  const SceneTransform scene{{-2.0, 1.0, 3.0}, 4.0};  // world cube [-2,2] x [1,5] x [3,7]
  const Octree octree = solidCube(scene, glm::vec4(1.0f, 0.0f, 0.0f, 1.0f), glm::vec3(0.0f, 0.0f, 1.0f));
  // The cube's corner (2, 5, 7) below and left of the middle of the view (where the clear's pieces meet):
  // it fills less than the lower left quarter.
  const Camera camera{
      .eye = {3.0, 6.0, 15.0}, .target = {2.5, 5.5, 7.0}, .fovYDegrees = 40.0, .width = 301, .height = 251};
  const std::size_t pixels = std::size_t(camera.width) * camera.height;
  RenderOptions options;
  options.lodPixels = 0.0f;
  options.threads = 2;
  Frame frame;
  frame.color.assign(pixels, glm::vec4(9.0f));
  frame.depth.assign(pixels, 9.0f);
  frame.voxelPixels.assign(pixels, 9.0f);
  render(octree.block.view(), octree.transform, camera, options, frame);
  ASSERT_EQ(frame.color.size(), pixels);

  // Rays within this distance (world units) of the cube's edges may go either way in float: left out.
  constexpr double kEdge = 1e-4;
  const glm::dvec3 lo(-2.0, 1.0, 3.0), hi(2.0, 5.0, 7.0);
  const Camera::Basis basis = camera.basis();
  std::size_t hits = 0, misses = 0;
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      glm::dvec3 direction;
      Camera::pixelRay(camera, basis, x, y, direction);
      double enter = 0.0, leave = 0.0;
      const bool inner = svotest::clipBox(lo, hi, camera.eye, direction, -kEdge, enter, leave);
      const std::size_t i = std::size_t(y) * camera.width + x;
      if (inner) {
        ++hits;
        EXPECT_EQ(frame.color[i].a, 1.0f) << x << "," << y;
        // Grazing rays on the top face (y = 5, seen from 0.5 above) lose ~2e-4 of t in float; entering the
        // box shrunk by kEdge is later by at most kEdge / cos.
        EXPECT_NEAR(frame.depth[i], enter, 1e-3 * enter) << x << "," << y;
        EXPECT_GT(frame.voxelPixels[i], 0.0f) << x << "," << y;
      } else if (!svotest::clipBox(lo, hi, camera.eye, direction, kEdge, enter, leave)) {
        ++misses;
        EXPECT_EQ(frame.color[i], glm::vec4(options.background, 0.0f)) << x << "," << y;
        EXPECT_EQ(frame.depth[i], std::numeric_limits<float>::infinity()) << x << "," << y;
        EXPECT_EQ(frame.voxelPixels[i], 0.0f) << x << "," << y;
      }
    }
  EXPECT_GT(hits, pixels / 8);
  EXPECT_GT(misses, pixels / 2);
}

TEST(Render, NormalsFacingAwayAreFlippedAndThreadCountDoesNotMatter) {
  const SceneTransform scene{{0.0, 0.0, 0.0}, 1.0};
  const Camera camera = Camera::framing(scene, {0.3, -0.2, -1.0}, 40, 30);
  RenderOptions options;
  options.threads = 1;
  const Frame towards =
      render(solidCube(scene, glm::vec4(0.2f, 0.6f, 0.9f, 1.0f), glm::vec3(0, 0, 1)), camera, options);
  options.threads = 0;
  const Frame away =
      render(solidCube(scene, glm::vec4(0.2f, 0.6f, 0.9f, 1.0f), glm::vec3(0, 0, -1)), camera, options);
  int hits = 0;
  for (std::size_t i = 0; i < towards.color.size(); ++i) {
    hits += towards.color[i].a == 1.0f;
    EXPECT_EQ(towards.depth[i], away.depth[i]);
    // The cube-point normal encoding is not exactly symmetric under negation: ~3e-5 per component.
    EXPECT_NEAR(towards.color[i].r, away.color[i].r, 1e-3);
    EXPECT_NEAR(towards.color[i].g, away.color[i].g, 1e-3);
    EXPECT_NEAR(towards.color[i].b, away.color[i].b, 1e-3);
  }
  EXPECT_GT(hits, 0);
}

TEST(Render, ContourSurfacesAreShadedWithTheContourNormal) {
  // Every leaf holds the same tilted slab; seen along -z, rays enter it through its upper surface, inside the
  // voxel rather than on a cube face, so the shading normal must be the slab's.
  const glm::ivec3 qn = quantizeContourNormal({0.0, 1.0, 1.0});
  std::uint32_t bits = 0;
  ASSERT_TRUE(encodeContour(qn, -0.1, 0.1, bits));
  const Contour contour = decodeContour(bits);
  VoxelTree tree;
  tree.voxels.resize(9);
  tree.voxels[0].firstChild = 1;
  tree.voxels[0].childMask = 0xff;
  for (int i = 1; i < 9; ++i) tree.voxels[i].hasContour = true, tree.voxels[i].contour = bits;
  Octree octree;
  octree.transform = {{0.0, 0.0, 0.0}, 2.0};  // leaves are unit cubes; slot 4 is [0,1] x [0,1] x [1,2]
  octree.block = layoutBlock(tree);
  // A narrow view at the middle of slot 4's +z face: every ray stays well inside that leaf's x, y range.
  const Camera camera{
      .eye = {0.5, 0.5, 12.0}, .target = {0.5, 0.5, 0.0}, .fovYDegrees = 1.5, .width = 16, .height = 16};
  RenderOptions options;
  options.lodPixels = 0.0f;
  const Frame frame = render(octree, camera, options);
  const glm::dvec3 n = glm::dvec3(contour.normal);
  const double surface = contour.position + 0.5 * contour.thickness;  // n.u on the upper surface
  const glm::dvec3 centre(0.5, 0.5, 1.5);
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const std::size_t i = std::size_t(y) * camera.width + x;
      glm::dvec3 origin, direction;
      camera.pixelRay(x, y, origin, direction);
      // u(t) = origin - centre + t * direction (unit voxel); solve n.u(t) = surface.
      const double t = (surface - glm::dot(n, origin - centre)) / glm::dot(n, direction);
      ASSERT_EQ(frame.color[i].a, 1.0f) << x << "," << y;
      EXPECT_NEAR(frame.depth[i], t, 1e-4 * t) << x << "," << y;
      const glm::dvec3 shade =
          expectedShade(glm::dvec3(0.8), glm::normalize(n), direction, glm::dvec3(options.lightDirection));
      EXPECT_NEAR(frame.color[i].r, shade.r, 1e-4) << x << "," << y;
      EXPECT_NEAR(frame.color[i].b, shade.b, 1e-4) << x << "," << y;
    }
  }
}

TEST(Render, RejectsBadOptions) {
  const SceneTransform scene{{0.0, 0.0, 0.0}, 1.0};
  const Octree octree = solidCube(scene, glm::vec4(1.0f), std::nullopt);
  const Camera camera = Camera::framing(scene, {0, 0, -1}, 8, 8);
  RenderOptions options;
  options.lodPixels = -1.0f;
  EXPECT_THROW(render(octree, camera, options), std::runtime_error);
  options = {};
  options.threads = -2;
  EXPECT_THROW(render(octree, camera, options), std::runtime_error);
  options = {};
  options.cast.recordPath = false;
  EXPECT_THROW(render(octree, camera, options), std::runtime_error);
  Camera bad = camera;
  bad.target = bad.eye;
  EXPECT_THROW(render(octree, bad, {}), std::runtime_error);
}

// ---------------------------------------------------------------------------------------------------------
// writeFrame

Frame randomFrame(int width, int height) {
  std::mt19937 rng(1234);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  Frame f;
  f.width = width, f.height = height;
  const std::size_t n = std::size_t(width) * height;
  for (std::size_t i = 0; i < n; ++i) {
    const bool hit = i % 7 != 0;
    f.color.emplace_back(unit(rng), unit(rng), unit(rng), hit ? 1.0f : 0.0f);
    f.depth.push_back(hit ? 1.0f + 100.0f * unit(rng) : std::numeric_limits<float>::infinity());
    f.voxelPixels.push_back(hit ? 0.01f + 10.0f * unit(rng) : 0.0f);
  }
  f.color[1] = glm::vec4(2.0f, -0.5f, 0.0031308f, 1.0f);  // out of range and at the sRGB knee
  return f;
}

struct Image {
  OIIO::ImageSpec spec;
  std::vector<float> pixels;  // as float, interleaved
  int channel(const std::string& name) const {
    for (int c = 0; c < spec.nchannels; ++c)
      if (spec.channelnames[c] == name) return c;
    return -1;
  }
  float at(std::size_t pixel, int c) const { return pixels[pixel * spec.nchannels + c]; }
};

Image readImage(const fs::path& path) {
  // Frames store unassociated alpha (a miss keeps the background color at alpha 0): read it back as stored.
  OIIO::ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1);
  auto in = OIIO::ImageInput::open(path.string(), &config);
  if (!in) throw std::runtime_error("cannot open " + path.string() + ": " + OIIO::geterror());
  Image image;
  image.spec = in->spec();
  image.pixels.resize(std::size_t(image.spec.width) * image.spec.height * image.spec.nchannels);
  if (!in->read_image(0, 0, 0, image.spec.nchannels, OIIO::TypeDesc::FLOAT, image.pixels.data()))
    throw std::runtime_error("cannot read " + path.string() + ": " + in->geterror());
  in->close();
  return image;
}

double srgb(double linear) {
  const double c = std::clamp(linear, 0.0, 1.0);
  return c <= 0.0031308 ? 12.92 * c : 1.055 * std::pow(c, 1.0 / 2.4) - 0.055;
}

TEST(WriteFrame, ExrRoundTripWithAuxChannels) {
  TempDir dir;
  const Frame frame = randomFrame(37, 23);
  const fs::path path = dir.path() / "frame.exr";
  writeFrame(path, frame, true);
  EXPECT_FALSE(fs::exists(dir.path() / "frame.exr.tmp"));
  const Image image = readImage(path);
  ASSERT_EQ(image.spec.width, 37);
  ASSERT_EQ(image.spec.height, 23);
  ASSERT_EQ(image.spec.nchannels, 6);
  const int r = image.channel("R"), g = image.channel("G"), b = image.channel("B"), a = image.channel("A");
  const int z = image.channel("Z"), vp = image.channel("voxelPixels");
  ASSERT_TRUE(r >= 0 && g >= 0 && b >= 0 && a >= 0 && z >= 0 && vp >= 0);
  EXPECT_EQ(image.spec.channelformat(z), OIIO::TypeDesc::FLOAT);
  EXPECT_EQ(image.spec.channelformat(vp), OIIO::TypeDesc::FLOAT);
  for (std::size_t i = 0; i < frame.color.size(); ++i) {
    // Half keeps 11 significant bits.
    const glm::vec4 c = frame.color[i];
    EXPECT_NEAR(image.at(i, r), c.r, std::abs(c.r) * 1e-3 + 1e-7) << i;
    EXPECT_NEAR(image.at(i, g), c.g, std::abs(c.g) * 1e-3 + 1e-7) << i;
    EXPECT_NEAR(image.at(i, b), c.b, std::abs(c.b) * 1e-3 + 1e-7) << i;
    EXPECT_EQ(image.at(i, a), c.a) << i;
    EXPECT_EQ(image.at(i, z), frame.depth[i]) << i;  // float: exact, infinity included
    EXPECT_EQ(image.at(i, vp), frame.voxelPixels[i]) << i;
  }
}

TEST(WriteFrame, ExrWithoutAuxHasOnlyRgba) {
  TempDir dir;
  const Frame frame = randomFrame(5, 4);
  writeFrame(dir.path() / "plain.exr", frame, false);
  const Image image = readImage(dir.path() / "plain.exr");
  EXPECT_EQ(image.spec.nchannels, 4);
  EXPECT_EQ(image.channel("Z"), -1);
}

TEST(WriteFrame, PngRoundTripIsSrgbWithinOneStep) {
  TempDir dir;
  const Frame frame = randomFrame(31, 17);
  for (const bool withAux : {false, true}) {
    const fs::path path = dir.path() / (withAux ? "rgba.png" : "rgb.png");
    writeFrame(path, frame, withAux);
    const Image image = readImage(path);
    ASSERT_EQ(image.spec.width, 31);
    ASSERT_EQ(image.spec.height, 17);
    ASSERT_EQ(image.spec.nchannels, withAux ? 4 : 3);
    EXPECT_EQ(image.spec.format, OIIO::TypeDesc::UINT8);
    for (std::size_t i = 0; i < frame.color.size(); ++i) {
      const glm::vec4 c = frame.color[i];
      for (int k = 0; k < 3; ++k)
        EXPECT_NEAR(image.at(i, k), srgb(c[k]), 1.0 / 255.0 + 1e-6) << i << " channel " << k;
      if (withAux) {
        EXPECT_EQ(image.at(i, 3), c.a) << i;
      }
    }
  }
}

TEST(WriteFrame, FailuresThrowNamingThePathAndLeaveNoFile) {
  TempDir dir;
  const Frame frame = randomFrame(4, 4);
  const fs::path notADir = dir.file("file.txt", "x");
  for (const fs::path& path : {fs::path("/proc/nonexistent/x.png"), notADir / "x.png", notADir / "x.exr",
                               dir.path() / "missing" / "x.exr", dir.path() / "x.jpg"}) {
    const std::string message = errorOf([&] { writeFrame(path, frame, true); });
    EXPECT_EQ(message.rfind(path.string() + ": cannot write image (", 0), 0u) << message;
    EXPECT_FALSE(fs::exists(path)) << path;
    fs::path temporary = path;
    temporary += ".tmp";
    EXPECT_FALSE(fs::exists(temporary)) << temporary;
  }
  // A directory in the way: the image is written, the rename fails, the temporary is removed.
  const fs::path blocked = dir.path() / "blocked.png";
  fs::create_directories(blocked / "inside");
  const std::string message = errorOf([&] { writeFrame(blocked, frame, false); });
  EXPECT_NE(message.find("cannot write image"), std::string::npos) << message;
  EXPECT_TRUE(fs::is_directory(blocked));
  EXPECT_FALSE(fs::exists(dir.path() / "blocked.png.tmp"));
  // A frame whose buffers do not match its size is refused before anything is written.
  Frame broken = frame;
  broken.depth.pop_back();
  EXPECT_THROW(writeFrame(dir.path() / "broken.exr", broken, true), std::runtime_error);
  EXPECT_FALSE(fs::exists(dir.path() / "broken.exr"));
}

TEST(WriteFrame, ReplacesAnExistingFile) {
  TempDir dir;
  const fs::path path = dir.file("old.png", "not an image");
  writeFrame(path, randomFrame(3, 2), false);
  const Image image = readImage(path);
  EXPECT_EQ(image.spec.width, 3);
}

}  // namespace
}  // namespace svo
