// The `.svo` store (paper sec. 7, docs/format.md): one file holding
//   a 256-byte header at offset 0 (magic, version, scene transform, levels, build parameters, attachment
//   types, the root voxel's attributes, slice size, directory location, checksum), slices, each one
//   resolution level of one cube of the octree, zstd-compressed and XXH3-checksummed, the slice directory at
//   the end (its location and checksum in the header).
// A slice stores no positions or pointers: the levels above it say which voxels it holds (codec.hpp). When a
// cube's next level would exceed the slice size, the slice splits spatially (sec. 7: "split spatially so that
// it has several child slices"): the cube's 8 sub-cubes are packed, in Morton order, into runs that each fit
// the slice size, and a run of one sub-cube becomes that sub-cube's own slice (slice_plan.hpp). Header and
// directory sit at known offsets, so the file can be read with range requests from a static server
// (byte_source.hpp, store_index.hpp). Written to a temporary name and renamed only when complete
// (store_writer.hpp).
//
// This header holds the vocabulary every part of the store shares: the scene, the directory entry, the
// voxels slices decode to, the header's contents and the slice error.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/store/block.hpp"

namespace svo {

inline constexpr char kFileMagic[8] = {'S', 'V', 'O', 'S', 'T', 'R', 'M', '\0'};
// 3: slices cover a run of their cube's sub-cubes (firstSlot, lastSlot).
// 4: contours coded against their voxel's normal and parent's contour, normals as octahedral codes against
// their parent's.
// Any change to the bytes a writer makes bumps this and adds fixtures of the new version
// (tests/data/fixtures/README.md): the fixtures pin every version's bytes.
inline constexpr std::uint32_t kFileVersion = 5;
// The oldest version readers decode: 4 differs from 5 only in what predicts a contour's normal (codec.hpp).
inline constexpr std::uint32_t kOldestReadVersion = 4;
// Default slice size: "about 1 MB at most" (sec. 7); a cube whose next level would exceed it splits.
inline constexpr std::uint32_t kDefaultSliceBytes = 1u << 20;

// Maps world space to the octree's [1, 2]^3: world = origin + (p - 1) * size.
struct SceneTransform {
  glm::dvec3 origin{0.0};
  double size = 1.0;
  glm::dvec3 toOctree(glm::dvec3 world) const { return (world - origin) / size + 1.0; }
  glm::dvec3 toWorld(glm::dvec3 p) const { return origin + (p - 1.0) * size; }
};

struct BuildParameters {
  std::int32_t levels = 0;
  float geometryError = 0.0f;  // finest-voxel units; 0 = refine everywhere
  float colorError = 0.0f;     // 8-bit steps
  float normalError = 0.0f;    // degrees
  std::uint32_t contours = 1;  // 0 when built without contours
};

struct Octree {
  SceneTransform transform;
  BuildParameters parameters;
  Block block;
};

// Whether the run of sub-cubes [firstSlot, lastSlot] is the whole cube.
constexpr bool isWholeCube(int firstSlot, int lastSlot) {
  return firstSlot == 0 && lastSlot == 7;
}

// One entry of the slice directory.
struct SliceInfo {
  std::uint64_t offset = 0;           // file offset of the compressed bytes
  std::uint32_t compressedBytes = 0;  // as stored
  std::uint32_t rawBytes = 0;         // decoded
  std::uint64_t checksum = 0;         // XXH3-64 of the compressed bytes
  glm::ivec3 cubeCoord{0};            // the cube, at cubeLevel
  std::int32_t cubeLevel = 0;
  // The run of the cube's sub-cubes (child slots, Morton order) the slice covers: 0-7 is the whole cube; a
  // shorter run is a packed group of sub-cubes, and needs cubeLevel + 1 < voxelLevel.
  std::uint8_t firstSlot = 0, lastSlot = 7;
  bool wholeCube() const { return isWholeCube(firstSlot, lastSlot); }
  // Whether it could split further: a run, or a cube holding more than one voxel of the level above.
  bool canSplit() const { return !wholeCube() || cubeLevel < voxelLevel - 1; }
  std::int32_t voxelLevel = 0;    // the level of the voxels the slice adds (their parents are one above)
  std::uint32_t parentCount = 0;  // voxels of level voxelLevel - 1 in the cube's run
  std::uint32_t voxelCount = 0;   // voxels the slice adds
  std::uint32_t contourCount = 0;
  std::uint32_t colorCount = 0, normalCount = 0;  // attribute values stored (the rest inherit)
  std::uint32_t parentSlice = kNoSlice;           // the slice that added this cube's parents' level
  static constexpr std::uint32_t kNoSlice = 0xFFFFFFFFu;
};

// The octree-space box ([1, 2]^3 is the scene) of the sub-cubes a slice covers.
struct SliceBox {
  glm::dvec3 lower{1.0}, upper{2.0};
};
SliceBox sliceBox(const SliceInfo& slice);
// Whether every voxel slice `inner` covers lies in what `outer` covers (cube and run of sub-cubes).
bool sliceWithin(const SliceInfo& inner, const SliceInfo& outer);

// Morton order of cube coordinates at one level (slot bits: x = bit 0, y = 1, z = 2): depth-first order of
// the octree, in which a cube's voxels at any finer level form one contiguous run.
bool mortonLess(const glm::ivec3& a, const glm::ivec3& b);
// Coordinate of child `slot` of the cube at `parent`, one level finer.
constexpr glm::ivec3 childCoord(const glm::ivec3& parent, int slot) {
  return parent * 2 + glm::ivec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1);
}
// The slot of the cube at `coord` in its parent (childCoord's inverse).
constexpr int childSlot(const glm::ivec3& coord) {
  return (coord.x & 1) | (coord.y & 1) << 1 | (coord.z & 1) << 2;
}

