// The viewer (`svo view`): its camera, scripts, false colors and sRGB encoding against independent
// references, and the real window under Xvfb driven by a script, its screenshots grabbed through X and
// compared with `svo render`'s images of the same cameras, its overlay's numbers with the pager's.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <regex>
#include <sstream>
#include <thread>

#include <OpenImageIO/imageio.h>
#include <glm/geometric.hpp>

#include "paging_helpers.hpp"
#include "reference.hpp"
#include "svo/client/streaming.hpp"
#include "svo/viewer/false_color.hpp"
#include "svo/viewer/fly_camera.hpp"
#include "svo/viewer/script.hpp"

namespace fs = std::filesystem;
using namespace svo;
using namespace svo::viewer;

namespace {

Camera lookingAt(glm::dvec3 eye, glm::dvec3 target, int width = 320, int height = 240) {
  Camera c;
  c.eye = eye, c.target = target, c.width = width, c.height = height, c.fovYDegrees = 40.0;
  return c;
}

TEST(FlyCamera, KeepsTheCameraItWasSetToExactlyUntilItMoves) {
  SceneTransform scene;
  scene.origin = glm::dvec3(-3.0), scene.size = 6.0;
  const Camera start = lookingAt({0.1, 0.7, 4.0}, {0.3, -0.2, 0.0});
  FlyCamera fly(scene, svo::sceneBox(scene), start);
  const Camera c = fly.camera(640, 480);
  EXPECT_EQ(c.eye, start.eye);
  EXPECT_EQ(c.target, start.target);
  EXPECT_EQ(c.up, start.up);
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.height, 480);
}

TEST(FlyCamera, FliesAlongTheViewAtItsSpeedAndTurnsWithTheMouse) {
  SceneTransform scene;
  scene.size = 8.0;
  FlyCamera fly(scene, svo::sceneBox(scene), lookingAt({0.0, 0.0, 5.0}, {0.0, 0.0, 0.0}));
  EXPECT_DOUBLE_EQ(fly.speed(), 8.0 / kSecondsToCrossScene);
  MoveKeys forward;
  forward.forward = true;
  ASSERT_TRUE(fly.move(forward, 0.5));
  const Camera moved = fly.camera(10, 10);
  EXPECT_NEAR(moved.eye.z, 5.0 - 0.5 * fly.speed(), 1e-12);
  EXPECT_NEAR(moved.eye.x, 0.0, 1e-12);
  // Forward and back cancel: no move.
  MoveKeys both = forward;
  both.back = true;
  EXPECT_FALSE(fly.move(both, 1.0));
  // A drag to the right turns right: looking down -z, right is +x.
  fly.look(1.0 / kLookRadiansPerPixel * (M_PI / 2.0), 0.0);
  const Camera turned = fly.camera(10, 10);
  const glm::dvec3 view = glm::normalize(turned.target - turned.eye);
  EXPECT_NEAR(view.x, 1.0, 1e-9);
  // Pitch stops short of straight up, where the camera basis would degenerate; the camera stays valid.
  fly.look(0.0, -1e6);
  EXPECT_DOUBLE_EQ(fly.pitch(), kMaxPitch);
  EXPECT_NO_THROW(fly.camera(10, 10).validate());
  fly.scaleSpeed(2.0);
  EXPECT_NEAR(fly.speed(), 8.0 / kSecondsToCrossScene * kSpeedPerScrollStep * kSpeedPerScrollStep, 1e-12);
}

TEST(FlyCamera, FramingTheSceneKeepsTheHeadingAndMatchesTheRenderersFraming) {
  SceneTransform scene;
  scene.origin = glm::dvec3(1e6, -2e6, 3e6), scene.size = 0.5;  // far from the origin
  // The contents: a slab in the cube's lower half, as occupiedBox would find it.
  const svo::WorldBox contents{scene.origin, scene.origin + glm::dvec3(0.5, 0.125, 0.25)};
  FlyCamera fly(scene, contents, lookingAt(scene.origin + glm::dvec3(9.0), scene.origin));
  fly.frameScene();
  const Camera framed = fly.camera(320, 240);
  const glm::dvec3 heading = glm::normalize(framed.target - framed.eye);
  const Camera reference = Camera::framingBox(contents.lo, contents.hi, heading, 320, 240);
  EXPECT_LT(glm::length(framed.eye - reference.eye), 1e-9 * 1e6);
  EXPECT_NEAR(glm::dot(heading, glm::normalize(glm::dvec3(-1.0))), 1.0, 1e-12);
}

