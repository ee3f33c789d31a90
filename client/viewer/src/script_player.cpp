#include "script_player.hpp"

#include <algorithm>
#include <cstdio>

#include <spdlog/spdlog.h>

namespace svo::viewer {
namespace {

double secondsBetween(ScriptPlayer::Clock::time_point a, ScriptPlayer::Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

MoveKeys keysOf(Action action) {
  MoveKeys keys;
  keys.forward = action == Action::Forward, keys.back = action == Action::Back;
  keys.left = action == Action::Left, keys.right = action == Action::Right;
  keys.down = action == Action::Down, keys.up = action == Action::Up;
  return keys;
}

}  // namespace

ScriptPlayer::Outcome ScriptPlayer::advance(Clock::time_point now, const Context& context) {
  Outcome out;
  held_ = {};
  while (next_ < steps_.size() && !failed_) {
    const ScriptStep& step = steps_[next_];
    if (!started_) {
      started_ = true, stepStart_ = now, lookDone_ = 0.0, screenshotHandedOut_ = false;
      spdlog::debug("{}: {}", step.where, describe(step));
    }
    if (!runStep(step, now, context, out)) break;
    ++next_;
    started_ = false;
    // The steps after one that changed the view see its effect from the next frame on.
    if (step.kind == ScriptStep::Kind::Camera || step.kind == ScriptStep::Kind::Key ||
        step.kind == ScriptStep::Kind::Set)
      break;
  }
  return out;
}

// Returns whether the step is done.
bool ScriptPlayer::runStep(const ScriptStep& step, Clock::time_point now, const Context& context,
                           Outcome& out) {
  using K = ScriptStep::Kind;
  const double inStep = secondsBetween(stepStart_, now);
  const auto timedOut = [&](const std::string& what) {
    if (inStep <= step.seconds) return false;
    failed_ = step.where + ": " + what + " within " + std::to_string(step.seconds) + " s";
    return true;
  };
  switch (step.kind) {
    case K::Camera: {
      Camera camera = step.camera;
      const Camera current = context.fly.camera(1, 1);
      camera.width = current.width, camera.height = current.height;
      context.fly.set(camera);
      out.jumped = true;
      return true;
    }
    case K::Hold:
      if (inStep >= step.seconds) return true;
      held_ = keysOf(step.action);
      return false;
    case K::Look: {
      const double share = step.seconds > 0.0 ? std::min(1.0, inStep / step.seconds) : 1.0;
      context.fly.look(step.dx * (share - lookDone_), step.dy * (share - lookDone_));
      lookDone_ = share;
      out.turned = true;
      return share >= 1.0;
    }
    case K::Key:
      out.pressed.push_back(step.action);
      return true;
    case K::Sleep:
      return inStep >= step.seconds;
    case K::WaitConverged:
      if (context.converged && context.frameCurrent) {
        sharp_.emplace_back(std::max(0.0, secondsBetween(stepStart_, context.lastFrameAt)), inStep);
        spdlog::info("{}: converged {:.3f} s after the camera stopped (last change {:.3f} s)", step.where,
                     inStep, sharp_.back().first);
        return true;
      }
      return timedOut("the view did not converge");
    case K::WaitFile:
      if (std::filesystem::exists(step.path)) return true;
      return timedOut(step.path.string() + " did not appear");
    case K::Screenshot:
      if (!screenshotHandedOut_) {
        out.screenshot = step.path;
        screenshotHandedOut_ = true;
        return false;
      }
      return !context.screenshotPending;
    case K::PrintOverlay:
      for (const std::string& line : overlayLines(context.stats)) std::printf("overlay: %s\n", line.c_str());
      std::fflush(stdout);
      return true;
    case K::Set: {
      ViewSettings settings = out.settings.value_or(context.settings);
      if (step.budgetBytes) settings.budgetBytes = *step.budgetBytes;
      if (step.lodPixels) settings.lodPixels = *step.lodPixels;
      if (step.contours) settings.contours = *step.contours;
      if (step.falseColor) settings.falseColor = *step.falseColor;
      out.settings = settings;
      return true;
    }
    case K::Mark:
      std::printf("mark %s\n", step.text.c_str());
      std::fflush(stdout);
      return true;
  }
  return true;
}

}  // namespace svo::viewer
