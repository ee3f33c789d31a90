// What the viewer's keys do, by name: the window's key presses and a script's key steps become the same
// actions.
#pragma once

#include <optional>
#include <string>
#include <string_view>

namespace svo::viewer {

enum class Action {
  // Held: the camera moves while the key is down.
  Forward,
  Back,
  Left,
  Right,
  Down,
  Up,
  // Pressed: once per press.
  FrameScene,
  Screenshot,
  ToggleOverlay,
  ToggleContours,
  ToggleFilter,
  Shaded,
  FalseColorLevel,
  FalseColorIterations,
  FalseColorDetail,
  Quit,
};
inline constexpr int kHeldActions = 6;  // Forward .. Up
inline bool isHeld(Action a) {
  return int(a) < kHeldActions;
}

// The action of a key name as a script writes it ("W", "F1", "Escape"); nullopt for a key that does nothing.
std::optional<Action> actionOfKeyName(std::string_view name);
// The same for a GLFW key code.
std::optional<Action> actionOfGlfwKey(int key);
// Every key and what it does, one line each (the overlay's help and `svo view --help`).
std::string keyHelp();

}  // namespace svo::viewer