TEST(ViewerScript, ReadsEveryKindOfStep) {
  svotest::TempDir dir;
  const fs::path file = dir.file("s.json", R"([
    {"camera": {"eye": [0, 0, 3], "target": [0, 0, 0]}},
    {"hold": "W", "seconds": 0.5}, {"look": [10, -5], "seconds": 0.2}, {"key": "F1"}, {"sleep": 0.1},
    {"wait": "converged"}, {"wait": "file", "path": "x", "timeout": 3}, {"screenshot": "a.png"},
    {"print": "overlay"}, {"mark": "here"}, {"set": {"budget": 16777216, "lod": 2, "colors": "octree level"}}])");
  const std::vector<ScriptStep> steps = loadScript(file);
  ASSERT_EQ(steps.size(), 11u);
  using K = ScriptStep::Kind;
  EXPECT_EQ(steps[0].kind, K::Camera);
  EXPECT_EQ(steps[0].camera.eye, glm::dvec3(0, 0, 3));
  EXPECT_EQ(steps[1].action, Action::Forward);
  EXPECT_EQ(steps[1].seconds, 0.5);
  EXPECT_EQ(steps[2].dx, 10.0);
  EXPECT_EQ(steps[2].dy, -5.0);
  EXPECT_EQ(steps[3].action, Action::ToggleOverlay);
  EXPECT_EQ(steps[5].kind, K::WaitConverged);
  EXPECT_EQ(steps[5].seconds, kDefaultWaitSeconds);
  EXPECT_EQ(steps[6].path, "x");
  EXPECT_EQ(steps[6].seconds, 3.0);
  EXPECT_EQ(steps[7].path, "a.png");
  EXPECT_EQ(steps[9].text, "here");
  EXPECT_EQ(steps[10].budgetBytes, std::size_t(16) << 20);
  EXPECT_EQ(steps[10].lodPixels, 2.0f);
  EXPECT_EQ(steps[10].falseColor, FalseColor::OctreeLevel);
  EXPECT_FALSE(steps[10].contours);
}

TEST(ViewerScript, NamesTheStepAndTheFieldOfABadOne) {
  svotest::TempDir dir;
  const auto errorOf = [&](const std::string& json) {
    try {
      loadScript(dir.file("bad.json", json));
    } catch (const std::runtime_error& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(errorOf(R"([{"sleep": 1}, {"key": "F13"}])").find("step 2: 'F13' is not a key"),
            std::string::npos);
  EXPECT_NE(errorOf(R"([{"hold": "F1", "seconds": 1}])").find("step 1: 'hold' takes a movement key"),
            std::string::npos);
  EXPECT_NE(errorOf(R"([{"sleep": -1}])").find("'sleep' must be a number of seconds"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"sleep": 1e999}])").find("not valid JSON"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"hold": "W"}])").find("'seconds' is missing"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"key": "W", "seconds": 1}])").find("'seconds' is not known here"),
            std::string::npos);
  EXPECT_NE(
      errorOf(R"([{"camera": {"eye": [0,0,1], "target": [0,0,1]}}])").find("step 1: camera: eye and target"),
      std::string::npos);
  EXPECT_NE(errorOf(R"([{"camera": {"eye": [0,0,1], "target": [0,0,0], "width": 9}}])").find("window's size"),
            std::string::npos);
  EXPECT_NE(errorOf(R"([{"screenshot": "a.jpg"}])").find(".png"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"wait": "forever"}])").find("'wait' must be"), std::string::npos);
  EXPECT_NE(errorOf(R"({"sleep": 1})").find("JSON array"), std::string::npos);
  EXPECT_NE(errorOf(R"([{}])").find("step 1: an empty step"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"set": {"budget": 1000}}])").find("'budget' must be a whole number"),
            std::string::npos);
  EXPECT_NE(errorOf(R"([{"set": {"lod": -1}}])").find("'lod' must be"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"set": {"colors": "pink"}}])").find("'colors' must be one of"), std::string::npos);
  EXPECT_NE(errorOf(R"([{"set": {"speed": 2}}])").find("'speed' is not a setting"), std::string::npos);
}

