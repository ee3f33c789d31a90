// A store's header and directory, parsed and checked once from their bytes, with the lookups readers derive
// from them. Every reader holds one: StoreReader over a local file or memory, a server over the file it
// serves, a remote client over the bytes it fetched with two range requests (the header at offset 0, then
// the directory where the header says).
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "svo/store/byte_source.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

// The fixed header at offset 0.
inline constexpr std::size_t kStoreHeaderBytes = 256;

// Checks a store's header: `bytes` are the first min(kStoreHeaderBytes, fileBytes) bytes of a store of
// `fileBytes` bytes named `name`. Checks magic, version, checksum, the scene's parameters, and that the
// directory ends the file. Throws std::runtime_error "NAME: what is wrong".
StoreHeader parseStoreHeader(const std::string& name, std::span<const std::byte> bytes,
                             std::uint64_t fileBytes);

class StoreIndex {
 public:
  // Checks the directory's bytes (header.directoryBytes, from header.directoryOffset) against the header:
  // checksum, every entry's fields, parent slices before their children, the slices tiling the bytes
  // between header and directory. Throws std::runtime_error "NAME: what is wrong".
  StoreIndex(std::string name, const StoreHeader& header, std::span<const std::byte> directory);

  const std::string& name() const { return name_; }
  const StoreHeader& header() const { return header_; }
  const std::vector<SliceInfo>& slices() const { return slices_; }
  // Slices without a parent slice (a sound store has one: the root cube's first level).
  std::span<const std::uint32_t> rootSlices() const { return children_.group(slices_.size()); }
  // The slices whose parent slice is `slice`, in directory order.
  std::span<const std::uint32_t> childSlices(std::uint32_t slice) const { return children_.group(slice); }
  // The slices adding voxels of `voxelLevel` (1 to the header's levels), in directory order.
  std::span<const std::uint32_t> slicesOfLevel(int voxelLevel) const {
    return ofLevel_.group(std::size_t(voxelLevel));
  }

  // The levels the trunk holds (the slices of the whole root cube, which a pager loads at open): 1 to this
  // level.
  int trunkLevels() const;

  // An error about slice `slice`, naming the store, the slice, its level and cube.
  SliceError sliceError(std::uint32_t slice, const std::string& what) const;
  // Throws std::runtime_error "NAME: what".
  [[noreturn]] void fail(const std::string& what) const;

 private:
  // Slice ids grouped by a key, each group in directory order.
  struct Groups {
    std::vector<std::uint32_t> start, ids;  // group k: ids[start[k], start[k + 1])
    std::span<const std::uint32_t> group(std::size_t k) const {
      return std::span(ids).subspan(start[k], start[k + 1] - start[k]);
    }
  };
  template <class Key>
  static Groups groupBy(std::size_t keys, std::size_t count, Key key);

  std::string name_;
  StoreHeader header_;
  std::vector<SliceInfo> slices_;
  Groups children_;  // by parent slice; the roots last
  Groups ofLevel_;   // by voxel level
};

// Reads and checks a store's header and directory from `source`: two reads.
StoreIndex readStoreIndex(const ByteSource& source);

}  // namespace svo
