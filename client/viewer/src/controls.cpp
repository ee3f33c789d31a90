#include "svo/viewer/controls.hpp"

#include <array>

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>

namespace svo::viewer {
namespace {

struct Binding {
  std::string_view name;
  int glfwKey;
  Action action;
  std::string_view help;
};

// WASD + Q/E as in most fly-through viewers; F1 and F12 as in most games for the overlay and screenshots.
constexpr std::array kBindings{
    Binding{"W", GLFW_KEY_W, Action::Forward, "fly forward"},
    Binding{"S", GLFW_KEY_S, Action::Back, "fly back"},
    Binding{"A", GLFW_KEY_A, Action::Left, "fly left"},
    Binding{"D", GLFW_KEY_D, Action::Right, "fly right"},
    Binding{"Q", GLFW_KEY_Q, Action::Down, "fly down"},
    Binding{"E", GLFW_KEY_E, Action::Up, "fly up"},
    Binding{"F", GLFW_KEY_F, Action::FrameScene, "frame the whole scene"},
    Binding{"F12", GLFW_KEY_F12, Action::Screenshot, "save a screenshot (PNG)"},
    Binding{"P", GLFW_KEY_P, Action::Screenshot, "save a screenshot (PNG)"},
    Binding{"F1", GLFW_KEY_F1, Action::ToggleOverlay, "show or hide the overlay"},
    Binding{"C", GLFW_KEY_C, Action::ToggleContours, "contours on or off"},
    Binding{"B", GLFW_KEY_B, Action::ToggleFilter, "post-process blur filter on or off"},
    Binding{"1", GLFW_KEY_1, Action::Shaded, "shaded"},
    Binding{"2", GLFW_KEY_2, Action::FalseColorLevel, "false color: octree level"},
    Binding{"3", GLFW_KEY_3, Action::FalseColorIterations, "false color: iterations per pixel"},
    Binding{"4", GLFW_KEY_4, Action::FalseColorDetail, "false color: resident vs wanted"},
    Binding{"Escape", GLFW_KEY_ESCAPE, Action::Quit, "quit"},
};

}  // namespace

std::optional<Action> actionOfKeyName(std::string_view name) {
  for (const Binding& b : kBindings)
    if (b.name == name) return b.action;
  return std::nullopt;
}

std::optional<Action> actionOfGlfwKey(int key) {
  for (const Binding& b : kBindings)
    if (b.glfwKey == key) return b.action;
  return std::nullopt;
}

std::string keyHelp() {
  std::string out = "mouse: drag with the left button to look; scroll: flying speed\n";
  for (const Binding& b : kBindings) {
    out += std::string(b.name) + ": " + std::string(b.help) + "\n";
  }
  return out;
}

}  // namespace svo::viewer
