// The GPU caster (an OpenGL 4.5 compute shader, on Mesa's llvmpipe here) against the CPU caster it ports:
// the same hit voxel per pixel and the same depth bit for bit, on a contoured colored store,
// the bunny when the data is there, and the stiff-case rays; and the pager's pool mirrored page by page
// renders the same frame as the whole octree cut to the same slices.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <cstring>

#include <glm/geometric.hpp>

#include <OpenImageIO/imageio.h>

#include "command_helpers.hpp"
#include "paging_helpers.hpp"
#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/builder/gen.hpp"
#include "svo/builder/mesh.hpp"
#include "svo/gpu/gl_context.hpp"
#include "svo/gpu/gpu_caster.hpp"
#include "svo/gpu/gpu_pool.hpp"
#include "svo/store/store_reader.hpp"

using namespace svo;
namespace fs = std::filesystem;

namespace {

// Depth agreement: the traversal's expressions are `precise` (no fused multiply-add the CPU does not fuse)
// and its divisions go through double (correctly rounded, where GLSL allows a float quotient 2.5 ulps off),
// so the depths match the CPU's bit for bit, on llvmpipe as on NVIDIA's driver.
constexpr int kDepthUlps = 0;
// Pixels whose hit voxel may differ: rays through a voxel's edge or corner, where a one-ulp difference in a
// direction picks the neighbour (the bound: 99.9% the same).
constexpr double kSameVoxelShare = 0.999;

std::int64_t ulpsBetween(float a, float b) {
  const auto ordered = [](float f) {
    const std::int32_t i = std::bit_cast<std::int32_t>(f);
    return i < 0 ? std::int64_t(INT32_MIN) - i : std::int64_t(i);
  };
  return std::abs(ordered(a) - ordered(b));
}

struct Agreement {
  std::size_t pixels = 0, hits = 0, sameVoxel = 0, depthOff = 0;
  float worstColor = 0.0f;
};

// CPU hits per pixel (no beam, as the GPU) against the GPU's.
Agreement compare(const BlockView& block, const SceneTransform& scene, const Camera& camera,
                  const RenderOptions& options, const gpu::GpuHits& hits, const Frame& gpuFrame) {
  Agreement a;
  RenderOptions cpuOptions = options;
  cpuOptions.beamTile = 0;
  const Frame cpu = render(block, scene, camera, cpuOptions);
  const PixelRays rays(scene, camera, options.lodPixels);
  for (int y = 0; y < camera.height; ++y) {
    for (int x = 0; x < camera.width; ++x) {
      const std::size_t i = std::size_t(y) * camera.width + x;
      const CastHit hit = castRay(block, rays(x, y), options.cast);
      ++a.pixels;
      std::uint32_t voxel = gpu::kMissSlot;
      if (hit.hit) {
        ++a.hits;
        voxel = std::uint32_t((hit.parent - block.slots()) * 8 + hit.childSlot);
      }
      if (voxel != hits.voxel[i]) continue;
      ++a.sameVoxel;
      if (hit.hit && ulpsBetween(hit.t, gpuFrame.depth[i]) > kDepthUlps) ++a.depthOff;
      for (int c = 0; c < 3; ++c)
        a.worstColor = std::max(a.worstColor, std::abs(cpu.color[i][c] - gpuFrame.color[i][c]));
    }
  }
  return a;
}

class Gpu : public ::testing::Test {
 protected:
  void SetUp() override {
    try {
      context_ = std::make_unique<gpu::HeadlessGlContext>();
      caster_ = std::make_unique<gpu::GpuCaster>();
    } catch (const gpu::GpuUnavailable& e) {
      FAIL() << "no OpenGL 4.5 with compute shaders (Mesa's llvmpipe through EGL is expected): " << e.what();
    }
  }
  std::unique_ptr<gpu::HeadlessGlContext> context_;
  std::unique_ptr<gpu::GpuCaster> caster_;
};

void expectAgreement(const Agreement& a, const char* what) {
  EXPECT_GT(a.hits, a.pixels / 10) << what;
  EXPECT_GE(double(a.sameVoxel), kSameVoxelShare * double(a.pixels))
      << what << ": " << a.sameVoxel << " of " << a.pixels;
  EXPECT_EQ(a.depthOff, 0u) << what;
  // Shading runs the same float operations, but pow, normalize and reflect may round differently: 1e-4 is
  // a hundredth of an 8-bit step.
  EXPECT_LT(a.worstColor, 1e-4f) << what;
}

TEST_F(Gpu, SameHitsAsTheCpuCasterOnAContouredColoredStore) {
  for (const AttributeLayout attributes : {AttributeLayout::Raw, AttributeLayout::Compressed}) {
    const Octree octree = readOctree(svotest::sphereStore(), attributes);
    // The box's edges hold exact normal units: the GLSL reads their values too.
    if (attributes == AttributeLayout::Compressed)
      EXPECT_GT(svotest::exactNormalUnits(octree.block.view()), 0u);
    for (const float lod : {0.0f, 1.0f, 4.0f}) {
      for (const bool contours : {true, false}) {
        RenderOptions options;
        options.lodPixels = lod;
        options.cast.contours = contours;
        const Camera camera = svotest::cameraAt({1.7, 1.1, 2.3}, {0.0, -0.2, 0.0}, 160);
        gpu::GpuHits hits;
        const Frame frame =
            gpu::renderBlock(*caster_, octree.block.view(), octree.transform, camera, options, &hits);
        // The dispatches' GPU time (timestamps around them) lies within the whole call's.
        EXPECT_GT(frame.deviceSeconds, 0.0);
        EXPECT_LE(frame.deviceSeconds, frame.seconds);
        expectAgreement(compare(octree.block.view(), octree.transform, camera, options, hits, frame),
                        (std::string(nameOf(attributes)) + (contours ? ", contours" : ", cubes")).c_str());
      }
    }
  }
}

void expectAgreementOn(gpu::GpuCaster& caster, const Octree& octree, const Camera& camera, const char* what,
                       const RenderOptions& options = {}) {
  gpu::GpuHits hits;
  const Frame frame = gpu::renderBlock(caster, octree.block.view(), octree.transform, camera, options, &hits);
  expectAgreement(compare(octree.block.view(), octree.transform, camera, options, hits, frame), what);
}

fs::path bunnyPath() {
  if (const char* env = std::getenv("SVO_BUNNY"); env && *env) return env;
  return fs::path(SVO_SOURCE_DIR) / "build" / "data" / "bunny.ply";
}

TEST_F(Gpu, SameHitsAsTheCpuCasterOnTheBunnyAndATerrain) {
  BuildOptions build;
  build.levels = 10;
  if (fs::exists(bunnyPath())) {
    const Octree bunny = buildOctree(loadMesh(bunnyPath()), build);
    expectAgreementOn(*caster_, bunny, Camera::framing(bunny.transform, kDefaultViewDirection, 200, 150),
                      "bunny");
    const glm::dvec3 centre = bunny.transform.origin + 0.5 * bunny.transform.size;
    expectAgreementOn(
        *caster_, bunny,
        svotest::cameraAt(centre + glm::dvec3(0.1, 0.15, 0.45) * bunny.transform.size, centre, 160),
        "bunny close-up");
  } else {
    ADD_FAILURE() << "no bunny at " << bunnyPath() << " (tools/scripts/fetch-data.sh)";
  }
  GenOptions gen;
  gen.kind = SceneKind::Terrain;
  gen.triangles = 20000;
  const Octree terrain = buildOctree(generateScene(gen), build);
  expectAgreementOn(*caster_, terrain, svotest::cameraAt({0.9, 0.8, 1.4}, {0.0, 0.1, 0.0}, 160), "terrain");
}

// The beam pass on the GPU (one per 8 x 8 work group) changes no pixel and skips the tiles the CPU skips.
TEST_F(Gpu, TheBeamPassChangesNoPixelAndRunsAsTheCpusDoes) {
  const Octree octree = readOctree(svotest::sphereStore());
  const Camera camera = svotest::cameraAt({1.2, 0.9, 2.0}, {0.0, -0.2, 0.0}, 150);
  RenderOptions withBeam, without;
  without.beamTile = 0;
  const Frame a = gpu::renderBlock(*caster_, octree.block.view(), octree.transform, camera, withBeam);
  const Frame b = gpu::renderBlock(*caster_, octree.block.view(), octree.transform, camera, without);
  EXPECT_EQ(std::memcmp(a.color.data(), b.color.data(), a.color.size() * sizeof(glm::vec4)), 0);
  EXPECT_EQ(std::memcmp(a.depth.data(), b.depth.data(), a.depth.size() * sizeof(float)), 0);
  // Tiles whose beam meets nothing cast no ray: their pixels take no iteration at all, and the iterations per
  // pixel are the CPU renderer's running the same pass on the same 8 x 8 tiles.
  withBeam.diagnostics = without.diagnostics = true;
  const Frame c = gpu::renderBlock(*caster_, octree.block.view(), octree.transform, camera, withBeam);
  const Frame d = gpu::renderBlock(*caster_, octree.block.view(), octree.transform, camera, without);
  const auto idle = [](const Frame& f) { return std::count(f.iterations.begin(), f.iterations.end(), 0); };
  EXPECT_GT(idle(c), idle(d) + 1000);
  RenderOptions cpuTiles = withBeam;
  cpuTiles.beamTile = 8;
  const Frame cpu = render(octree, camera, cpuTiles);
  EXPECT_EQ(c.iterations, cpu.iterations);
}

// Stiff rays: exactly axis-parallel (the centre pixel of an odd-sized image looking along an axis), grazing
// a box face edge-on, from far outside and from inside the scene.
TEST_F(Gpu, SameHitsAsTheCpuCasterOnStiffRays) {
  const Octree octree = readOctree(svotest::sphereStore());
  const struct {
    glm::dvec3 eye, target;
    const char* what;
  } cases[] = {
      {{0.0, 0.0, 5.0}, {0.0, 0.0, 0.0}, "along -z"},
      {{-5.0, 0.0, 0.0}, {0.0, 0.0, 0.0}, "along +x"},
      {{0.0, 0.3, 0.0}, {0.0, -5.0, 0.0}, "along -y from inside"},
      {{-3.0, -1.2, 0.35}, {3.0, -1.2, 0.35}, "grazing the box's bottom face"},
      {{0.3, -0.9, 3.0}, {0.3, -0.9, -3.0}, "along the box's top edge"},
      {{4e3, 3e3, 5e3}, {0.0, 0.0, 0.0}, "from far away"},
  };
  for (const auto& c : cases) {
    Camera camera = svotest::cameraAt(c.eye, c.target, 101);
    if (std::abs(glm::normalize(c.target - c.eye).y) > 0.99) camera.up = {0.0, 0.0, -1.0};
    camera.fovYDegrees = c.eye.x > 1e3 ? 0.05 : 50.0;
    RenderOptions options;
    options.lodPixels = 0.0f;
    gpu::GpuHits hits;
    const Frame frame =
        gpu::renderBlock(*caster_, octree.block.view(), octree.transform, camera, options, &hits);
    const Agreement a = compare(octree.block.view(), octree.transform, camera, options, hits, frame);
    EXPECT_GE(double(a.sameVoxel), kSameVoxelShare * double(a.pixels)) << c.what;
    EXPECT_EQ(a.depthOff, 0u) << c.what;
    EXPECT_LT(a.worstColor, 1e-4f) << c.what;
  }
}

}  // namespace

