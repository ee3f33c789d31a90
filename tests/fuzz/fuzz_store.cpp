// libFuzzer target over the store reader (DESIGN.md: fuzz the parsers). Any bytes given as a .svo file must
// end in a clean exception or a valid octree: never a crash, a hang or a sanitizer report. Built with
// FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION, which turns the checksum comparisons off so that mutated inputs
// reach the directory and slice decoders instead of stopping at the first checksum.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <string>

#include "svo/store/container.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  // The reader takes a path: one scratch file per fuzzing process, in memory where /dev/shm exists.
  static const std::filesystem::path path =
      (std::filesystem::is_directory("/dev/shm") ? std::filesystem::path("/dev/shm")
                                                 : std::filesystem::temp_directory_path()) /
      ("svo_fuzz_store_" + std::to_string(::getpid()) + ".svo");
  if (std::FILE* f = std::fopen(path.c_str(), "wb")) {
    const bool written = size == 0 || std::fwrite(data, 1, size, f) == size;
    std::fclose(f);
    if (!written) return 0;
  } else {
    return 0;
  }
  try {
    const svo::StoreReader reader(path);
    (void)svo::layoutBlock(reader.loadTree());
  } catch (const std::exception&) {
    // Rejected cleanly: what the reader must do with bad input.
  }
  return 0;
}
