// The block pool mirrored on the GPU: the pager's arena in the GPU caster's buffer, the same size as the
// budget, with only the pages written since the last frame uploaded (blocks loaded or moved, links patched).
// Blocks hold only relative pointers, so the bytes go up unchanged.
#pragma once

#include <cstdint>

#include "svo/client/pager.hpp"
#include "svo/gpu/gpu_caster.hpp"

namespace svo::gpu {

class GpuPool {
 public:
  // Throws std::runtime_error when the pager's budget exceeds what one storage buffer holds here.
  GpuPool(GpuCaster& caster, Pager& pager);

  // Uploads what the pager wrote since the last sync; returns the bytes uploaded.
  std::uint64_t sync();
  // sync, then one frame from the pool (Pager::feedback takes it as a CPU frame).
  Frame render(const Camera& camera, const RenderOptions& options, GpuHits* hits = nullptr);

  std::uint64_t uploadedBytes() const { return uploaded_; }

 private:
  GpuCaster& caster_;
  Pager& pager_;
  std::uint32_t rootSlot_ = 0;
  std::uint64_t uploaded_ = 0;
};

}  // namespace svo::gpu
