// Camera math against closed forms, camera JSON loading, octree-space rays and the renderer's packets of
// pixel rays.
#include <cmath>
#include <filesystem>
#include <numbers>
#include <string>
#include <tuple>
#include <utility>

#include <gtest/gtest.h>
#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/render.hpp"

namespace svo {
namespace {

namespace fs = std::filesystem;
constexpr double kPi = std::numbers::pi;
using svotest::errorOf;
using svotest::TempDir;

double angleBetween(glm::dvec3 a, glm::dvec3 b) {
  return std::atan2(glm::length(glm::cross(a, b)), glm::dot(a, b));
}

Camera makeCamera(glm::dvec3 eye, glm::dvec3 target, int width, int height, double fov = 45.0) {
  return Camera{.eye = eye, .target = target, .fovYDegrees = fov, .width = width, .height = height};
}

// ---------------------------------------------------------------------------------------------------------
// Camera

TEST(Camera, CentrePixelRayIsTheViewDirection) {
  const Camera c = makeCamera({1.0, 2.0, 5.0}, {-2.0, 0.5, -1.0}, 640, 480, 60.0);
  glm::dvec3 origin, direction;
  // Pixel (w/2 - 0.5, h/2 - 0.5) has its centre exactly at the image centre.
  c.pixelRay(c.width / 2 - 0.5, c.height / 2 - 0.5, origin, direction);
  const glm::dvec3 view = glm::normalize(c.target - c.eye);
  EXPECT_NEAR(glm::length(origin - c.eye), 0.0, 1e-12);
  EXPECT_NEAR(direction.x, view.x, 1e-12);
  EXPECT_NEAR(direction.y, view.y, 1e-12);
  EXPECT_NEAR(direction.z, view.z, 1e-12);
  EXPECT_NEAR(glm::length(direction), 1.0, 1e-12);
}

TEST(Camera, CornerRayAngleMatchesClosedForm) {
  for (const auto& [width, height, fov] :
       {std::tuple{640, 480, 60.0}, {300, 600, 45.0}, {512, 512, 90.0}, {1920, 1080, 10.0}, {7, 3, 150.0}}) {
    const Camera c = makeCamera({0.0, 0.0, 3.0}, {0.0, 0.0, 0.0}, width, height, fov);
    const double aspect = double(width) / height;
    const double expected = std::atan(std::tan(fov * kPi / 360.0) * std::sqrt(aspect * aspect + 1.0));
    const glm::dvec3 view(0.0, 0.0, -1.0);
    // The four image corners: pixel "centres" half a pixel outside the first and last pixels.
    for (const auto& [x, y] :
         {std::pair{-0.5, -0.5}, {width - 0.5, -0.5}, {-0.5, height - 0.5}, {width - 0.5, height - 0.5}}) {
      glm::dvec3 origin, direction;
      c.pixelRay(x, y, origin, direction);
      EXPECT_NEAR(angleBetween(direction, view), expected, 1e-12) << width << "x" << height << " fov " << fov;
    }
    // Top and bottom edge centres subtend exactly half the vertical fov.
    glm::dvec3 origin, top, bottom;
    c.pixelRay(width / 2.0 - 0.5, -0.5, origin, top);
    c.pixelRay(width / 2.0 - 0.5, height - 0.5, origin, bottom);
    EXPECT_NEAR(angleBetween(top, view), fov * kPi / 360.0, 1e-12);
    EXPECT_NEAR(angleBetween(top, bottom), fov * kPi / 180.0, 1e-12);
  }
}

TEST(Camera, ImageAxesAreRightHandedWithRowZeroAtTheTop) {
  // Looking down -z with y up: image +x is world +x, image row 0 is world +y.
  const Camera c = makeCamera({0.0, 0.0, 3.0}, {0.0, 0.0, 0.0}, 100, 80);
  glm::dvec3 origin, topLeft, bottomRight;
  c.pixelRay(0, 0, origin, topLeft);
  c.pixelRay(99, 79, origin, bottomRight);
  EXPECT_LT(topLeft.x, 0.0);
  EXPECT_GT(topLeft.y, 0.0);
  EXPECT_GT(bottomRight.x, 0.0);
  EXPECT_LT(bottomRight.y, 0.0);
  EXPECT_LT(topLeft.z, 0.0);
  // Symmetric pixels give mirrored rays.
  EXPECT_NEAR(topLeft.x, -bottomRight.x, 1e-12);
  EXPECT_NEAR(topLeft.y, -bottomRight.y, 1e-12);
}

TEST(Camera, PixelAngleIsTheCentrePixelsAngle) {
  const Camera c = makeCamera({0.0, 0.0, 3.0}, {0.0, 0.0, 0.0}, 800, 600, 50.0);
  EXPECT_NEAR(c.pixelAngle(), 2.0 * std::tan(50.0 * kPi / 360.0) / 600.0, 1e-15);
  // Two rays one pixel apart across the image centre subtend pixelAngle to first order.
  glm::dvec3 origin, a, b;
  c.pixelRay(399.5 - 0.5, 299.5 - 0.5, origin, a);
  c.pixelRay(399.5 + 0.5, 299.5 - 0.5, origin, b);
  EXPECT_NEAR(angleBetween(a, b), c.pixelAngle(), c.pixelAngle() * 1e-5);
}

TEST(Camera, ValidateRejectsBadCameras) {
  const Camera good = makeCamera({0.0, 0.0, 3.0}, {0.0, 0.0, 0.0}, 64, 48);
  EXPECT_NO_THROW(good.validate());
  const auto expectBad = [&](auto change, const std::string& fragment) {
    Camera c = good;
    change(c);
    const std::string message = errorOf([&] { c.validate(); });
    EXPECT_NE(message.find(fragment), std::string::npos) << message;
  };
  expectBad([](Camera& c) { c.target = c.eye; }, "differ");
  expectBad([](Camera& c) { c.up = {0.0, 0.0, -2.0}; }, "parallel");
  expectBad([](Camera& c) { c.up = {0.0, 0.0, 0.0}; }, "parallel");
  expectBad([](Camera& c) { c.fovYDegrees = 0.0; }, "fov");
  expectBad([](Camera& c) { c.fovYDegrees = 180.0; }, "fov");
  expectBad([](Camera& c) { c.fovYDegrees = -10.0; }, "fov");
  expectBad([](Camera& c) { c.width = 0; }, "width");
  expectBad([](Camera& c) { c.height = 16385; }, "width");
  expectBad([](Camera& c) { c.eye.x = std::numeric_limits<double>::quiet_NaN(); }, "finite");
  expectBad([](Camera& c) { c.fovYDegrees = std::numeric_limits<double>::infinity(); }, "finite");
  Camera edge = good;
  edge.width = 1, edge.height = 16384;
  EXPECT_NO_THROW(edge.validate());
}

TEST(Camera, FramingFitsTheSceneCube) {
  const SceneTransform scene{{10.0, -4.0, 2.0}, 8.0};
  const glm::dvec3 centre = scene.origin + 4.0;
  for (const glm::dvec3 view : {glm::dvec3(0, 0, -1), glm::dvec3(1, -1, -1), glm::dvec3(0, -3, 0),
                                glm::dvec3(0, 1, 0), glm::dvec3(-2, 0.5, 1)}) {
    for (const auto& [width, height] : {std::pair{512, 512}, {800, 300}, {200, 700}}) {
      const Camera c = Camera::framing(scene, view, width, height);
      ASSERT_NO_THROW(c.validate());
      EXPECT_EQ(c.width, width);
      EXPECT_EQ(c.height, height);
      EXPECT_NEAR(glm::length(c.target - centre), 0.0, 1e-9);
      EXPECT_NEAR(angleBetween(c.target - c.eye, view), 0.0, 1e-9);
      // Every cube corner lies inside the image: its projection is within the half-extents.
      const glm::dvec3 f = glm::normalize(c.target - c.eye);
      const glm::dvec3 r = glm::normalize(glm::cross(f, c.up));
      const glm::dvec3 u = glm::cross(r, f);
      const double tanY = std::tan(c.fovYDegrees * kPi / 360.0), tanX = tanY * width / height;
      for (int corner = 0; corner < 8; ++corner) {
        const glm::dvec3 p =
            scene.origin + scene.size * glm::dvec3(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1) - c.eye;
        const double depth = glm::dot(p, f);
        ASSERT_GT(depth, 0.0);
        EXPECT_LE(std::abs(glm::dot(p, r)) / depth, tanX * (1 + 1e-9));
        EXPECT_LE(std::abs(glm::dot(p, u)) / depth, tanY * (1 + 1e-9));
      }
    }
  }
}

TEST(Camera, OccupiedBoxHoldsTheGeometryWithinOneFramingCube) {
  // A long thin rectangle, x in [0, 4] and z in [0, 0.5] at y = 0.25: its scene cube is at least 4 wide.
  Mesh mesh;
  mesh.positions = {{0.0, 0.25, 0.0}, {4.0, 0.25, 0.0}, {4.0, 0.25, 0.5}, {0.0, 0.25, 0.5}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  BuildOptions options;
  options.levels = 8;
  const Octree octree = buildOctree(mesh, options);
  const WorldBox box = occupiedBox(octree.block.view(), octree.transform, options.levels);
  // The box is made of whole cubes of the framing level (1/64 of the scene): it holds the rectangle and
  // reaches at most one such cube past it on each side (the geometry's exact bounds).
  const double cube = octree.transform.size / 64.0 * (1.0 + 1e-9);
  const glm::dvec3 lo(0.0, 0.25, 0.0), hi(4.0, 0.25, 0.5);
  for (int k = 0; k < 3; ++k) {
    EXPECT_LE(box.lo[k], lo[k]) << k;
    EXPECT_GE(box.lo[k], lo[k] - cube) << k;
    EXPECT_GE(box.hi[k], hi[k]) << k;
    EXPECT_LE(box.hi[k], hi[k] + cube) << k;
  }
  // The scene cube, which an octree without voxels below its root frames instead.
  const WorldBox cubeBox = sceneBox(octree.transform);
  EXPECT_EQ(cubeBox.lo, octree.transform.origin);
  EXPECT_EQ(cubeBox.hi, octree.transform.origin + octree.transform.size);
}

// ---------------------------------------------------------------------------------------------------------
// loadCamera

TEST(LoadCamera, ReadsAllKeys) {
  TempDir dir;
  const fs::path file = dir.file("cam.json", R"({"eye": [1, 2, 3], "target": [0.5, 0, -1], "up": [0, 0, 1],
                                                  "fov": 30.5, "width": 320, "height": 200})");
  const Camera c = loadCamera(file);
  EXPECT_EQ(c.eye, glm::dvec3(1, 2, 3));
  EXPECT_EQ(c.target, glm::dvec3(0.5, 0, -1));
  EXPECT_EQ(c.up, glm::dvec3(0, 0, 1));
  EXPECT_EQ(c.fovYDegrees, 30.5);
  EXPECT_EQ(c.width, 320);
  EXPECT_EQ(c.height, 200);
}

TEST(LoadCamera, AppliesDefaults) {
  TempDir dir;
  const Camera c = loadCamera(dir.file("cam.json", R"({"eye": [0, 0, 4], "target": [0, 0, 0]})"));
  EXPECT_EQ(c.up, glm::dvec3(0, 1, 0));
  EXPECT_EQ(c.fovYDegrees, 45.0);
  EXPECT_EQ(c.width, 512);
  EXPECT_EQ(c.height, 512);
}

TEST(LoadCamera, BadFilesNameTheFileAndTheKey) {
  TempDir dir;
  struct Case {
    const char* json;
    const char* fragment;
  };
  const Case cases[] = {
      {R"({"target": [0, 0, 0]})", "key 'eye'"},
      {R"({"eye": "here", "target": [0, 0, 0]})", "key 'eye' must be an array of 3 numbers"},
      {R"({"eye": [0, 0], "target": [0, 0, 0]})", "key 'eye' must be an array of 3 numbers"},
      {R"({"eye": [0, 0, 1], "target": [0, "0", 0]})", "key 'target' must be an array of 3 numbers"},
      {R"({"eye": [0, 0, 1], "target": [0, 0, 0], "fov": "wide"})", "key 'fov' must be a number"},
      {R"({"eye": [0, 0, 1], "target": [0, 0, 0], "width": 3.5})", "key 'width' must be an integer"},
      {R"({"eye": [0, 0, 1], "target": [0, 0, 0], "height": 0})", "key 'height' must be an integer"},
      {R"({"eye": [0, 0, 1], "target": [0, 0, 0], "fovy": 30})", "key 'fovy' is not known"},
      {R"({"eye": [1, 1, 1], "target": [1, 1, 1]})", "eye and target must differ"},
      {R"({"eye": [0, 0, 1], "target": [0, 0, 0], "up": [0, 0, 5]})", "parallel"},
      {R"({"eye": [0, 0, 1], "target": [0, 0, 0], "fov": 180})", "fov"},
      {R"([1, 2, 3])", "JSON object"},
      {R"({"eye": [0, 0, 1], )", "not valid JSON"},
  };
  int index = 0;
  for (const Case& c : cases) {
    const fs::path file = dir.file("bad" + std::to_string(index++) + ".json", c.json);
    const std::string message = errorOf([&] { loadCamera(file); });
    EXPECT_EQ(message.rfind(file.string() + ": ", 0), 0u) << message;
    EXPECT_NE(message.find(c.fragment), std::string::npos) << c.json << " -> " << message;
  }
  const fs::path missing = dir.path() / "missing.json";
  const std::string message = errorOf([&] { loadCamera(missing); });
  EXPECT_NE(message.find(missing.string()), std::string::npos) << message;
}

// ---------------------------------------------------------------------------------------------------------
// octreeRay

TEST(OctreeRay, MapsWorldPointsAtTheSameT) {
  const SceneTransform scene{{12.5, -3.0, 7.25}, 6.0};
  const Camera c = makeCamera({30.0, 4.0, 20.0}, scene.origin + 3.0, 200, 100, 40.0);
  for (const auto& [px, py] : {std::pair{0.0, 0.0}, {100.0, 50.0}, {199.0, 99.0}, {17.3, 80.9}}) {
    glm::dvec3 origin, direction;
    c.pixelRay(px, py, origin, direction);
    const OctreeRay ray = octreeRay(scene, c, px, py, 2.0f);
    for (const double t : {0.0, 1.0, 10.0, 25.0, 40.0}) {
      const glm::dvec3 expected = scene.toOctree(origin + t * direction);
      const glm::dvec3 actual = glm::dvec3(ray.origin) + t * glm::dvec3(ray.direction);
      // Float rounding of the origin and direction: a few ulps of the coordinates (~4 in [1, 8]).
      EXPECT_NEAR(glm::length(actual - expected), 0.0, 1e-5) << px << "," << py << " t " << t;
    }
    EXPECT_NEAR(ray.footprintSlope, c.pixelAngle() * 2.0 / scene.size, 1e-9);
    EXPECT_EQ(ray.footprintOrigin, 0.0f);
    const OctreeRay finest = octreeRay(scene, c, px, py, 0.0f);
    EXPECT_EQ(finest.footprintSlope, 0.0f);
    EXPECT_EQ(finest.footprintOrigin, 0.0f);
  }
}

// ---------------------------------------------------------------------------------------------------------
// PixelRays

// A packet's rays, computed side by side, are at()'s bit for bit in every lane: full and partial packets, for
// a plain camera, one far from the scene with a narrow field of view, and one looking almost straight down.
TEST(PixelRays, PacketsEqualRayByRay) {
  SceneTransform scene;
  scene.origin = glm::dvec3(1.0e6, -2.5e5, 3.0e4);
  scene.size = 37.5;
  Camera plain, far, down;
  plain.width = 640, plain.height = 480;
  far.eye = scene.origin + glm::dvec3(9.0e5, 1.0e4, -3.0e5), far.target = scene.origin, far.fovYDegrees = 0.5;
  down.eye = glm::dvec3(0.0, 10.0, 0.0), down.target = glm::dvec3(1e-3, 0.0, 0.0), down.up = {0.0, 0.0, 1.0};
  for (const Camera& camera : {plain, far, down}) {
    const PixelRays rays(scene, camera, 1.5f);
    for (const int count : {kPacketLanes, 1, 13}) {
      double across[kPacketLanes], downs[kPacketLanes];
      for (int k = 0; k < count; ++k)
        across[k] = rays.across(3 * k % camera.width), downs[k] = rays.down(7 * k % camera.height);
      OctreeRay packet[kPacketLanes];
      rays.packet(across, downs, count, 0.25f, packet);
      for (int k = 0; k < count; ++k) {
        OctreeRay one = rays.at(across[k], downs[k]);
        one.tMin = 0.25f;
        ASSERT_EQ(packet[k].origin, one.origin) << k;
        ASSERT_EQ(packet[k].direction, one.direction) << k;
        ASSERT_EQ(packet[k].tMin, one.tMin);
        ASSERT_EQ(packet[k].tMax, one.tMax);
        ASSERT_EQ(packet[k].footprintOrigin, one.footprintOrigin);
        ASSERT_EQ(packet[k].footprintSlope, one.footprintSlope);
      }
    }
  }
}

}  // namespace
}  // namespace svo
