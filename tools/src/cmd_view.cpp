// `svo view IN.svo` or `svo view http://host:8080/NAME`: a window that flies through the scene while it
// streams in (client/viewer). The options are `svo render`'s; --script drives the window from a file of
// timed moves and key presses, and the run's numbers are printed when the window closes.
#include <chrono>
#include <cstdio>

#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "machine.hpp"
#include "measure.hpp"
#include "pager_flags.hpp"
#include "remote.hpp"
#include "report.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/streaming.hpp"
#include "svo/gpu/gl_context.hpp"
#include "svo/viewer/controls.hpp"
#include "svo/viewer/viewer.hpp"
#include "view_flags.hpp"

namespace svo::tools {
namespace {

// The window when no --width or --height is given: 720p, the size the viewer's frame rates are quoted at.
constexpr int kDefaultWindowWidth = 1280;
constexpr int kDefaultWindowHeight = 720;

struct ViewArgs {
  std::string in, token, script, screenshots = ".", colors = "shaded", device = "cpu";
  bool rangeOnly = false, noContours = false, noOverlay = false;
  CameraFlags camera = [] {
    CameraFlags flags;
    flags.width = kDefaultWindowWidth, flags.height = kDefaultWindowHeight;
    return flags;
  }();
  RenderOptions render;
  std::size_t budget = 0;
  PagerOptions pager;
};

viewer::FalseColor falseColorOf(const std::string& name) {
  for (viewer::FalseColor mode : viewer::kFalseColors)
    if (name == viewer::nameOf(mode)) return mode;
  throw UsageError("--colors: '" + name +
                   "' is not one of: shaded, octree level, iterations per pixel, "
                   "resident vs wanted");
}

void printSummary(const viewer::ViewerSummary& s) {
  std::printf("window %.0f ms after launch, first frame %.0f ms after launch\n", s.windowSeconds * 1e3,
              s.firstFrameSeconds * 1e3);
  if (s.movingFrames > 0)
    std::printf("moving: %zu frames, %.1f frames/s, median %.1f ms at %.0f%% of the window's resolution\n",
                s.movingFrames, s.movingFramesPerSecond, s.movingFrameMsMedian, s.movingScaleMedian * 100.0);
  if (s.stillFrames > 0)
    std::printf("still: %zu frames, median %.1f ms at full resolution\n", s.stillFrames,
                s.stillFrameMsMedian);
  for (const auto& [lastChange, converged] : s.sharpAfterStop)
    std::printf("sharp after the camera stopped: last change %.3f s, converged %.3f s\n", lastChange,
                converged);
  std::printf("ray cast on %s; %s read from the store", s.device.c_str(), formatBytes(s.bytesRead).c_str());
  if (s.uploadedBytes > 0) std::printf(", %s uploaded to the GPU", formatBytes(s.uploadedBytes).c_str());
  std::printf("\n");
}

void runView(const ViewArgs& args, bool sizeGiven, std::chrono::steady_clock::time_point launched) {
  keepFreedMemoryForReuse();
  viewer::ViewerOptions options;
  options.launched = launched;
  options.sourceName = args.in;
  const RemoteOptions remote = remoteOptions(args.token, args.rangeOnly);
  options.openSource = [in = args.in, remote] { return openSliceSource(in, remote); };
  options.pager = args.pager;
  options.pager.fetchThreads = resolvedFetchThreads(args.pager.fetchThreads, args.in);
  options.defaultBudget = args.budget == 0;
  options.pager.budgetBytes =
      args.budget
          ? args.budget
          : std::size_t(std::min<std::uint64_t>(defaultMemoryShare(machineMemory()), kMaxBudgetBytes));
  options.render = args.render;
  options.settings.lodPixels = args.render.lodPixels;
  options.settings.contours = !args.noContours;
  options.settings.filter = args.render.filter;
  options.settings.falseColor = falseColorOf(args.colors);
  options.settings.overlay = !args.noOverlay;
  options.camera = explicitCamera(args.camera);
  options.viewDirection = viewDirectionOf(args.camera);
  // A camera file's size is the window's unless --width or --height says otherwise.
  const bool fromCamera = options.camera && !sizeGiven;
  options.width = fromCamera ? options.camera->width : args.camera.width;
  options.height = fromCamera ? options.camera->height : args.camera.height;
  if (!args.script.empty()) options.script = viewer::loadScript(args.script);
  options.screenshotFolder = args.screenshots;
  options.gpu = args.device == "gpu";
  try {
    printSummary(viewer::runViewer(options));
  } catch (const viewer::NoDisplay& e) {
    throw std::runtime_error(std::string("no display: ") + e.what() +
                             "; `svo render` writes the same images without a window");
  } catch (const gpu::GpuUnavailable& e) {
    throw std::runtime_error(std::string("--device gpu: ") + e.what());
  }
}

}  // namespace

void addViewCommand(CLI::App& app) {
  auto args = std::make_shared<ViewArgs>();
  auto* cmd = app.add_subcommand("view", "fly through a .svo scene in a window while it streams in");
  cmd->footer("Keys:\n" + viewer::keyHelp());
  cmd->add_option("input", args->in, "input .svo store: a file, or its http(s):// URL")
      ->required()
      ->check(storeLocator());
  addTokenOption(cmd, args->token);
  addRangeOnlyFlag(cmd, args->rangeOnly);
  addCameraFlags(*cmd, args->camera);
  addRenderFlags(*cmd, args->render, args->noContours);
  cmd->add_option("--budget", args->budget,
                  "the block pool in bytes (64M, 1G; default: half the available memory)")
      ->transform(CLI::AsSizeValue(false));
  addPagerThreadFlags(*cmd, args->pager);
  addAttributeLayoutFlag(*cmd, args->pager.attributes);
  cmd->add_option("--colors", args->colors,
                  "shaded, 'octree level', 'iterations per pixel' or 'resident vs wanted'")
      ->capture_default_str();
  cmd->add_option(
         "--device", args->device,
         "cpu: ray cast on all cores; gpu: the OpenGL 4.5 compute caster in the window's context (the "
         "pool in one storage buffer, so --budget at most its size)")
      ->check(CLI::IsMember({"cpu", "gpu"}))
      ->capture_default_str();
  cmd->add_flag("--no-overlay", args->noOverlay, "start with the overlay hidden (F1 shows it)");
  cmd->add_option("--script", args->script, "JSON steps that drive the viewer (timed moves, keys, waits)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--screenshot-dir", args->screenshots, "where F12 saves screenshots")
      ->check(CLI::ExistingDirectory)
      ->capture_default_str();
  cmd->callback([args, cmd] {
    const auto launched = std::chrono::steady_clock::now();
    applyDeviceBeamDefault(*cmd, args->device, args->render);
    runView(*args, cmd->count("--width") + cmd->count("--height") > 0, launched);
  });
}

}  // namespace svo::tools
