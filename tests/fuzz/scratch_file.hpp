// The PLY reader under fuzzing takes a path: each input is written to one scratch file per fuzzing process,
// in memory where /dev/shm exists. (The store reader reads its inputs from memory: fuzz_store.cpp.)
#pragma once

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>

namespace svofuzz {

// Writes the input to `path`; false when it cannot.
inline bool writeScratch(const std::filesystem::path& path, const std::uint8_t* data, std::size_t size) {
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return false;
  const bool written = size == 0 || std::fwrite(data, 1, size, f) == size;
  std::fclose(f);
  return written;
}

// The process's scratch file: `stem` + pid + `extension`.
inline std::filesystem::path scratchPath(const std::string& stem, const std::string& extension) {
  return (std::filesystem::is_directory("/dev/shm") ? std::filesystem::path("/dev/shm")
                                                    : std::filesystem::temp_directory_path()) /
         (stem + std::to_string(::getpid()) + extension);
}

}  // namespace svofuzz
