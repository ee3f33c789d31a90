// The viewer's window: GLFW with an OpenGL 3.3 core context (4.5 for the GPU caster), the frame shown as a
// texture blitted over the whole window, and Dear ImGui for the overlay. GLFW, GL and ImGui stay inside
// window.cpp and overlay_ui.cpp.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <glm/vec2.hpp>

#include "svo/viewer/controls.hpp"
#include "svo/viewer/fly_camera.hpp"

struct GLFWwindow;

namespace svo::viewer {

class Window {
 public:
  struct Input {
    std::function<void(Action)> pressed;          // a key's action, once per press
    std::function<void(double, double)> dragged;  // mouse motion with the left button down, pixels
    std::function<void(double)> scrolled;         // scroll steps
  };
  // Throws NoDisplay when there is no display to open a window on. `compute`: an OpenGL 4.5 context, for
  // the GPU caster.
  Window(int width, int height, const std::string& title, bool compute, Input input);
  ~Window();
  Window(const Window&) = delete;
  Window& operator=(const Window&) = delete;

  bool closing() const;
  void close();
  // Handles pending events; waits up to `seconds` for one first when positive.
  void handleEvents(double seconds);
  // The movement keys down now (none while the overlay has the keyboard).
  MoveKeys heldKeys() const;
  glm::ivec2 framebufferSize() const;
  std::string renderer() const;  // GL_RENDERER

  // The image to show: RGBA8, rows from the top.
  void upload(const std::vector<std::uint8_t>& rgba, int width, int height);
  // Draws the last image stretched over the window (smoothed when it is smaller).
  void draw();
  // Between beginOverlay and endOverlay, ImGui calls draw the overlay; present swaps the buffers.
  void beginOverlay();
  void endOverlay();
  void present();

 private:
  GLFWwindow* window_ = nullptr;
  Input input_;
  unsigned texture_ = 0, readFramebuffer_ = 0;
  int textureWidth_ = 0, textureHeight_ = 0;
  double lastX_ = 0.0, lastY_ = 0.0;
  bool dragging_ = false;
};

}  // namespace svo::viewer
