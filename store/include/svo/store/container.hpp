// The `.svo` store (paper sec. 7, DESIGN.md): one file holding
//   a 256-byte header at offset 0 (magic, version, scene transform, levels, build parameters, attachment
//   types, the root voxel's attributes, slice size, directory location, checksum), slices, each one
//   resolution level of one cube of the octree, zstd-compressed and XXH3-checksummed, the slice directory at
//   the end (its location and checksum in the header).
// A slice stores no positions or pointers: the levels above it say which voxels it holds (released code: a
// split bit per node of the level above in its cube, a valid mask per split node, then contours and the
// attribute values that differ from the parent's for the new voxels; since version 4 contours and normals
// are byte planes of what is left after predicting them, and normals are 16-bit lattice codes, format.hpp:
// 5.13 -> 2.60 B per leaf voxel on disk, 2M-triangle terrain at 13 levels). When a cube's next level would
// exceed the slice size, the slice splits spatially (sec. 7: "split spatially so that it has several child
// slices"): the cube's 8 sub-cubes are packed, in Morton order, into runs that each fit the slice size, and
// a run of one sub-cube becomes that sub-cube's own slice. Packing keeps slices near the slice size where
// one slice per sub-cube would leave most of them a fraction of it. Header and directory sit at
// known offsets, so the file can be read with range requests from a static server. Written to a temporary
// name and renamed only when complete.
#pragma once

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
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
inline constexpr std::uint32_t kFileVersion = 4;
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

// A slice's decoded bytes by part: presence bits go with their part; the head, split bits and valid masks
// are hierarchy.
struct SliceParts {
  std::uint64_t hierarchy = 0, contours = 0, colors = 0, normals = 0;
};
SliceParts slicePartsOf(const SliceInfo& slice, bool hasColors, bool hasNormals);

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
  std::uint32_t contour = 0, color = 0, normal = 0;
};
// Voxels level by level from one cube's voxel down, each level in Morton order (so a voxel's children are
// contiguous and follow their parents' order).
using VoxelLevels = std::vector<std::vector<SliceVoxel>>;
// The voxel tree of `levels` (levels[0] holds the root alone); record indices run level by level.
VoxelTree treeOfLevels(const VoxelLevels& levels, bool hasColors, bool hasNormals);

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
// A slice's decoded bytes. zstd writes every byte, so zeroing them first would only cost time: about a
// tenth of the decode of a 1 MiB slice.
using SliceBytes = std::vector<std::byte, UninitializedAllocator<std::byte>>;

// What a store's header says.
struct StoreHeader {
  SceneTransform transform;
  BuildParameters parameters;
  bool hasColors = false, hasNormals = false;
  std::uint32_t rootColor = 0, rootNormal = 0;  // the root voxel's own attribute values
  std::uint32_t sliceBytes = kDefaultSliceBytes;
  std::uint64_t directoryOffset = 0, directoryBytes = 0, fileBytes = 0;
};

// A slice that failed its checksum, does not decompress or does not decode. `slice` is its directory index;
// the message names the file, the slice, its level and cube.
struct SliceError : std::runtime_error {
  SliceError(std::uint32_t slice, const std::string& message);
  std::uint32_t slice;
};

struct StoreWriteOptions {
  std::uint32_t sliceBytes = kDefaultSliceBytes;  // raw bytes a slice may hold before its cube splits
  LayoutOptions inheritance;                      // when a child inherits its parent's attribute (sec. 5.4)
  std::function<void(double)> progress;           // fraction of the voxels written, from the writing thread
};

// Where a subtree's slices go in a store: its root voxel's level and cube coordinate, the effective
// attribute values its children inherit from (the root's own, or what the root itself inherited), and the
// slice holding the root voxel (kNoSlice for the store's root, which the header holds). The subtree's slices
// start with the root's cube at the root's level.
struct SubtreePlacement {
  int rootLevel = 0;
  glm::ivec3 rootCoord{0};
  std::uint32_t rootColor = 0, rootNormal = 0;
  std::uint32_t parentSlice = SliceInfo::kNoSlice;
};

