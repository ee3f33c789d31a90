// Where the pager's slices come from: a store's index (header and directory) and each slice's compressed
// bytes as stored. The pager checks, decompresses and decodes them itself, so checksums hold end to end
// whatever carried the bytes: a local file, memory, an HTTP server answering range requests.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>

#include "svo/store/byte_source.hpp"
#include "svo/store/store_index.hpp"
#include "svo/store/store_types.hpp"

namespace svo {

class SliceSource {
 public:
  virtual ~SliceSource() = default;
  virtual const StoreIndex& index() const = 0;
  // Slice `slice`'s compressed bytes into `compressed` (resized). Safe to call from several threads at once.
  // Throws SliceError naming the store and the slice.
  virtual void fetch(std::uint32_t slice, SliceBytes& compressed) const = 0;
};

// The slices of a store read through a byte source; its header and directory are read and checked on
// construction (two reads).
class StoreSliceSource final : public SliceSource {
 public:
  explicit StoreSliceSource(std::shared_ptr<const ByteSource> bytes);
  const StoreIndex& index() const override { return index_; }
  void fetch(std::uint32_t slice, SliceBytes& compressed) const override;

 private:
  std::shared_ptr<const ByteSource> bytes_;
  StoreIndex index_;
};

// A local store file as a slice source.
std::shared_ptr<SliceSource> openLocalStore(const std::filesystem::path& path);

}  // namespace svo
