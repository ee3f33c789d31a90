#include "svo/client/slice_source.hpp"

#include "svo/store/store_reader.hpp"

namespace svo {

StoreSliceSource::StoreSliceSource(std::shared_ptr<const ByteSource> bytes)
    : bytes_(std::move(bytes)), index_(readStoreIndex(*bytes_)) {}

void SliceSource::fetchAll(std::span<const std::uint32_t> slices, std::vector<SliceBytes>& compressed) const {
  for (const std::uint32_t slice : slices) {
    SliceBytes bytes;
    fetch(slice, bytes);
    compressed.push_back(std::move(bytes));
  }
}

void StoreSliceSource::fetch(std::uint32_t slice, SliceBytes& compressed) const {
  fetchSlice(*bytes_, index_, slice, compressed);
}

void StoreSliceSource::fetchAll(std::span<const std::uint32_t> slices,
                                std::vector<SliceBytes>& compressed) const {
  fetchSlices(*bytes_, index_, slices, compressed);
}

std::shared_ptr<SliceSource> openLocalStore(const std::filesystem::path& path) {
  return std::make_shared<StoreSliceSource>(std::make_shared<LocalFileSource>(path));
}

}  // namespace svo
