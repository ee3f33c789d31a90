// castPacket (client/raycast.hpp) against castRay, ray by ray: the same hit, t, voxel, position, path and
// iteration count, bit for bit, over coherent pixel packets, incoherent random packets, stiff rays, partial
// packets, iteration caps, far child pointers and a block pool's linked regions. castRay itself is checked
// against the brute-force reference in test_raycast.cpp.
#include <gtest/gtest.h>

#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/raycast.hpp"
#include "svo/client/render.hpp"
#include "svo/client/whole_scene.hpp"

namespace {

bool sameBits(float a, float b) {
  return std::memcmp(&a, &b, sizeof a) == 0;
}

// Empty when the two hits agree in every field castRay defines (the path only where `withPath`); else what
// differs.
std::string difference(const svo::CastHit& a, const svo::CastHit& b, bool withPath = true) {
  if (a.hit != b.hit) return fmt::format("hit {} vs {}", a.hit, b.hit);
  if (a.iterations != b.iterations) return fmt::format("iterations {} vs {}", a.iterations, b.iterations);
  if (!a.hit) return {};
  if (!sameBits(a.t, b.t)) return fmt::format("t {} vs {}", a.t, b.t);
  if (a.scale != b.scale || a.parent != b.parent || a.childSlot != b.childSlot || a.leaf != b.leaf)
    return "voxel";
  for (int i = 0; i < 3; ++i)
    if (!sameBits(a.position[i], b.position[i]) || !sameBits(a.cubeMin[i], b.cubeMin[i])) return "position";
  for (int s = a.scale + 1; withPath && s < svo::kMaxLevels; ++s)
    if (a.pathParent[s] != b.pathParent[s] || a.pathSlot[s] != b.pathSlot[s]) return "path";
  return {};
}

std::string describe(const svo::OctreeRay& r) {
  return fmt::format("o ({:.9g}, {:.9g}, {:.9g}) d ({:.9g}, {:.9g}, {:.9g}) tMin {:.9g} slope {:.9g}",
                     r.origin.x, r.origin.y, r.origin.z, r.direction.x, r.direction.y, r.direction.z, r.tMin,
                     r.footprintSlope);
}

// The SIMD loops this CPU runs, widest first, and castRay one by one.
std::vector<svo::PacketSimd> packetLoops() {
  std::vector<svo::PacketSimd> loops;
  for (const svo::PacketSimd simd : {svo::PacketSimd::Avx512, svo::PacketSimd::Avx2})
    if (svo::cpuHas(simd)) loops.push_back(simd);
  loops.push_back(svo::PacketSimd::None);
  return loops;
}

// Casts `rays` in packets of `lanes` (the last one partial) with each loop this CPU has and expects each hit
// to equal castRay's; returns castRay's hits.
std::size_t expectSameAsCastRay(const svo::BlockView& block, const std::vector<svo::OctreeRay>& rays,
                                svo::CastOptions options, int lanes = svo::kPacketLanes) {
  std::size_t hits = 0;
  for (const svo::PacketSimd simd : packetLoops()) {
    SCOPED_TRACE(fmt::format("loop {}", svo::nameOf(simd)));
    options.simd = simd;
    EXPECT_EQ(svo::packetSimdUsed(simd), simd);
    hits = 0;
    for (std::size_t first = 0; first < rays.size(); first += std::size_t(lanes)) {
      const int count = int(std::min<std::size_t>(std::size_t(lanes), rays.size() - first));
      svo::CastHit packet[svo::kPacketLanes];
      svo::castPacket(block, &rays[first], count, options, packet);
      for (int l = 0; l < count; ++l) {
        const svo::CastHit single = svo::castRay(block, rays[first + std::size_t(l)], options);
        const std::string why = difference(single, packet[l], options.recordPath);
        if (!why.empty()) {
          ADD_FAILURE() << why << " for ray " << first + std::size_t(l) << ": "
                        << describe(rays[first + std::size_t(l)]);
          return hits;
        }
        hits += single.hit;
      }
    }
  }
  return hits;
}

svo::Octree sphereAndBoxes() {
  svo::Mesh mesh = svotest::makeSphere({0.3, -0.2, 0.1}, 1.0, 32, 32);
  svotest::appendMesh(mesh, svotest::makeBox({-1.2, -1.2, -1.2}, {-0.6, -0.5, -0.7}));
  svotest::appendMesh(mesh, svotest::makeRandomTriangles(5, 60, {-1, -1, -1}, {1, 1, 1}, 0.2));
  svo::BuildOptions options;
  options.levels = 8;
  return svo::buildOctree(mesh, options);
}
const svo::Octree& scene() {
  static const svo::Octree octree = sphereAndBoxes();
  return octree;
}

// Every pixel of a camera in castTile's order: 4x4 blocks left to right, so that with a width a multiple of 8
// each packet of 32 rays is the 8x4 block castTile casts together.
std::vector<svo::OctreeRay> pixelPackets(const svo::SceneTransform& transform, const svo::Camera& camera,
                                         float lodPixels) {
  const svo::PixelRays rays(transform, camera, lodPixels);
  std::vector<svo::OctreeRay> out;
  for (int y = 0; y < camera.height; y += 4)
    for (int x = 0; x < camera.width; x += 4)
      for (int i = 0; i < 16; ++i) out.push_back(rays(x + i % 4, y + i / 4));
  return out;
}

svo::Camera closeUp(const svo::SceneTransform& transform) {
  svo::Camera camera = svo::Camera::framing(transform, svo::kDefaultViewDirection, 96, 64);
  camera.eye = camera.target + 0.25 * (camera.eye - camera.target);
  return camera;
}

TEST(CastPacket, PixelPacketsEqualCastRay) {
  const svo::Octree& octree = scene();
  for (const svo::Camera& camera :
       {svo::Camera::framing(octree.transform, svo::kDefaultViewDirection, 96, 64),
        closeUp(octree.transform)})
    for (float lod : {0.0f, 1.0f, 4.0f})
      for (bool contours : {true, false}) {
        SCOPED_TRACE(fmt::format("lod {} contours {}", lod, contours));
        svo::CastOptions options;
        options.contours = contours;
        EXPECT_GT(
            expectSameAsCastRay(octree.block.view(), pixelPackets(octree.transform, camera, lod), options),
            0u);
      }
}

// Without the paths (depth alone), every other field is castRay's with them, in every loop.
TEST(CastPacket, HitsWithoutPathsEqualCastRay) {
  const svo::Octree& octree = scene();
  svo::CastOptions withoutPath;
  withoutPath.recordPath = false;
  for (const svo::Camera& camera :
       {svo::Camera::framing(octree.transform, svo::kDefaultViewDirection, 96, 64),
        closeUp(octree.transform)}) {
    const std::vector<svo::OctreeRay> rays = pixelPackets(octree.transform, camera, 1.0f);
    EXPECT_GT(expectSameAsCastRay(octree.block.view(), rays, withoutPath), 0u);
    for (std::size_t i = 0; i < rays.size(); ++i) {
      const std::string why = difference(svo::castRay(octree.block.view(), rays[i], {}),
                                         svo::castRay(octree.block.view(), rays[i], withoutPath), false);
      ASSERT_TRUE(why.empty()) << why << " for ray " << i;
    }
  }
}

// Far child pointers (sec. 5.1): the scene laid out again with near pointers of 16 slots at most (the least a
// layout allows), so most runs are reached through a far slot.
TEST(CastPacket, FarPointersEqualCastRay) {
  svo::LayoutOptions layout;
  layout.maxNearPointer = 16;
  svo::LayoutStats stats;
  const svo::Block block = svo::layoutBlock(svo::readBlock(scene().block.view()), layout, &stats);
  ASSERT_GT(stats.farSlots, 100u);
  const svo::SceneTransform& transform = scene().transform;
  for (const svo::Camera& camera :
       {svo::Camera::framing(transform, svo::kDefaultViewDirection, 96, 64), closeUp(transform)})
    EXPECT_GT(expectSameAsCastRay(block.view(), pixelPackets(transform, camera, 1.0f), {}), 0u);
}

// Incoherent packets: every lane its own origin and direction, so lanes push, advance and pop apart.
TEST(CastPacket, RandomPacketsEqualCastRay) {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> inCube(0.9f, 2.1f), component(-1.0f, 1.0f);
  std::vector<svo::OctreeRay> rays;
  for (int i = 0; i < 20000; ++i) {
    svo::OctreeRay r;
    r.origin = {inCube(rng), inCube(rng), inCube(rng)};
    if (i % 3 == 0) r.origin = 1.5f + 2.0f * glm::vec3(component(rng), component(rng), component(rng));
    r.direction = {component(rng), component(rng), component(rng)};
    if (i % 5 == 0) r.footprintSlope = 0.002f;  // some lanes stop at their level of detail
    rays.push_back(r);
  }
  EXPECT_GT(expectSameAsCastRay(scene().block.view(), rays, {}), 0u);
  // Partial packets: every count from 1 to kPacketLanes.
  for (int lanes = 1; lanes < svo::kPacketLanes; ++lanes)
    EXPECT_GT(expectSameAsCastRay(scene().block.view(), rays, {}, lanes), 0u);
}

// Axis-parallel and grazing rays, tiny and zero components, rays along voxel faces, far origins, lanes that
// miss or are degenerate beside lanes that hit.
TEST(CastPacket, StiffRaysEqualCastRay) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<svo::OctreeRay> rays;
  const auto add = [&](glm::vec3 o, glm::vec3 d) {
    svo::OctreeRay r;
    r.origin = o, r.direction = d;
    rays.push_back(r);
  };
  for (int axis = 0; axis < 3; ++axis)
    for (float sign : {-1.0f, 1.0f})
      for (float u : {1.25f, 1.5f, 1.5f + 1.0f / 256.0f, 1.37f})
        for (float v : {1.5f, 1.75f, 1.0f + 1.0f / 64.0f}) {
          glm::vec3 o(u, v, 1.41f), d(0.0f);
          o[axis] = sign < 0 ? 2.5f : 0.5f;
          d[axis] = sign;
          add(o, d);                                       // exactly along an axis
          add(o, d + glm::vec3(1e-30f, -1e-30f, 1e-30f));  // components far below 2^-23
          add(o, d + glm::vec3(1e-4f, 1e-4f, -1e-4f));     // grazing
          add(glm::vec3(o.x, 1.5f, o.z), d);               // in a grid plane of every level
          add(o + 8000.0f * glm::vec3(-d), d);             // far away
        }
  add({1.5f, 1.5f, 0.5f}, {0.0f, 0.0f, 0.0f});  // degenerate lanes
  add({1.5f, 1.5f, 0.5f}, {nan, 0.0f, 1.0f});
  add({1.5f, 1.5f, 0.5f}, {-0.0f, 0.0f, 1.0f});
  for (const svo::OctreeRay& r : std::vector<svo::OctreeRay>(rays)) {  // the same rays from behind the hit
    svo::OctreeRay late = r;
    late.tMin = 0.9f;
    rays.push_back(late);
  }
  for (bool contours : {true, false}) {
    svo::CastOptions options;
    options.contours = contours;
    EXPECT_GT(expectSameAsCastRay(scene().block.view(), rays, options), 0u);
  }
}

