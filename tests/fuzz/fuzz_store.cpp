// libFuzzer target over the store reader. Any bytes given as a store must end
// in a clean exception or a valid octree: never a crash, a hang or a sanitizer report. The input is read
// from memory (MemorySource), then loaded whole and, on its own, walked by verify. Built with
// FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION, which turns the checksum comparisons off so that mutated inputs
// reach the directory and slice decoders instead of stopping at the first checksum.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <memory>
#include <optional>
#include <vector>

#include "svo/store/byte_source.hpp"
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
  return 0;
}