// The display's 8-bit codes against the sRGB curve written out in double precision (IEC 61966-2-1): equal
// but where the float curve and the double one round a value within 1e-4 of a code boundary differently.
TEST(Srgb, EncodedCodesMatchTheStandardCurve) {
  Frame frame;
  constexpr int kValues = 1 << 20;
  frame.width = kValues, frame.height = 1;
  for (int i = 0; i < kValues; ++i) {
    const float v = float(i) / float(kValues - 1) * 1.2f - 0.1f;  // beyond [0, 1] both ways
    frame.color.push_back(glm::vec4(v, v * v, std::sqrt(std::max(v, 0.0f)), 1.0f));
  }
  frame.color.push_back(glm::vec4(std::nanf(""), 1.0f, 0.0f, 1.0f));
  frame.width += 1;
  std::vector<std::uint8_t> rgba;
  encodeSrgb8(frame, rgba);
  ASSERT_EQ(rgba.size(), frame.color.size() * 4);
  std::size_t differing = 0;
  for (std::size_t i = 0; i + 1 < frame.color.size(); ++i) {
    for (int c = 0; c < 3; ++c) {
      const double linear = std::clamp(double(frame.color[i][c]), 0.0, 1.0);
      const double s = linear <= 0.0031308 ? 12.92 * linear : 1.055 * std::pow(linear, 1.0 / 2.4) - 0.055;
      const double code = s * 255.0;
      const int expected = int(std::lround(code));
      const int got = rgba[i * 4 + std::size_t(c)];
      if (got != expected) {
        ++differing;
        ASSERT_LT(std::abs(code - std::floor(code) - 0.5), 1e-4) << "value " << frame.color[i][c];
      }
    }
    ASSERT_EQ(rgba[i * 4 + 3], 255);
  }
  EXPECT_LT(differing, 20u);
  EXPECT_EQ(rgba[(frame.color.size() - 1) * 4], 0);  // NaN is black
}

// The deepest level a frame shows equals the deepest level of the voxels its rays hit, counted from the ray
// caster's own hit scale.
TEST(FalseColors, DeepestLevelIsTheRayCastersDeepestHit) {
  Pager pager(svotest::sphereStore());
  const Camera camera = svotest::cameraAt({0.6, 0.5, 1.6}, {0.0, 0.0, 0.7}, 96);
  svotest::converge(pager, svotest::everything(pager, camera));
  RenderOptions options;
  options.lodPixels = 0.0f;
  const Frame frame = render(pager.trunk(), pager.transform(), camera, options);
  const PixelRays rays(pager.transform(), camera, 0.0f);
  int deepest = -1;
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x)
      if (const CastHit hit = castRay(pager.trunk(), rays(x, y), options.cast); hit.hit)
        deepest = std::max(deepest, kMaxLevels - hit.scale);
  ASSERT_GT(deepest, 0);
  EXPECT_EQ(deepestLevel(frame, camera, pager.transform().size), deepest);
}

// Resident vs wanted: from the trunk alone much of a close-up waits for finer slices; once the view has
// converged with room for all of it, every pixel is at its target or at the finest level the store has.
TEST(FalseColors, DetailMapShowsWhatIsMissingUntilTheViewConverges) {
  Pager pager(svotest::sphereStore());
  const Camera camera = svotest::cameraAt({0.4, 0.3, 1.5}, {0.0, 0.0, 0.8}, 96);
  RenderOptions options;
  options.diagnostics = true;
  const Frame coarse = render(pager.trunk(), pager.transform(), camera, options);
  const auto count = [](const std::vector<PixelDetail>& map, PixelDetail d) {
    return std::count(map.begin(), map.end(), d);
  };
  const std::vector<PixelDetail> before = pager.detailMap(coarse, camera, options.lodPixels);
  EXPECT_GT(count(before, PixelDetail::Waiting), 100);
  EXPECT_EQ(count(before, PixelDetail::Miss), std::count_if(coarse.depth.begin(), coarse.depth.end(),
                                                            [](float d) { return !std::isfinite(d); }));
  StreamedFrame last;
  ASSERT_TRUE(convergeView(pager, camera, options, 60.0, &last).converged());
  const std::vector<PixelDetail> after = pager.detailMap(last.frame, camera, options.lodPixels);
  EXPECT_EQ(count(after, PixelDetail::Waiting) + count(after, PixelDetail::Loading) +
                count(after, PixelDetail::NoRoom),
            0);
  EXPECT_GT(count(after, PixelDetail::AtTarget) + count(after, PixelDetail::FinestStored), 1000);
}

}  // namespace
