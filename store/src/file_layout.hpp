// The `.svo` file's own records, shared by the writer (store_writer.cpp) and the index that reads them back
// (store_index.cpp): the fixed header at offset 0 and the directory entries. Little-endian, as x86-64 and
// the GPU both are. Not part of the store's interface: readers get StoreHeader and SliceInfo.
#pragma once

#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <string>

#include <xxhash.h>

#include "svo/store/store_types.hpp"

namespace svo::file {

// Smallest slice size accepted: below this the per-slice header and directory entry dominate.
inline constexpr std::uint32_t kMinSliceBytes = 256;
// Fuzz builds skip the checksum comparisons so mutated inputs reach the decoders (tests/fuzz).
#ifdef FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION
inline constexpr bool kCheckChecksums = false;
#else
inline constexpr bool kCheckChecksums = true;
#endif

struct Header {
  char magic[8];
  std::uint32_t version;
  std::uint32_t headerBytes;
  double origin[3];
  double size;
  std::int32_t levels;
  float geometryError, colorError, normalError;
  std::uint32_t contours;
  std::uint32_t attachmentTypes;  // bit (type - 1) set for each attachment present
  std::uint32_t rootColor, rootNormal;
  std::uint32_t sliceBytes;
  std::uint32_t sliceCount;
  std::uint64_t directoryOffset;
  std::uint64_t directoryBytes;
  std::uint64_t directoryChecksum;  // XXH3-64 of the directory
  std::uint8_t reserved[136];       // room for later fields; zero
  std::uint64_t headerChecksum;     // XXH3-64 of every byte above
};
static_assert(sizeof(Header) == 256);

inline std::uint64_t headerChecksum(const Header& h) {
  return XXH3_64bits(&h, offsetof(Header, headerChecksum));
}

// One directory record.
struct DirectoryEntry {
  std::uint64_t offset;
  std::uint64_t checksum;
  std::uint32_t compressedBytes, rawBytes;
  std::int32_t cubeCoord[3];
  std::uint8_t cubeLevel, voxelLevel;
  std::uint8_t firstSlot, lastSlot;
  std::uint32_t parentCount, voxelCount, contourCount, colorCount, normalCount;
  std::uint32_t parentSlice;
};
static_assert(sizeof(DirectoryEntry) == 64);

// The directory record of a slice and back: the one place that maps SliceInfo to its on-disk form.
inline DirectoryEntry entryOf(const SliceInfo& s) {
  return {s.offset,
          s.checksum,
          s.compressedBytes,
          s.rawBytes,
          {s.cubeCoord.x, s.cubeCoord.y, s.cubeCoord.z},
          std::uint8_t(s.cubeLevel),
          std::uint8_t(s.voxelLevel),
          s.firstSlot,
          s.lastSlot,
          s.parentCount,
          s.voxelCount,
          s.contourCount,
          s.colorCount,
          s.normalCount,
          s.parentSlice};
}
inline SliceInfo sliceOf(const DirectoryEntry& e) {
  SliceInfo s;
  s.offset = e.offset;
  s.compressedBytes = e.compressedBytes;
  s.rawBytes = e.rawBytes;
  s.checksum = e.checksum;
  s.cubeCoord = {e.cubeCoord[0], e.cubeCoord[1], e.cubeCoord[2]};
  s.cubeLevel = e.cubeLevel;
  s.voxelLevel = e.voxelLevel;
  s.firstSlot = e.firstSlot;
  s.lastSlot = e.lastSlot;
  s.parentCount = e.parentCount;
  s.voxelCount = e.voxelCount;
  s.contourCount = e.contourCount;
  s.colorCount = e.colorCount;
  s.normalCount = e.normalCount;
  s.parentSlice = e.parentSlice;
  return s;
}

// Bad input or a failed write: the message names the store first.
[[noreturn]] inline void fail(const std::string& name, const std::string& what) {
  throw std::runtime_error(name + ": " + what);
}

}  // namespace svo::file
