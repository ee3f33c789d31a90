#include "svo/gpu/gpu_pool.hpp"

#include <stdexcept>
#include <string>

namespace svo::gpu {

GpuPool::GpuPool(GpuCaster& caster, Pager& pager) : caster_(caster), pager_(pager) {
  const std::size_t budget = pager.budgetBytes();
  if (budget > caster.maxBufferBytes())
    throw std::runtime_error("the GPU holds the block pool in one storage buffer, at most " +
                             std::to_string(caster.maxBufferBytes() >> 20) + " MiB here; the budget is " +
                             std::to_string(budget >> 20) + " MiB (--budget)");
  caster.reserve(budget);
}

std::uint64_t GpuPool::sync() {
  const Pager::PoolChanges changes = pager_.takePoolChanges();
  std::uint64_t bytes = 0;
  for (const BlockPool::PageRun& run : changes.written) {
    const std::size_t offset = std::size_t(run.first) * kPageBytes,
                      size = std::size_t(run.count) * kPageBytes;
    caster_.upload(offset, changes.arena.subspan(offset, size));
    bytes += size;
  }
  rootSlot_ = changes.rootSlot;
  uploaded_ += bytes;
  return bytes;
}

Frame GpuPool::render(const Camera& camera, const RenderOptions& options, GpuHits* hits) {
  sync();
  const BlockView trunk = pager_.trunk();
  return caster_.render(rootSlot_, trunk.hasColors(), trunk.hasNormals(), pager_.transform(), camera, options,
                        hits);
}

}  // namespace svo::gpu