namespace {

// The pager's pool mirrored page by page: after every update, the GPU frame from the pool equals the GPU
// frame of the whole octree cut to the resident slices, bit for bit; and a converged view uploads only what
// loaded.
TEST_F(Gpu, PagedFrameEqualsTheWholeOctreeCutToTheSameSlices) {
  for (const AttributeLayout attributes : {AttributeLayout::Raw, AttributeLayout::Compressed}) {
    PagerOptions pagerOptions;
    pagerOptions.budgetBytes = std::size_t(16) << 20;
    pagerOptions.attributes = attributes;
    LayoutOptions layout;
    layout.attributes = attributes;
    Pager pager(svotest::sphereStore(), pagerOptions);
    gpu::GpuPool pool(*caster_, pager);
    // The first sync uploads exactly the pages that hold blocks (the trunk), not the whole budget.
    EXPECT_EQ(pool.sync(), pager.residentBytes());
    gpu::GpuCaster wholeCaster;
    const StoreReader reader(svotest::sphereStore());
    const Camera camera = svotest::cameraAt({0.5, 0.4, 1.6}, {0.0, 0.0, 0.7}, 96);
    RenderOptions options;
    const ViewQuery view = viewOf(pager.transform(), camera, options.lodPixels);
    std::size_t compared = 0;
    for (int step = 0; step < 400 && !(pager.converged() && compared > 2); ++step) {
      pager.update(view);
      const Frame paged = pool.render(camera, options);
      const Block cut = layoutBlock(svotest::truncatedTree(reader, pager.residentSlices()), layout);
      const Frame whole = gpu::renderBlock(wholeCaster, cut.view(), pager.transform(), camera, options);
      ASSERT_EQ(std::memcmp(paged.color.data(), whole.color.data(), paged.color.size() * sizeof(glm::vec4)),
                0)
          << nameOf(attributes) << ", step " << step;
      ASSERT_EQ(std::memcmp(paged.depth.data(), whole.depth.data(), paged.depth.size() * sizeof(float)), 0);
      ++compared;
      pager.feedback(paged, camera, options.lodPixels);
      pager.waitForWork(0.01);
    }
    ASSERT_TRUE(pager.converged());
    // Uploads: the pages the loads wrote, never more than a page per resident page plus the links patched.
    EXPECT_GT(pool.uploadedBytes(), 0u);
    EXPECT_EQ(pool.sync(), 0u);  // nothing changed since the last frame
  }
}

}  // namespace

