#include "svo/client/whole_scene.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>

#include "svo/client/streaming.hpp"

namespace svo {
namespace {

// Peak bytes per voxel of reading a store whole as one block (readOctree): the decoded levels, the voxel
// records and the block. Measured with /usr/bin/time on the npm bunny at 10 levels (85 B per voxel,
// 4.3 M voxels) and a 200k-triangle terrain at 11 levels (66 B, 12 M voxels), the process's base included.
constexpr double kWholeLoadBytesPerVoxel = 85.0;
// Pool bytes per decoded slice byte that hold every block of a store: above the pager's 3.0 estimate
// (pager.cpp, kBlockBytesPerRawByte), as the page rounding of small blocks adds to it.
constexpr double kWholePoolBytesPerRawByte = 4.0;
// Besides that: the trunk and the rounding of the last pages.
constexpr std::size_t kWholePoolSlackBytes = std::size_t(64) << 20;
// Seconds loading every slice may take before the scene is refused (a pool that thrashes never converges).
constexpr double kLoadEverythingTimeout = 600.0;

}  // namespace

bool StoreFootprint::mayFitOneBlock() const {
  // Slots before the contours: the contour pointer of the last descriptor spans them and every contour.
  return parentVoxels + std::max(colors, normals) <= kMaxWordPointer &&
         2 * parentVoxels + contours <= kMaxWordPointer;
}

std::uint64_t StoreFootprint::wholeLoadBytes() const {
  return std::uint64_t(kWholeLoadBytesPerVoxel * double(voxels));
}

StoreFootprint footprintOf(const std::vector<SliceInfo>& slices) {
  StoreFootprint f;
  for (const SliceInfo& s : slices) {
    f.voxels += s.voxelCount;
    f.parentVoxels += s.parentCount;
    f.contours += s.contourCount;
    f.colors += s.colorCount;
    f.normals += s.normalCount;
    f.decodedBytes += s.rawBytes;
  }
  return f;
}

std::size_t wholeStoreBudget(const std::vector<SliceInfo>& slices) {
  const double bytes = kWholePoolBytesPerRawByte * double(footprintOf(slices).decodedBytes);
  return std::min(kMaxBudgetBytes, std::size_t(bytes) + kWholePoolSlackBytes);
}

WholeScene::WholeScene(Octree octree) : octree_(std::move(octree)) {}

WholeScene WholeScene::paged(const std::filesystem::path& store, std::size_t poolBytes,
                             AttributeOptions attributes) {
  PagerOptions options;
  options.budgetBytes = poolBytes;
  options.attributes = attributes;
  WholeScene scene;
  scene.pager_ = std::make_unique<Pager>(store, options);
  if (!loadEverything(*scene.pager_, kLoadEverythingTimeout))
    throw std::runtime_error(store.string() + ": its " +
                             std::to_string(scene.pager_->index().slices().size()) +
                             " slices do not all fit a pool of " + std::to_string(poolBytes >> 20) + " MiB");
  return scene;
}

std::size_t WholeScene::bytes() const {
  return octree_ ? octree_->block.bytes().size() : pager_->residentBytes();
}

}  // namespace svo
