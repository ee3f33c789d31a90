// Plays a script (script.hpp) against the running viewer, one step after another, each frame.
#pragma once

#include <chrono>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "svo/viewer/fly_camera.hpp"
#include "svo/viewer/overlay.hpp"
#include "svo/viewer/script.hpp"

namespace svo::viewer {

class ScriptPlayer {
 public:
  using Clock = std::chrono::steady_clock;
  explicit ScriptPlayer(std::vector<ScriptStep> steps) : steps_(std::move(steps)) {}

  // What the viewer is at, for the steps that wait on it.
  struct Context {
    FlyCamera& fly;
    const OverlayStats& stats;
    const ViewSettings& settings;
    bool frameCurrent;       // the frame shown is the current camera's at full resolution
    bool converged;          // the pager has nothing left to load and the frame shows all of it
    bool screenshotPending;  // a screenshot waits for its frame
    Clock::time_point lastFrameAt;
  };
  // What the steps did this frame.
  struct Outcome {
    std::vector<Action> pressed;
    bool turned = false;  // the camera turned (look): a moving camera
    bool jumped = false;  // the camera jumped: a still camera somewhere else
    std::optional<std::filesystem::path> screenshot;
    std::optional<ViewSettings> settings;  // changed as the overlay would
  };
  // Runs the steps due at `now`.
  Outcome advance(Clock::time_point now, const Context& context);

  // The movement keys the current step holds down.
  MoveKeys heldKeys() const { return held_; }
  bool running() const { return !steps_.empty() && next_ < steps_.size(); }
  bool finished() const { return next_ >= steps_.size(); }
  // Why the script stopped early (a wait that timed out), naming the step.
  const std::optional<std::string>& failed() const { return failed_; }
  // Per wait on convergence: seconds from the step's start to the last frame that changed, and to
  // convergence.
  const std::vector<std::pair<double, double>>& sharpAfterStop() const { return sharp_; }

 private:
  bool runStep(const ScriptStep& step, Clock::time_point now, const Context& context, Outcome& out);

  std::vector<ScriptStep> steps_;
  std::size_t next_ = 0;
  bool started_ = false;  // the current step has begun
  Clock::time_point stepStart_{};
  double lookDone_ = 0.0;  // share of the current look step applied
  bool screenshotHandedOut_ = false;
  MoveKeys held_;
  std::optional<std::string> failed_;
  std::vector<std::pair<double, double>> sharp_;
};

}  // namespace svo::viewer