TEST(CastPacket, IterationCapsEqualCastRay) {
  const svo::Octree& octree = scene();
  const auto rays = pixelPackets(octree.transform, closeUp(octree.transform), 0.0f);
  for (int cap : {1, 3, 10}) {
    SCOPED_TRACE(fmt::format("cap {}", cap));
    svo::CastOptions options;
    options.maxIterations = cap;
    expectSameAsCastRay(octree.block.view(), rays, options);  // a cap of 1 hits nothing
  }
}

// A block pool: regions joined by links, and stubs where a region's next level is not resident.
TEST(CastPacket, PoolRegionsEqualCastRay) {
  const std::filesystem::path store =
      std::filesystem::temp_directory_path() / fmt::format("svo-packet-{}.svo", ::getpid());
  svotest::writeSphereAndBoxStore(store, 2048);
  {
    const svo::WholeScene whole = svo::WholeScene::paged(store, std::size_t(64) << 20);
    const svo::Camera camera = svo::Camera::framing(whole.transform(), svo::kDefaultViewDirection, 96, 64);
    for (float lod : {0.0f, 1.0f})
      EXPECT_GT(expectSameAsCastRay(whole.root(), pixelPackets(whole.transform(), camera, lod), {}), 0u);
  }
  std::filesystem::remove(store);
}

}  // namespace
