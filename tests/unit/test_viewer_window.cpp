// `svo view` for real: a window on an Xvfb display of its own, driven by a --script of timed moves and key
// presses. Its window is grabbed through X (ImageMagick's import) once a view has converged and compared
// with `svo render`'s PNG of the same camera and budget; the overlay's numbers are compared with what
// `svo render`'s pager reports for that view and with the deepest level in its EXR's depth and voxel sizes.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <regex>
#include <sstream>
#include <thread>

#include <OpenImageIO/imageio.h>

#include "command_helpers.hpp"
#include "paging_helpers.hpp"
#include "reference.hpp"

namespace fs = std::filesystem;

namespace {

// Seconds a step of these tests may take on a busy 2-core machine before the test fails.
constexpr int kPatienceSeconds = 120;
constexpr int kWidth = 320, kHeight = 240;

// A child process with its output in a file; killed when the test ends early.
class Child {
 public:
  Child(const std::vector<std::string>& argv, const fs::path& output, const std::string& display) {
    pid_ = ::fork();
    if (pid_ == 0) {
      const int fd = ::open(output.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
      ::dup2(fd, 1), ::dup2(fd, 2);
      if (display.empty()) {
        ::unsetenv("DISPLAY");
      } else {
        ::setenv("DISPLAY", display.c_str(), 1);
      }
      std::vector<char*> args;
      for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
      args.push_back(nullptr);
      ::execvp(args[0], args.data());
      ::_exit(127);
    }
  }
  ~Child() {
    if (pid_ > 0) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  // Whether it has not exited yet.
  bool running() {
    int status = 0;
    if (pid_ <= 0) return false;
    if (::waitpid(pid_, &status, WNOHANG) != pid_) return true;
    pid_ = -1;
    exitCode_ = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    return false;
  }
  // The exit code, or -1 when it did not exit within the patience (then it is killed).
  int wait() {
    if (pid_ <= 0) return exitCode_;
    for (int i = 0; i < kPatienceSeconds * 10; ++i) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return -1;
  }

 private:
  pid_t pid_ = -1;
  int exitCode_ = -1;
};

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// An X server of the test's own. Its display number is drawn from the process id far above :0: X clients try
// the display's abstract socket first, and that namespace may be shared with other machines' sandboxes whose
// servers sit on the low numbers.
class Xvfb {
 public:
  Xvfb() {
    constexpr int kFirstDisplay = 100, kDisplays = 800, kTries = 20;
    for (int t = 0; t < kTries && display_.empty(); ++t) {
      const int n = kFirstDisplay + int((::getpid() + t * 37) % kDisplays);
      if (fs::exists("/tmp/.X" + std::to_string(n) + "-lock")) continue;
      const std::string name = ":" + std::to_string(n);
      pid_ = ::fork();
      if (pid_ == 0) {
        const int null = ::open("/dev/null", O_WRONLY);
        ::dup2(null, 1), ::dup2(null, 2);
        // -noreset: an X server resets when its last client leaves, and one connecting meanwhile is refused.
        ::execlp("Xvfb", "Xvfb", name.c_str(), "-nolisten", "tcp", "-noreset", "-screen", "0", "640x480x24",
                 static_cast<char*>(nullptr));
        ::_exit(127);
      }
      if (accepts(n)) {
        display_ = name;
      } else {
        stop();
      }
    }
  }
  ~Xvfb() { stop(); }
  const std::string& display() const { return display_; }  // empty when none started

 private:
  void stop() {
    if (pid_ > 0) ::kill(pid_, SIGTERM), ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
  // Whether the server on `display` takes connections on its socket before it exits or the patience ends.
  bool accepts(int display) {
    const std::string path = "/tmp/.X11-unix/X" + std::to_string(display);
    for (int i = 0; i < kPatienceSeconds * 10; ++i) {
      if (::waitpid(pid_, nullptr, WNOHANG) == pid_) {  // it exited: the display was taken
        pid_ = -1;
        return false;
      }
      const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
      sockaddr_un address{};
      address.sun_family = AF_UNIX;
      std::strncpy(address.sun_path, path.c_str(), sizeof address.sun_path - 1);
      const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
      ::close(fd);
      if (ok) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    return false;
  }

  pid_t pid_ = -1;
  std::string display_;
};

// The grab matches the reference when no channel differs by more than 1 (the stated tolerance: X's 24-bit
// visual keeps 8 bits per channel, so the codes should be equal) on at least 99.9% of the pixels.
void expectSameImage(const fs::path& grab, const fs::path& reference) {
  const svotest::Rgb8 a = svotest::readRgb8(grab), b = svotest::readRgb8(reference);
  ASSERT_EQ(a.width, b.width) << grab;
  ASSERT_EQ(a.height, b.height) << grab;
  std::size_t off = 0;
  int worst = 0;
  for (std::size_t i = 0; i < a.pixels.size(); i += 3) {
    int d = 0;
    for (int c = 0; c < 3; ++c) d = std::max(d, std::abs(int(a.pixels[i + c]) - int(b.pixels[i + c])));
    worst = std::max(worst, d);
    off += d > 1;
  }
  EXPECT_LE(double(off), 0.001 * double(a.width) * a.height)
      << grab << " vs " << reference << ": worst " << worst;
}

// Waits until `file` holds `text`; false after the patience or when `writer` exits without writing it.
bool waitForText(const fs::path& file, const std::string& text, Child& writer) {
  for (int i = 0; i < kPatienceSeconds * 10; ++i) {
    if (slurp(file).find(text) != std::string::npos) return true;
    if (!writer.running()) return slurp(file).find(text) != std::string::npos;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return false;
}

std::string cameraJson(glm::dvec3 eye, glm::dvec3 target, bool withSize) {
  std::ostringstream s;
  s.precision(17);
  s << "{\"eye\": [" << eye.x << ", " << eye.y << ", " << eye.z << "], \"target\": [" << target.x << ", "
    << target.y << ", " << target.z << "], \"fov\": 45";
  if (withSize) s << ", \"width\": " << kWidth << ", \"height\": " << kHeight;
  return s.str() + "}";
}

// The deepest octree level in an EXR written by `svo render --aux` (Z and voxelPixels channels).
int deepestLevelOfExr(const fs::path& exr, double fovDegrees, double sceneSize) {
  auto in = OIIO::ImageInput::open(exr.string());
  if (!in) return -2;
  const OIIO::ImageSpec spec = in->spec();
  std::vector<float> values(std::size_t(spec.width) * spec.height * std::size_t(spec.nchannels));
  in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, values.data());
  const double pixelAngle = 2.0 * std::tan(fovDegrees * M_PI / 360.0) / spec.height;
  int deepest = -1;
  for (std::size_t i = 0; i < std::size_t(spec.width) * spec.height; ++i) {
    const float* p = &values[i * std::size_t(spec.nchannels)];
    if (!std::isfinite(p[4])) continue;
    const double voxel = double(p[5]) * p[4] * pixelAngle / sceneSize;
    deepest = std::max(deepest, int(std::lround(-std::log2(voxel))));
  }
  return deepest;
}

// The viewer on `device` (cpu or gpu) against `svo render` on the CPU.
void expectScreenshotsMatchRender(const std::string& device) {
  Xvfb x;
  ASSERT_FALSE(x.display().empty()) << "Xvfb did not start (tools/scripts/install-deps.sh installs it)";
  svotest::TempDir dir;
  const fs::path store = svotest::sphereStore();
  const glm::dvec3 closeEye{0.45, 0.35, 1.45}, closeTarget{0.0, 0.0, 0.8};
  const glm::dvec3 farEye{2.2, 1.3, 2.6}, farTarget{0.0, -0.2, 0.0};
  const fs::path closeCamera = dir.file("close.json", cameraJson(closeEye, closeTarget, true));
  const fs::path farCamera = dir.file("far.json", cameraJson(farEye, farTarget, true));
  const fs::path screenshot = dir.path() / "far_screenshot.png";
  const std::string grabbed = (dir.path() / "grabbed").string();
  // From the far camera: fly, turn, jump to the close-up, converge, hide the overlay, hold still for the
  // grab; then back to the far camera for a screenshot and a grab with the overlay hidden.
  const fs::path script =
      dir.file("script.json",
               "[{\"hold\": \"W\", \"seconds\": 0.4}, {\"look\": [30, 10], "
               "\"seconds\": 0.3}, {\"camera\": " +
                   cameraJson(closeEye, closeTarget, false) +
                   "}, {\"wait\": \"converged\"}, "
                   "{\"key\": \"F1\"}, {\"sleep\": 0.2}, {\"print\": \"overlay\"}, {\"mark\": "
                   "\"grab-close\"}, {\"wait\": \"file\", "
                   "\"path\": \"" +
                   grabbed + "-close\"}, {\"camera\": " + cameraJson(farEye, farTarget, false) +
                   "}, "
                   "{\"wait\": \"converged\"}, {\"screenshot\": \"" +
                   screenshot.string() +
                   "\"}, {\"mark\": \"grab-far\"}, "
                   "{\"wait\": \"file\", \"path\": \"" +
                   grabbed +
                   "-far\"}, {\"set\": {\"budget\": 2097152}}, "
                   "{\"wait\": \"converged\"}, {\"print\": \"overlay\"}]");
  const fs::path output = dir.path() / "view.out";
  Child viewer({SVO_BINARY, "view", store.string(), "--camera", farCamera.string(), "--budget", "64M",
                "--script", script.string(), "--device", device},
               output, x.display());
  for (const std::string name : {"close", "far"}) {
    ASSERT_TRUE(waitForText(output, "mark grab-" + name, viewer)) << slurp(output);
    const fs::path grab = dir.path() / ("grab_" + name + ".png");
    svotest::runShell("import -display " + x.display() + " -window root -crop " + std::to_string(kWidth) +
                      "x" + std::to_string(kHeight) + "+0+0 +repage " + grab.string());
    std::ofstream(grabbed + "-" + name).put('\n');
  }
  ASSERT_EQ(viewer.wait(), 0) << slurp(output);
  const std::string viewed = slurp(output);
  EXPECT_EQ(viewed.find("overlay: ray casting on the CPU") != std::string::npos, device == "cpu") << viewed;
  // A budget set as the overlay sets it opens a new pool of that size, which the view then fills within it.
  std::smatch m;
  const std::string afterBudget = viewed.substr(viewed.rfind("overlay: source"));
  ASSERT_TRUE(std::regex_search(afterBudget, m, std::regex(R"(resident ([\d.]+) MB of 2.0 MB)"))) << viewed;
  EXPECT_LE(std::stod(m[1]), 2.0);
  EXPECT_NE(afterBudget.find("converged"), std::string::npos) << afterBudget;

  // `svo render` of the same cameras and budget, each in a fresh process.
  for (const std::string name : {"close", "far"}) {
    const fs::path camera = dir.path() / (name + ".json");
    const std::string common = std::string(SVO_BINARY) + " render " + store.string() + " --camera " +
                               camera.string() + " --budget 64M";
    const std::string rendered = svotest::runShell(common + " -o " + (dir.path() / (name + ".png")).string());
    ASSERT_NE(rendered.find("wrote"), std::string::npos) << rendered;
    expectSameImage(dir.path() / ("grab_" + name + ".png"), dir.path() / (name + ".png"));
    if (name == "far") expectSameImage(screenshot, dir.path() / "far.png");
    if (name != "close") continue;
    // The overlay's numbers at the converged close-up against the render's pager for the same view.
    ASSERT_TRUE(std::regex_search(rendered, m, std::regex(R"((\d+) slices resident)"))) << rendered;
    const std::string slices = m[1];
    ASSERT_TRUE(
        std::regex_search(viewed, m, std::regex(R"(overlay: resident [\d.]+ MB of 64.0 MB, (\d+) slices)")))
        << viewed;
    EXPECT_EQ(m[1], slices) << viewed << rendered;
    EXPECT_NE(viewed.find("overlay: slices in flight 0, wanted 0, converged"), std::string::npos) << viewed;
    const std::string exr = svotest::runShell(common + " --aux -o " + (dir.path() / "close.exr").string());
    ASSERT_NE(exr.find("wrote"), std::string::npos) << exr;
    const svo::StoreReader reader(store);
    const int deepest = deepestLevelOfExr(dir.path() / "close.exr", 45.0, reader.header().transform.size);
    ASSERT_TRUE(
        std::regex_search(viewed, m, std::regex(R"(overlay: deepest level on screen (\d+) of (\d+))")))
        << viewed;
    EXPECT_EQ(std::stoi(m[1]), deepest);
    EXPECT_EQ(std::stoi(m[2]), reader.header().parameters.levels);
  }
}

TEST(ViewerWindow, ScreenshotsThroughXMatchRenderAndTheOverlayMatchesThePager) {
  expectScreenshotsMatchRender("cpu");
}

// The same on the GPU caster (llvmpipe's OpenGL 4.5 under Xvfb): the pool mirrored in one buffer.
TEST(ViewerWindow, OnTheGpuScreenshotsMatchTheCpuRenderAndTheOverlayMatchesThePager) {
  expectScreenshotsMatchRender("gpu");
}

TEST(ViewerWindow, WithoutADisplayItSaysSoInOneLineAndSuggestsRender) {
  svotest::TempDir dir;
  const fs::path output = dir.path() / "out.txt";
  Child viewer({SVO_BINARY, "view", svotest::sphereStore().string()}, output, "");
  EXPECT_EQ(viewer.wait(), 1);
  const std::string said = slurp(output);
  EXPECT_NE(said.find("svo: no display"), std::string::npos) << said;
  EXPECT_NE(said.find("svo render"), std::string::npos) << said;
  EXPECT_EQ(std::count(said.begin(), said.end(), '\n'), 1) << said;
}

TEST(ViewerWindow, ABadScriptIsNamedBeforeAnyWindowOpens) {
  svotest::TempDir dir;
  const fs::path script = dir.file("bad.json", R"([{"sleep": 0.1}, {"hold": "W", "seconds": "long"}])");
  const fs::path output = dir.path() / "out.txt";
  Child viewer({SVO_BINARY, "view", svotest::sphereStore().string(), "--script", script.string()}, output,
               "");
  EXPECT_EQ(viewer.wait(), 1);
  const std::string said = slurp(output);
  EXPECT_NE(said.find("bad.json: step 2: 'seconds' must be a number"), std::string::npos) << said;
}

}  // namespace
