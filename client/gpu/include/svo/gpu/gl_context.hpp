// An OpenGL 4.5 core context without a window: EGL on the device's display, or Mesa's surfaceless platform
// (llvmpipe on a machine with no GPU and no X), for `svo render --device gpu`, the benchmarks and the tests.
// The viewer makes its window's context current instead.
#pragma once

#include <memory>
#include <stdexcept>
#include <string>

namespace svo::gpu {

// No OpenGL 4.5 with compute shaders here; the message says what was missing.
struct GpuUnavailable : std::runtime_error {
  using std::runtime_error::runtime_error;
};

class HeadlessGlContext {
 public:
  // Creates the context and makes it current on this thread. Throws GpuUnavailable.
  HeadlessGlContext();
  ~HeadlessGlContext();
  HeadlessGlContext(const HeadlessGlContext&) = delete;
  HeadlessGlContext& operator=(const HeadlessGlContext&) = delete;
  // GL_RENDERER and GL_VERSION, for reports.
  std::string renderer() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace svo::gpu