namespace {

// `svo render --device gpu` writes the CPU's image (8-bit codes within 1, and equal on 99.9% of the pixels),
// whole and streamed; a budget beyond one storage buffer is one clear line and no image.
TEST(GpuCommand, RenderOnTheGpuWritesTheCpusImage) {
  svotest::TempDir dir;
  const std::string store = svotest::sphereStore().string();
  for (const std::string how : {"", " --budget 8M"}) {
    const std::string common = std::string(SVO_BINARY) + " render " + store + how +
                               " --eye 0.6,0.5,1.7 --target 0,0,0.7 --width 200 --height 150 -o ";
    const fs::path gpuPng = dir.path() / "gpu.png", cpuPng = dir.path() / "cpu.png";
    const std::string onGpu = svotest::runShell(common + gpuPng.string() + " --device gpu");
    ASSERT_NE(onGpu.find("exit 0"), std::string::npos) << onGpu;
    ASSERT_NE(svotest::runShell(common + cpuPng.string()).find("exit 0"), std::string::npos);
    const svotest::Rgb8 a = svotest::readRgb8(gpuPng), b = svotest::readRgb8(cpuPng);
    ASSERT_EQ(a.pixels.size(), b.pixels.size());
    ASSERT_FALSE(a.pixels.empty());
    std::size_t off = 0;
    for (std::size_t i = 0; i < a.pixels.size(); ++i) {
      const int d = std::abs(int(a.pixels[i]) - int(b.pixels[i]));
      ASSERT_LE(d, 1) << "byte " << i << how;
      off += d != 0;
    }
    EXPECT_LE(double(off), 0.001 * double(a.pixels.size())) << how;
  }
  const fs::path tooLarge = dir.path() / "large.png";
  const std::string said = svotest::runShell(std::string(SVO_BINARY) + " render " + store +
                                             " --budget 1G --device gpu -o " + tooLarge.string());
  EXPECT_NE(said.find("storage buffer"), std::string::npos) << said;
  EXPECT_NE(said.find("exit 1"), std::string::npos) << said;
  EXPECT_EQ(std::count(said.begin(), said.end(), '\n'), 2) << said;  // the error line and the exit line
  EXPECT_FALSE(fs::exists(tooLarge));
}

// `svo bench raycast --device gpu` times the GPU caster beside the CPU's and says how far their depths agree:
// equal to the bit on every pixel of both cameras.
TEST(GpuCommand, BenchRaycastReportsTheGpuDepthsEqualToTheCpus) {
  svotest::TempDir dir;
  const fs::path mesh = dir.path() / "sphere.ply";
  ASSERT_NE(svotest::runShell(std::string(SVO_BINARY) + " gen sphere --triangles 2k -o " + mesh.string())
                .find("exit 0"),
            std::string::npos);
  const std::string said = svotest::runShell(std::string(SVO_BINARY) + " bench raycast " + mesh.string() +
                                             " --device gpu --levels 6 --size 48 --runs 1 --threads 1 -o " +
                                             (dir.path() / "report").string());
  ASSERT_NE(said.find("exit 0"), std::string::npos) << said;
  for (const char* camera : {"whole", "close"}) {
    const std::string line = std::string("sphere ") + camera + ": shaded without the beam pass";
    const std::size_t at = said.find(line);
    ASSERT_NE(at, std::string::npos) << line << "\n" << said;
    const std::string rest = said.substr(at, said.find('\n', at) - at);
    EXPECT_NE(
        rest.find("depths equal to the CPU caster's on 100.000% of the pixels (largest difference 0 ulps)"),
        std::string::npos)
        << rest;
  }
}

}  // namespace