// Per record of a tree: the color and normal a store holds for it, its own or the one it inherits.
struct EffectiveAttributes {
  std::vector<std::uint32_t> color, normal;
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
  // cell in Morton order (`counting` first, then to write). The slices are those writeStore makes of the
  // whole tree; the ones spanning several cells are assembled from each cell's part, so at most one cell is
  // held at a time (plus one slice per level).
  void appendForest(const VoxelTree& top, int cellLevel,
                    const std::function<VoxelTree(glm::ivec3 cell, bool counting)>& loadCell);
  const std::vector<SliceInfo>& slices() const { return slices_; }
  void finish(const StoreContents& contents);

 private:
  void put(const void* data, std::size_t bytes);
  // Compresses and writes one slice; fills the directory entry `reserved` or appends one. Returns its id.
  std::uint32_t writeSlice(const std::vector<std::byte>& raw, SliceInfo info,
                           std::uint32_t reserved = SliceInfo::kNoSlice);
  std::filesystem::path path_, temp_;
  StoreWriteOptions options_;
  std::FILE* file_ = nullptr;
  std::uint64_t offset_ = 0;
  std::vector<SliceInfo> slices_;
  std::vector<char> compressed_;
};

// Writes the voxel tree as a slice store, atomically: `path` either keeps its old content or gets the
// complete new file. Returns the directory written.
std::vector<SliceInfo> writeStore(const std::filesystem::path& path, const VoxelTree& tree,
                                  const SceneTransform& transform, const BuildParameters& parameters,
                                  const StoreWriteOptions& options = {});

// Reads a store: the header and directory on open (checked), slices on demand (checksum verified before a
// byte is decoded). Throws std::runtime_error naming the file and what is wrong; slice problems throw
// SliceError.
class StoreReader {
 public:
  explicit StoreReader(const std::filesystem::path& path);
  const StoreHeader& header() const { return header_; }
  const std::vector<SliceInfo>& slices() const { return slices_; }
  const std::filesystem::path& path() const { return path_; }
  // The slice's decoded bytes, after its checksum and size checks.
  SliceBytes readSlice(std::uint32_t slice) const;
  // Every slice decoded into one voxel tree (attributes resolved), with every structural invariant checked:
  // slices cover disjoint parents, parent counts and masks agree, sizes match.
  VoxelTree loadTree() const;
  // Reads, checks and decodes every slice onto its parents, depth first over the slice hierarchy (one chain
  // of slices in memory at a time, so any size of store): checksums, heads against the directory, sections,
  // each slice's cube within its parent slice's cube one level down, no two slices over one parent voxel,
  // every slice reachable from the root. Throws like loadTree; returns the voxels counted, and the leaf
  // voxels (no children) in `leaves` when given.
  std::uint64_t verify(const std::function<void(double)>& progress = nullptr,
                       std::uint64_t* leaves = nullptr) const;
  // Decodes slice `slice` (its bytes from readSlice) onto its parents: the voxels of the level above in its
  // cube, in Morton order. Sets their child masks and appends the new voxels to `children` in Morton order.
  // Throws SliceError when the bytes disagree with the directory or the parents.
  void decodeSlice(std::uint32_t slice, std::span<const std::byte> raw, std::span<SliceVoxel> parents,
                   std::vector<SliceVoxel>& children) const;

 private:
  // Slice `id`'s parents: the voxels of `level` (Morton order, one level above the slice) inside its run of
  // sub-cubes, each marked in `covered`; one marked before means two slices claim it.
  std::span<SliceVoxel> claimParents(std::uint32_t id, std::vector<SliceVoxel>& level,
                                     std::vector<std::uint8_t>& covered) const;
  SliceError sliceError(std::uint32_t slice, const std::string& what) const;

  struct File {  // the open descriptor, shared by copies of the reader
    int fd = -1;
    ~File();
  };
  std::filesystem::path path_;
  std::shared_ptr<File> file_;
  StoreHeader header_;
  std::vector<SliceInfo> slices_;
};

// The whole store as one in-memory octree (loadTree + layoutBlock): the same block the in-core builder makes.
Octree readOctree(const std::filesystem::path& path);
// Writes the octree's voxels (read back from its block) as a store.
void writeOctree(const std::filesystem::path& path, const Octree& octree,
                 const StoreWriteOptions& options = {});

}  // namespace svo
