// The GPU path of the commands and benchmarks (`--device gpu`): a headless OpenGL context with the GPU caster
// in it, rendering whole octrees or a pager's pool mirrored page by page.
#pragma once

#include <memory>
#include <string>

#include "svo/client/streaming.hpp"
#include "svo/gpu/gl_context.hpp"
#include "svo/gpu/gpu_caster.hpp"
#include "svo/gpu/gpu_pool.hpp"

namespace svo::gpu {

class HeadlessGpu {
 public:
  HeadlessGpu() : caster_(std::make_unique<GpuCaster>()) {}  // throws GpuUnavailable
  GpuCaster& caster() { return *caster_; }
  std::string renderer() const { return context_.renderer(); }
  // Frames of `pager`'s pool on the GPU, for streamFrame and convergeView: the pool is mirrored in the
  // caster's buffer (one pager at a time). Throws std::runtime_error when the budget exceeds one buffer.
  PoolRenderer poolRenderer(Pager& pager) {
    auto pool = std::make_shared<GpuPool>(*caster_, pager);
    return [pool](Pager&, const Camera& camera, const RenderOptions& options) {
      return pool->render(camera, options);
    };
  }

 private:
  HeadlessGlContext context_;  // first: the caster's GL objects live in it
  std::unique_ptr<GpuCaster> caster_;
};

}  // namespace svo::gpu
