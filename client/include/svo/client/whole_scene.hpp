// A store's whole octree, ready to ray cast at every depth: one block when it fits one (a block's relative
// pointers reach 2^24 words, sec. 5.1), or else every slice resident in a block pool.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <vector>

#include "svo/client/pager.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

// What loading a store whole takes, from its directory alone.
struct StoreFootprint {
  std::uint64_t voxels = 0;  // every voxel below the root
  std::uint64_t parentVoxels =
      0;  // voxels of the levels above each slice's: at least the voxels with children
  std::uint64_t contours = 0, colors = 0, normals = 0, decodedBytes = 0;
  // Whether the tree may fit one block: its descriptors, contours and attribute values within the 24-bit
  // pointers' reach, counting one descriptor per parent voxel and nothing else. Optimistic, so a store
  // it clears can still throw BlockTooLarge when laid out; one it refuses cannot fit.
  bool mayFitOneBlock() const;
  // Peak memory of reading it whole as one block (readOctree: decoded voxel records, then the block).
  std::uint64_t wholeLoadBytes() const;
};
StoreFootprint footprintOf(const std::vector<SliceInfo>& slices);

// A store's octree at every depth, for commands and benchmarks that compare what every level shows.
class WholeScene {
 public:
  // The octree just laid out, as one block.
  explicit WholeScene(Octree octree);
  // Every slice of the store resident in a pool of `poolBytes` laying attributes out as `attributes` says.
  // Throws std::runtime_error naming the store when they do not all fit.
  static WholeScene paged(const std::filesystem::path& store, std::size_t poolBytes,
                          AttributeOptions attributes = {});

  BlockView root() const { return octree_ ? octree_->block.view() : pager_->trunk(); }
  const SceneTransform& transform() const { return octree_ ? octree_->transform : pager_->transform(); }
  const BuildParameters& parameters() const {
    return octree_ ? octree_->parameters : pager_->index().header().parameters;
  }
  bool isPaged() const { return pager_ != nullptr; }
  Pager* pager() const { return pager_.get(); }  // the pool holding it when paged, else nullptr
  const Octree* octree() const { return octree_ ? &*octree_ : nullptr; }
  // Bytes the octree takes: the one block, or the pool's resident blocks.
  std::size_t bytes() const;

 private:
  WholeScene() = default;

  std::optional<Octree> octree_;
  std::unique_ptr<Pager> pager_;
};

// A pool budget that holds every block of a store: blocks take up to about 3 bytes per decoded slice byte
// (the pager's estimate), and the arena's untouched pages cost nothing.
std::size_t wholeStoreBudget(const std::vector<SliceInfo>& slices);

}  // namespace svo
