#include "window.hpp"

#include <stdexcept>

#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>
#include <backends/imgui_impl_glfw.h>
#include <backends/imgui_impl_opengl3.h>
#include <imgui.h>

#include "svo/viewer/viewer.hpp"

namespace svo::viewer {
namespace {

// GLFW reports errors through a callback; the last one explains a failed init or window.
std::string lastGlfwError;

Window& owner(GLFWwindow* window) {
  return *static_cast<Window*>(glfwGetWindowUserPointer(window));
}

}  // namespace

Window::Window(int width, int height, const std::string& title, bool compute, Input input)
    : input_(std::move(input)) {
  glfwSetErrorCallback([](int, const char* description) { lastGlfwError = description; });
  if (!glfwInit()) throw NoDisplay("cannot open a window (" + lastGlfwError + ")");
  // 3.3 core shows the frame; the GPU caster's compute shaders need 4.5.
  glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, compute ? 4 : 3);
  glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, compute ? 5 : 3);
  glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
  glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
  window_ = glfwCreateWindow(width, height, title.c_str(), nullptr, nullptr);
  if (!window_) {
    glfwTerminate();
    throw NoDisplay(std::string("cannot open an OpenGL ") + (compute ? "4.5" : "3.3") + " window (" +
                    lastGlfwError + ")");
  }
  glfwMakeContextCurrent(window_);
  glfwSwapInterval(0);  // the viewer paces itself; frame times are the renderer's, not the display's
  glfwSetWindowUserPointer(window_, this);
  // Installed before ImGui's, which chain to them.
  glfwSetKeyCallback(window_, [](GLFWwindow* w, int key, int, int action, int) {
    if (action != GLFW_PRESS || ImGui::GetIO().WantCaptureKeyboard) return;
    if (const std::optional<Action> a = actionOfGlfwKey(key); a && !isHeld(*a)) owner(w).input_.pressed(*a);
  });
  glfwSetCursorPosCallback(window_, [](GLFWwindow* w, double x, double y) {
    Window& self = owner(w);
    const bool down = glfwGetMouseButton(w, GLFW_MOUSE_BUTTON_LEFT) == GLFW_PRESS;
    if (down && self.dragging_) self.input_.dragged(x - self.lastX_, y - self.lastY_);
    self.dragging_ = down && (self.dragging_ || !ImGui::GetIO().WantCaptureMouse);
    self.lastX_ = x, self.lastY_ = y;
  });
  glfwSetScrollCallback(window_, [](GLFWwindow* w, double, double dy) {
    if (!ImGui::GetIO().WantCaptureMouse) owner(w).input_.scrolled(dy);
  });
  IMGUI_CHECKVERSION();
  ImGui::CreateContext();
  ImGui::GetIO().IniFilename = nullptr;  // no imgui.ini left in the working folder
  ImGui::StyleColorsDark();
  ImGui_ImplGlfw_InitForOpenGL(window_, true);
  ImGui_ImplOpenGL3_Init("#version 330 core");
  glGenTextures(1, &texture_);
  glGenFramebuffers(1, &readFramebuffer_);
}

Window::~Window() {
  glDeleteFramebuffers(1, &readFramebuffer_);
  glDeleteTextures(1, &texture_);
  ImGui_ImplOpenGL3_Shutdown();
  ImGui_ImplGlfw_Shutdown();
  ImGui::DestroyContext();
  glfwDestroyWindow(window_);
  glfwTerminate();
}

bool Window::closing() const {
  return glfwWindowShouldClose(window_) != 0;
}

void Window::close() {
  glfwSetWindowShouldClose(window_, GLFW_TRUE);
}

void Window::handleEvents(double seconds) {
  if (seconds > 0.0) {
    glfwWaitEventsTimeout(seconds);
  } else {
    glfwPollEvents();
  }
}

MoveKeys Window::heldKeys() const {
  MoveKeys keys;
  if (ImGui::GetIO().WantCaptureKeyboard) return keys;
  const auto down = [&](int key) { return glfwGetKey(window_, key) == GLFW_PRESS; };
  keys.forward = down(GLFW_KEY_W), keys.back = down(GLFW_KEY_S);
  keys.left = down(GLFW_KEY_A), keys.right = down(GLFW_KEY_D);
  keys.down = down(GLFW_KEY_Q), keys.up = down(GLFW_KEY_E);
  return keys;
}

glm::ivec2 Window::framebufferSize() const {
  glm::ivec2 size;
  glfwGetFramebufferSize(window_, &size.x, &size.y);
  return size;
}

std::string Window::renderer() const {
  const auto* name = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
  return name ? name : "an unnamed OpenGL device";
}

void Window::upload(const std::vector<std::uint8_t>& rgba, int width, int height) {
  glBindTexture(GL_TEXTURE_2D, texture_);
  glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
  if (width != textureWidth_ || height != textureHeight_) {
    glTexImage2D(GL_TEXTURE_2D, 0, GL_RGBA8, width, height, 0, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
    textureWidth_ = width, textureHeight_ = height;
    glBindFramebuffer(GL_READ_FRAMEBUFFER, readFramebuffer_);
    glFramebufferTexture2D(GL_READ_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_TEXTURE_2D, texture_, 0);
  } else {
    glTexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, width, height, GL_RGBA, GL_UNSIGNED_BYTE, rgba.data());
  }
}

void Window::draw() {
  const int width = textureWidth_, height = textureHeight_;
  const glm::ivec2 size = framebufferSize();
  glBindFramebuffer(GL_READ_FRAMEBUFFER, readFramebuffer_);
  glBindFramebuffer(GL_DRAW_FRAMEBUFFER, 0);
  glClearColor(0.0f, 0.0f, 0.0f, 1.0f);
  glClear(GL_COLOR_BUFFER_BIT);
  if (width == 0) return;
  // Image rows run from the top, GL's from the bottom: the blit flips them.
  const bool exact = width == size.x && height == size.y;
  glBlitFramebuffer(0, 0, width, height, 0, size.y, size.x, 0, GL_COLOR_BUFFER_BIT,
                    exact ? GL_NEAREST : GL_LINEAR);
  glBindFramebuffer(GL_FRAMEBUFFER, 0);
}

void Window::beginOverlay() {
  ImGui_ImplOpenGL3_NewFrame();
  ImGui_ImplGlfw_NewFrame();
  ImGui::NewFrame();
}

void Window::endOverlay() {
  ImGui::Render();
  const glm::ivec2 size = framebufferSize();
  glViewport(0, 0, size.x, size.y);
  ImGui_ImplOpenGL3_RenderDrawData(ImGui::GetDrawData());
}

void Window::present() {
  glfwSwapBuffers(window_);
}

}  // namespace svo::viewer
