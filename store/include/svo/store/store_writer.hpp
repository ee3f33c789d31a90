// Writing a `.svo` store (store_types.hpp): the slices the planner makes (slice_plan.hpp), each
// zstd-compressed and XXH3-checksummed, then the directory and the header. The file is written under a
// temporary name in the target's folder, flushed and renamed into place only when complete.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <vector>

#include <tbb/task_group.h>
#include <glm/vec3.hpp>

#include "svo/store/block.hpp"
#include "svo/store/slice_plan.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

struct StoreWriteOptions {
  std::uint32_t sliceBytes = kDefaultSliceBytes;  // raw bytes a slice may hold before its cube splits
  LayoutOptions inheritance;                      // when a child inherits its parent's attribute (sec. 5.4)
  std::function<void(double)> progress;           // fraction of the voxels written, from the writing thread
};

// What a store's header records besides its slices.
struct StoreContents {
  SceneTransform transform;
  BuildParameters parameters;
  bool hasColors = false, hasNormals = false;
  std::uint32_t rootColor = 0, rootNormal = 0;
};

// Writes a store subtree by subtree (the out-of-core build appends the trunk, then each cell): slices go to
// a temporary file in the target's folder; finish() adds the directory and header, flushes and renames it
// into place. Destroyed unfinished, it removes the temporary file and the target keeps its old content.
class StoreFileWriter {
 public:
  StoreFileWriter(const std::filesystem::path& path, const StoreWriteOptions& options);
  ~StoreFileWriter();
  StoreFileWriter(const StoreFileWriter&) = delete;
  StoreFileWriter& operator=(const StoreFileWriter&) = delete;
  // Appends the slices of `tree` placed at `at` (its parent slice already written); returns their ids.
  // `effective` receives each record's attribute values as a reader decodes them (inheritance applied).
  std::vector<std::uint32_t> append(const VoxelTree& tree, const SubtreePlacement& at,
                                    EffectiveAttributes* effective = nullptr);
  // The out-of-core build's store, as the first subtree: `top` holds the levels down to `cellLevel`, and each
  // of its voxels of that level is a cell whose subtree (rooted at that voxel) `loadCell` returns, twice per
  // cell (`counting` first, for every cell, then to write). The slices are those writeStore makes of the
  // whole tree, written in Morton order; the ones spanning several cells are assembled from each cell's part.
  // Cells are loaded and planned on TBB's threads, so `loadCell` must be thread-safe, and as many cells as
  // TBB may run threads are held at a time (plus one slice per level).
  void appendForest(const VoxelTree& top, int cellLevel,
                    const std::function<VoxelTree(glm::ivec3 cell, bool counting)>& loadCell);
  const std::vector<SliceInfo>& slices() const { return slices_; }
  void finish(const StoreContents& contents);

 private:
  struct PendingSlice {
    std::uint32_t id;
    std::vector<std::byte> raw;
    std::vector<char> compressed;
  };
  void put(const void* data, std::size_t bytes);
  // Queues one slice for compression and writing; fills the directory entry `reserved` or appends one.
  // Returns its id. A full queue is compressed in parallel in the background while the next one fills,
  // then written in the order its slices came.
  std::uint32_t writeSlice(const std::vector<std::byte>& raw, SliceInfo info,
                           std::uint32_t reserved = SliceInfo::kNoSlice);
  // Writes the batch being compressed (once it is), then starts compressing the queue.
  void startCompressing();
  // Every queued slice compressed and written, its directory entry complete.
  void flush();
  std::filesystem::path path_, temp_;
  StoreWriteOptions options_;
  std::FILE* file_ = nullptr;
  std::uint64_t offset_ = 0;
  std::vector<SliceInfo> slices_;
  std::vector<PendingSlice> pending_, compressing_;
  std::unique_ptr<tbb::task_group> compression_;  // compresses `compressing_`
};

// Writes the voxel tree as a slice store, atomically: `path` either keeps its old content or gets the
// complete new file. Returns the directory written.
std::vector<SliceInfo> writeStore(const std::filesystem::path& path, const VoxelTree& tree,
                                  const SceneTransform& transform, const BuildParameters& parameters,
                                  const StoreWriteOptions& options = {});

// Writes the octree's voxels (read back from its block) as a store.
void writeOctree(const std::filesystem::path& path, const Octree& octree,
                 const StoreWriteOptions& options = {});

}  // namespace svo
