// Where the pager's slices come from: a store's index (header and directory) and each slice's compressed
// bytes as stored. The pager checks, decompresses and decodes them itself, so checksums hold end to end
// whatever carried the bytes: a local file, memory, an HTTP server answering range requests.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <span>
#include <vector>

#include "svo/store/byte_source.hpp"
#include "svo/store/schedule.hpp"
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
  // The compressed bytes of `slices` (a region's chain), appended to `compressed` in order; a source may
  // fetch neighbours together. Stops at the first that fails and throws its SliceError; `compressed` then
  // holds the ones before it. By default one fetch() each.
  virtual void fetchAll(std::span<const std::uint32_t> slices, std::vector<SliceBytes>& compressed) const;
  // The view the pager schedules for, with its pool's budget and its next requests, most wanted first, at
  // each update before the requests go out: a source that sends slices ahead of their fetches (the view
  // stream) follows it; the others need not know.
  virtual void follow(const ViewQuery& /*view*/, std::size_t /*budgetBytes*/,
                      std::span<const std::uint32_t> /*first*/ = {}) const {}
};

// The slices of a store read through a byte source; its header and directory are read and checked on
// construction (two reads).
class StoreSliceSource final : public SliceSource {
 public:
  explicit StoreSliceSource(std::shared_ptr<const ByteSource> bytes);
  const StoreIndex& index() const override { return index_; }
  void fetch(std::uint32_t slice, SliceBytes& compressed) const override;
  // Slices that lie back to back in the file come with one read (fetchSlices).
  void fetchAll(std::span<const std::uint32_t> slices, std::vector<SliceBytes>& compressed) const override;

 private:
  std::shared_ptr<const ByteSource> bytes_;
  StoreIndex index_;
};

// A local store file as a slice source.
std::shared_ptr<SliceSource> openLocalStore(const std::filesystem::path& path);

}  // namespace svo
