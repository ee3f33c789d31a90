// Reading a store's slices, in three steps that can run in different places:
//   fetch   a slice's compressed bytes from a byte source, as stored (a server sends them unchanged);
//   unpack  compressed bytes checked against the directory (checksum, size) and decompressed (a remote
//           client does this with the bytes it fetched by range request);
//   decode  decoded bytes onto their parents (codec.hpp), with the store and slice named in errors.
// Every step throws SliceError naming the store, the slice, its level and cube: a checksum is verified
// before a byte is decompressed, and nothing is decoded unchecked. StoreReader composes the three over one
// source and its index.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "svo/store/byte_source.hpp"
#include "svo/store/store_index.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

// Slice `slice`'s compressed bytes into `compressed` (resized; its capacity is reused).
void fetchSlice(const ByteSource& source, const StoreIndex& index, std::uint32_t slice,
                SliceBytes& compressed);
// The most bytes fetchSlices reads at once: a region's chain of slices, a few MB at the default slice size.
inline constexpr std::uint64_t kMaxSlicesReadBytes = std::uint64_t(16) << 20;
// The compressed bytes of `slices`, appended to `compressed` in order, each run of them that lies back to
// back in the file (a region's chain of slices does) read at once (at most kMaxSlicesReadBytes): one request
// over a network instead of one per slice. Stops at the first read that fails and throws the SliceError of
// the first slice it was for; `compressed` then holds the slices before it.
void fetchSlices(const ByteSource& source, const StoreIndex& index, std::span<const std::uint32_t> slices,
                 std::vector<SliceBytes>& compressed);
// Checks slice `slice`'s compressed bytes against the directory (size, checksum) without decompressing
// them: what a server verifies before it sends stored bytes on, and unpackSlice's first step.
void checkSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> compressed);
// Slice `slice`'s decoded bytes from its compressed bytes, after checkSlice and the frame's size check.
SliceBytes unpackSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> compressed);
// Slice `slice`'s parents among `level`, the voxels of the level above it in Morton order (its cube's, or
// the whole octree's): the contiguous range inside its run of sub-cubes, what decodeSlice decodes onto.
std::span<SliceVoxel> sliceParents(const StoreIndex& index, std::uint32_t slice, std::span<SliceVoxel> level);
// Decodes slice `slice` (its bytes from unpackSlice) onto its parents: the voxels of the level above in its
// cube, in Morton order. Sets their child masks and appends the new voxels to `children` in Morton order.
// `pause` as codec.hpp's decodeSlice calls it.
void decodeSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> raw,
                 std::span<SliceVoxel> parents, std::vector<SliceVoxel>& children,
                 const std::function<void()>& pause = {});
// decodeSlice onto voxels [parentsBegin, parentsEnd) of `tree`, its new voxels appended to the same array: a
// level-order tree grown a slice at a time.
void decodeSlice(const StoreIndex& index, std::uint32_t slice, std::span<const std::byte> raw,
                 LevelOrderTree& tree, std::size_t parentsBegin, std::size_t parentsEnd,
                 const std::function<void()>& pause = {});

// A store read from one source: the header and directory on open (checked), slices on demand. Throws
// std::runtime_error naming the store and what is wrong; slice problems throw SliceError. Copies share the
// source (a local file's descriptor) and the index.
class StoreReader {
 public:
  explicit StoreReader(const std::filesystem::path& path);  // a LocalFileSource
  explicit StoreReader(std::shared_ptr<const ByteSource> source);
  const StoreHeader& header() const { return index_->header(); }
  const std::vector<SliceInfo>& slices() const { return index_->slices(); }
  // The source's name as a path: a local store's file.
  const std::filesystem::path& path() const { return path_; }
  const ByteSource& source() const { return *source_; }
  const StoreIndex& index() const { return *index_; }
  // The slice's decoded bytes (fetchSlice, then unpackSlice). Safe to call from several threads at once.
  SliceBytes readSlice(std::uint32_t slice) const;
  // decodeSlice over this store's index.
  void decodeSlice(std::uint32_t slice, std::span<const std::byte> raw, std::span<SliceVoxel> parents,
                   std::vector<SliceVoxel>& children) const {
    svo::decodeSlice(*index_, slice, raw, parents, children);
  }
  // Every slice decoded into one voxel tree (attributes resolved), with every structural invariant checked:
  // slices cover disjoint parents, parent counts and masks agree, sizes match.
  VoxelTree loadTree() const;
  // Reads, checks and decodes every slice onto its parents, depth first over the slice hierarchy (one chain
  // of slices in memory at a time, so any size of store): checksums, heads against the directory, sections,
  // each slice's cube within its parent slice's cube one level down, no two slices over one parent voxel,
  // every slice reachable from the root. Throws like loadTree. Calls `enter` with each slice's new voxels
  // (Morton order) once decoded, and `leave` with its parents and voxels once every slice below it has been
  // walked (their child masks then set). The first slice's parent is the root voxel.
  using SliceVisit = std::function<void(std::uint32_t slice, std::span<const SliceVoxel> parents,
                                        std::span<const SliceVoxel> voxels)>;
  void walk(const SliceVisit& enter, const SliceVisit& leave) const;
  // walk checking everything: returns the voxels counted, and the leaf voxels (no children) in `leaves`
  // when given.
  std::uint64_t verify(const std::function<void(double)>& progress = nullptr,
                       std::uint64_t* leaves = nullptr) const;

 private:
  std::shared_ptr<const ByteSource> source_;
  std::shared_ptr<const StoreIndex> index_;
  std::filesystem::path path_;
};

// The whole store as one in-memory octree (loadTree + layoutBlock): the same block the in-core builder makes.
Octree readOctree(const std::filesystem::path& path, AttributeOptions attributes = {});
Octree readOctree(const StoreReader& reader, AttributeOptions attributes = {});

}  // namespace svo
