#include "svo/gpu/gl_context.hpp"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#define GL_GLEXT_PROTOTYPES
#include <GL/glcorearb.h>

#include <cstring>
#include <vector>

namespace svo::gpu {

struct HeadlessGlContext::State {
  EGLDisplay display = EGL_NO_DISPLAY;
  EGLContext context = EGL_NO_CONTEXT;
};

namespace {

// An OpenGL 4.5 core context current on `display` without a surface; EGL_NO_CONTEXT when it has none.
EGLContext coreContext(EGLDisplay display) {
  EGLint major = 0, minor = 0;
  if (display == EGL_NO_DISPLAY || !eglInitialize(display, &major, &minor)) return EGL_NO_CONTEXT;
  if (!eglBindAPI(EGL_OPENGL_API)) return EGL_NO_CONTEXT;
  // No window: any configuration with desktop OpenGL (pbuffer is the surface type every headless one has),
  // else none at all where EGL allows it (EGL_KHR_no_config_context).
  const EGLint configAttributes[] = {EGL_SURFACE_TYPE, EGL_PBUFFER_BIT, EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
                                     EGL_NONE};
  EGLConfig config = EGL_NO_CONFIG_KHR;
  EGLint configs = 0;
  if (!eglChooseConfig(display, configAttributes, &config, 1, &configs) || configs == 0) {
    const char* extensions = eglQueryString(display, EGL_EXTENSIONS);
    if (!extensions || !std::strstr(extensions, "EGL_KHR_no_config_context")) return EGL_NO_CONTEXT;
    config = EGL_NO_CONFIG_KHR;
  }
  const EGLint contextAttributes[] = {EGL_CONTEXT_MAJOR_VERSION,
                                      4,
                                      EGL_CONTEXT_MINOR_VERSION,
                                      5,
                                      EGL_CONTEXT_OPENGL_PROFILE_MASK,
                                      EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                      EGL_NONE};
  const EGLContext context = eglCreateContext(display, config, EGL_NO_CONTEXT, contextAttributes);
  if (context == EGL_NO_CONTEXT) return EGL_NO_CONTEXT;
  if (!eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, context)) {
    eglDestroyContext(display, context);
    return EGL_NO_CONTEXT;
  }
  return context;
}

}  // namespace

HeadlessGlContext::HeadlessGlContext() : state_(std::make_unique<State>()) {
  // Mesa's surfaceless platform first (llvmpipe or a GPU's Mesa driver, no X needed), then the default
  // display (a vendor driver's).
  std::vector<EGLDisplay> candidates;
  if (const auto platformDisplay =
          reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(eglGetProcAddress("eglGetPlatformDisplayEXT")))
    candidates.push_back(platformDisplay(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr));
  candidates.push_back(eglGetDisplay(EGL_DEFAULT_DISPLAY));
  for (const EGLDisplay display : candidates) {
    const EGLContext context = coreContext(display);
    if (context != EGL_NO_CONTEXT) {
      state_->display = display, state_->context = context;
      return;
    }
    if (display != EGL_NO_DISPLAY) eglTerminate(display);
  }
  throw GpuUnavailable("no EGL display gives an OpenGL 4.5 core context without a window");
}

HeadlessGlContext::~HeadlessGlContext() {
  if (state_->context != EGL_NO_CONTEXT) {
    eglMakeCurrent(state_->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(state_->display, state_->context);
  }
  if (state_->display != EGL_NO_DISPLAY) eglTerminate(state_->display);
}

std::string HeadlessGlContext::renderer() const {
  const auto text = [](GLenum name) {
    const auto* s = reinterpret_cast<const char*>(glGetString(name));
    return std::string(s ? s : "?");
  };
  return text(GL_RENDERER) + ", OpenGL " + text(GL_VERSION);
}

}  // namespace svo::gpu