// A voxel as the slices describe it: where it is, which children it has, its contour and its effective
// (inherited or stored) attributes.
struct SliceVoxel {
  glm::ivec3 coord{0};  // cube coordinate at its level
  std::uint8_t childMask = 0;
  bool hasContour = false;
  // A hint decodeSlice leaves: a lattice code whose normal is `normal` (format.hpp), so that the next level's
  // decoding need not find the code again. Trusted only where latticeNormalBits(normalCode) == normal.
  std::uint16_t normalCode = 0;
  std::uint32_t contour = 0, color = 0, normal = 0;
};
// Voxels level by level from one cube's voxel down, each level in Morton order (so a voxel's children are
// contiguous and follow their parents' order).
using VoxelLevels = std::vector<std::vector<SliceVoxel>>;
// The voxel tree of `levels` (levels[0] holds the root alone); record indices run level by level.
VoxelTree treeOfLevels(const VoxelLevels& levels, bool hasColors, bool hasNormals);

// A voxel tree as decoded slices give it, laid out without copying it into records: its voxels level by
// level in one array from the root (alone on its level) down, each level in Morton order, so that every
// voxel's children are contiguous and follow their parents' order, and a voxel's first child is found by
// counting the children of the voxels before it.
struct LevelOrderTree : TreeAttachments {
  std::vector<SliceVoxel> voxels;  // their child masks count them: one voxel more than children
  // The voxels laid out as stub descriptors (VoxelRecord::stub), ascending; each without children.
  std::vector<std::uint32_t> stubs;

  // Room for `count` more voxels, so that appending them moves none of those there (a level is appended
  // while the one above it is read). Geometric: a tree grown a level at a time is copied a few times at most.
  void reserveMore(std::size_t count) {
    if (voxels.size() + count > voxels.capacity())
      voxels.reserve(std::max(voxels.size() + count, 2 * voxels.capacity()));
  }
};
// layoutBlock of the tree that treeOfLevels would give, with the same block and descriptor slots.
Block layoutBlock(const LevelOrderTree& tree, const LayoutOptions& options = {}, LayoutStats* stats = nullptr,
                  std::vector<std::uint32_t>* descriptorSlot = nullptr);

// A vector whose growth leaves its elements default-initialized (bytes: uninitialized) rather than zeroed.
template <class T>
struct UninitializedAllocator : std::allocator<T> {
  template <class U>
  struct rebind {
    using other = UninitializedAllocator<U>;
  };
  UninitializedAllocator() = default;
  template <class U>
  UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
  template <class U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;
  }
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
// A slice's bytes, compressed or decoded. Reads and zstd write every byte, so zeroing them first would only
// cost time: about a tenth of the decode of a 1 MiB slice.
using SliceBytes = std::vector<std::byte, UninitializedAllocator<std::byte>>;

// What a store's header says.
struct StoreHeader {
  std::uint32_t version = kFileVersion;  // the file's format version
  SceneTransform transform;
  BuildParameters parameters;
  bool hasColors = false, hasNormals = false;
  std::uint32_t rootColor = 0, rootNormal = 0;  // the root voxel's own attribute values
  std::uint32_t sliceBytes = kDefaultSliceBytes;
  std::uint64_t directoryOffset = 0, directoryBytes = 0, fileBytes = 0;
  std::uint64_t directoryChecksum = 0;  // XXH3-64 of the directory's bytes
};

// A slice that failed its checksum, does not decompress or does not decode, or whose bytes could not be
// fetched. `slice` is its directory index; the message names the store, the slice, its level and cube.
struct SliceError : std::runtime_error {
  SliceError(std::uint32_t slice, const std::string& message, bool transient = false);
  std::uint32_t slice;
  // The source failed for a reason that may pass (TransientSourceError): asking again later may succeed.
  bool transient;
};

}  // namespace svo
