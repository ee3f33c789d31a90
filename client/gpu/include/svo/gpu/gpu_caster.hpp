// The ESVO ray caster as an OpenGL 4.5 compute shader (src/shaders/raycast.comp: the CPU caster and the
// renderer's shading, line for line) over one shader storage buffer holding a block, or a block pool's arena
// mirrored page by page. Runs in whatever context is current: a HeadlessGlContext, or the viewer's window.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "svo/client/render.hpp"
#include "svo/gpu/gl_context.hpp"

namespace svo::gpu {

// Per pixel, what the rays hit on the GPU: the hit voxel as (parent descriptor's slot in the buffer) * 8 +
// child slot (kMissSlot for a miss), and its scale, for comparisons with the CPU caster.
inline constexpr std::uint32_t kMissSlot = 0xffffffffu;
struct GpuHits {
  std::vector<std::uint32_t> voxel;
  std::vector<std::uint8_t> scale;
};

class GpuCaster {
 public:
  // Compiles the shader in the current context. Throws GpuUnavailable without compute shaders.
  GpuCaster();
  ~GpuCaster();
  GpuCaster(const GpuCaster&) = delete;
  GpuCaster& operator=(const GpuCaster&) = delete;

  // The largest buffer this device takes (GL_MAX_SHADER_STORAGE_BLOCK_SIZE; 128 MiB on llvmpipe).
  std::size_t maxBufferBytes() const;
  // Sizes the buffer (its old contents are lost). Throws std::runtime_error above maxBufferBytes.
  void reserve(std::size_t bytes);
  std::size_t capacity() const { return capacity_; }
  // Copies `bytes` to the buffer at `offset` (both multiples of 4).
  void upload(std::size_t offset, std::span<const std::byte> bytes);
  std::uint64_t uploadedBytes() const { return uploadedBytes_; }

  // One frame of the octree whose root descriptor is `rootSlot` (64-bit slots from the buffer's start), as
  // svo::render gives it: color, depth, voxel size in pixels, iterations and LOD stops (`diagnostics`), and
  // the dispatches' GPU time (Frame::deviceSeconds) beside the whole call's.
  // `hasColors` / `hasNormals`: the root block's attachments. With options.beamTile > 0 a first dispatch runs
  // the beam pass for every 8 x 8 tile (the ray pass's work group, whatever beamTile's size).
  Frame render(std::uint32_t rootSlot, bool hasColors, bool hasNormals, const SceneTransform& scene,
               const Camera& camera, const RenderOptions& options, GpuHits* hits = nullptr);

 private:
  unsigned program_ = 0, beamProgram_ = 0, pool_ = 0, pixels_ = 0, params_ = 0, tileStarts_ = 0,
           timers_[2] = {};
  std::size_t capacity_ = 0, pixelBytes_ = 0, tileStartBytes_ = 0;
  std::uint64_t uploadedBytes_ = 0;
};

// One block (a whole octree) in a buffer of its own size: the GPU frame of svo::render(block, ...).
Frame renderBlock(GpuCaster& caster, const BlockView& block, const SceneTransform& scene,
                  const Camera& camera, const RenderOptions& options, GpuHits* hits = nullptr);

}  // namespace svo::gpu
