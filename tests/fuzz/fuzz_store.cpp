// libFuzzer target over the store reader (DESIGN.md: fuzz the parsers). Any bytes given as a .svo file must
// end in a clean exception or a valid octree: never a crash, a hang or a sanitizer report. Built with
// FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION, which turns the checksum comparisons off so that mutated inputs
// reach the directory and slice decoders instead of stopping at the first checksum.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <string>

#include "scratch_file.hpp"
#include "svo/store/store_reader.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const std::filesystem::path path = svofuzz::scratchPath("svo_fuzz_store_", ".svo");
  if (!svofuzz::writeScratch(path, data, size)) return 0;
  try {
    const svo::StoreReader reader(path);
    (void)svo::layoutBlock(reader.loadTree());
  } catch (const std::exception&) {
    // Rejected cleanly: what the reader must do with bad input.
  }
  return 0;
}
