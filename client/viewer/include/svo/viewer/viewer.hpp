// `svo view`: a window that flies through a scene streaming in (GLFW, OpenGL, Dear ImGui). Frames are ray
// cast on the CPU from the pager's pool; moving frames render at a lower resolution to stay interactive, a
// still view refines to the full resolution, and the window never waits for a slice.
#pragma once

#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "svo/client/pager.hpp"
#include "svo/client/render.hpp"
#include "svo/client/slice_source.hpp"
#include "svo/viewer/overlay.hpp"
#include "svo/viewer/script.hpp"

namespace svo::viewer {

// There is no display to open a window on (no DISPLAY, no X server, no OpenGL 3.3).
struct NoDisplay : std::runtime_error {
  using std::runtime_error::runtime_error;
};

struct ViewerOptions {
  std::string sourceName;  // the file or URL, for the title and the overlay
  // Opens the store (called on a background thread, so that a slow server does not hold the window).
  std::function<std::shared_ptr<const SliceSource>()> openSource;
  PagerOptions pager;          // its budget is the pool's
  bool defaultBudget = false;  // the budget is a default: on the GPU it shrinks to what one buffer holds
  RenderOptions render;
  ViewSettings settings;         // LOD, contours and false colors as the viewer starts
  std::optional<Camera> camera;  // else the whole scene seen along viewDirection
  glm::dvec3 viewDirection = kDefaultViewDirection;
  int width = 1280, height = 720;  // the window
  std::vector<ScriptStep> script;  // loadScript's; empty: a person drives the viewer
  // Ray cast with the GPU caster (an OpenGL 4.5 compute shader in the window's context) over the pool
  // mirrored in one storage buffer, instead of on the CPU; frames are read back for the overlay's numbers,
  // the false colors and the pager's ray feedback.
  bool gpu = false;
  std::filesystem::path screenshotFolder = ".";
  std::chrono::steady_clock::time_point launched = std::chrono::steady_clock::now();
};

// What a run measured, printed when the viewer closes.
struct ViewerSummary {
  double windowSeconds = -1.0;      // launch to the window
  double firstFrameSeconds = -1.0;  // launch to the first frame shown
  std::size_t movingFrames = 0, stillFrames = 0;
  double movingFrameMsMedian = 0.0, stillFrameMsMedian = 0.0;  // update + render + display
  double movingFramesPerSecond = 0.0;  // moving frames over the seconds the camera moved
  double movingScaleMedian = 1.0;      // their resolution against the window's
  // For each script wait on convergence: seconds from the camera stopping to the view converged, and to
  // the last frame that changed the image.
  std::vector<std::pair<double, double>> sharpAfterStop;
  std::string device;               // what ray cast: the CPU, or the GPU's name
  std::uint64_t uploadedBytes = 0;  // with the GPU: pool pages uploaded over the run
  std::uint64_t bytesRead = 0;      // compressed bytes read from the store over the run
};

// Runs until the window closes, Escape, or the script's last step. Throws NoDisplay without a display, and
// std::runtime_error for a store that cannot be opened or a script that fails (a wait that times out).
ViewerSummary runViewer(const ViewerOptions& options);

}  // namespace svo::viewer
