// libFuzzer target over the store reader. Any bytes given as a store must end in a clean exception or a
// valid octree: never a crash, a hang or a sanitizer report. The input is read from memory (MemorySource),
// then loaded whole, on its own walked by verify, and on its own decoded into level arrays. Built with
// FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION, which turns the checksum comparisons off so that mutated inputs
// reach the directory and slice decoders instead of stopping at the first checksum.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <memory>
#include <optional>
#include <vector>

#include "svo/store/byte_source.hpp"
#include "svo/store/level_arrays.hpp"
#include "svo/store/store_reader.hpp"

namespace {
// Runs `read`; an exception is a clean rejection, what the reader must do with bad input.
template <class Read>
void tolerateRejection(Read read) {
  try {
    read();
  } catch (const std::exception&) {
  }
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const auto* bytes = reinterpret_cast<const std::byte*>(data);
  std::optional<svo::StoreReader> reader;
  tolerateRejection([&] {
    reader.emplace(
        std::make_shared<const svo::MemorySource>("fuzz input", std::vector<std::byte>(bytes, bytes + size)));
  });
  if (!reader) return 0;
  // Both whole-store walks, each on its own: one may reject what the other has not reached yet.
  tolerateRejection([&] { (void)svo::layoutBlock(reader->loadTree()); });
  tolerateRejection([&] { (void)reader->verify(); });
  // The level-array decoder on every slice, each level's slices taking their parents in the directory's
  // order (where that is not the octree's, the decoder's checks reject it or the values are wrong, never
  // out of bounds).
  tolerateRejection([&] {
    const svo::StoreHeader& header = reader->header();
    std::vector<svo::OctreeLevel> levels{svo::rootLevel(header)};
    for (int level = 1; level <= header.parameters.levels && !reader->index().slicesOfLevel(level).empty();
         ++level) {
      levels.emplace_back();
      std::size_t firstParent = 0;
      for (const std::uint32_t id : reader->index().slicesOfLevel(level)) {
        const svo::SliceInfo& slice = reader->index().slices()[id];
        svo::decodeSliceLevel(reader->readSlice(id), slice, header, levels[levels.size() - 2], firstParent,
                              levels.back());
        firstParent += slice.parentCount;
      }
    }
  });
  return 0;
}
