#include "svo/store/container.hpp"

#include <cstdio>
#include <cstring>
#include <fstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include <unistd.h>
#include <xxhash.h>
#include <zstd.h>

namespace svo {
namespace {

// zstd level for the block: fast to write, decompresses at GB/s (zstd manual: levels 1-3 are the fast range).
constexpr int kZstdLevel = 3;

// Fixed-size header at offset 0; little-endian, as x86-64 and the GPU both are.
struct FileHeader {
  char magic[8];
  std::uint32_t version;
  std::uint32_t headerBytes;
  double origin[3];
  double size;
  std::int32_t levels;
  float geometryError, colorError, normalError;
  std::uint32_t contours;
  std::uint32_t attachmentTypes;  // bit (type - 1) set for each attachment present
  std::uint64_t blockOffset;
  std::uint64_t blockCompressedBytes;
  std::uint64_t blockRawBytes;
  std::uint64_t blockChecksum;   // XXH3-64 of the compressed block
  std::uint8_t reserved[144];    // room for later fields; zero
  std::uint64_t headerChecksum;  // XXH3-64 of every byte above
};
static_assert(sizeof(FileHeader) == 256);

std::uint64_t headerChecksum(const FileHeader& h) {
  return XXH3_64bits(&h, offsetof(FileHeader, headerChecksum));
}

[[noreturn]] void fail(const std::filesystem::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

}  // namespace

void writeOctree(const std::filesystem::path& path, const Octree& octree) {
  const AlignedBytes& raw = octree.block.bytes();
  std::vector<char> compressed(ZSTD_compressBound(raw.size()));
  const std::size_t packed =
      ZSTD_compress(compressed.data(), compressed.size(), raw.data(), raw.size(), kZstdLevel);
  if (ZSTD_isError(packed)) fail(path, std::string("compression failed: ") + ZSTD_getErrorName(packed));

  FileHeader h{};
  std::memcpy(h.magic, kFileMagic, sizeof h.magic);
  h.version = kFileVersion;
  h.headerBytes = sizeof(FileHeader);
  for (int i = 0; i < 3; ++i) h.origin[i] = octree.transform.origin[i];
  h.size = octree.transform.size;
  h.levels = octree.parameters.levels;
  h.geometryError = octree.parameters.geometryError;
  h.colorError = octree.parameters.colorError;
  h.normalError = octree.parameters.normalError;
  h.contours = octree.parameters.contours;
  const BlockView view = octree.block.view();
  for (auto type : {AttachmentType::Color, AttachmentType::Normal})
    if (view.attachment(type)) h.attachmentTypes |= 1u << (std::uint32_t(type) - 1);
  h.blockOffset = sizeof(FileHeader);
  h.blockCompressedBytes = packed;
  h.blockRawBytes = raw.size();
  h.blockChecksum = XXH3_64bits(compressed.data(), packed);
  h.headerChecksum = headerChecksum(h);

  // Temporary name in the same folder, flushed, then renamed: the target is never half-written.
  const std::filesystem::path temp = path.string() + ".tmp." + std::to_string(::getpid());
  {
    std::FILE* f = std::fopen(temp.c_str(), "wb");
    if (!f) fail(path, std::string("cannot write (") + std::strerror(errno) + ")");
    const bool ok = std::fwrite(&h, sizeof h, 1, f) == 1 &&
                    std::fwrite(compressed.data(), 1, packed, f) == packed && std::fflush(f) == 0 &&
                    ::fsync(::fileno(f)) == 0;
    const int err = errno;
    if (std::fclose(f) != 0 || !ok) {
      std::remove(temp.c_str());
      fail(path, std::string("cannot write (") + std::strerror(err) + ")");
    }
  }
  std::error_code ec;
  std::filesystem::rename(temp, path, ec);
  if (ec) {
    std::filesystem::remove(temp);
    fail(path, "cannot rename into place (" + ec.message() + ")");
  }
}

Octree readOctree(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, std::filesystem::exists(path) ? "cannot open" : "no such file");
  FileHeader h{};
  in.read(reinterpret_cast<char*>(&h), sizeof h);
  if (in.gcount() < std::streamsize(sizeof h.magic) || std::memcmp(h.magic, kFileMagic, sizeof h.magic) != 0)
    fail(path, "not an svostream file (bad magic)");
  if (in.gcount() != std::streamsize(sizeof h)) fail(path, "truncated header");
  if (h.version != kFileVersion)
    fail(path, "unsupported file version " + std::to_string(h.version) + " (this build reads " +
                   std::to_string(kFileVersion) + ")");
  if (h.headerBytes != sizeof h || headerChecksum(h) != h.headerChecksum)
    fail(path, "header checksum mismatch");
  if (h.levels < 1 || h.levels > kMaxLevels || !(h.size > 0.0))
    fail(path, "header holds invalid scene parameters");
  // Bound sizes before allocating: the raw block may not exceed what zstd's frame says nor 64 GiB.
  constexpr std::uint64_t kMaxBlockBytes = std::uint64_t(64) << 30;
  if (h.blockRawBytes == 0 || h.blockRawBytes > kMaxBlockBytes || h.blockRawBytes % kPageBytes != 0 ||
      h.blockCompressedBytes == 0 || h.blockCompressedBytes > kMaxBlockBytes)
    fail(path, "header holds invalid block sizes");
  std::vector<char> compressed(h.blockCompressedBytes);
  in.seekg(std::streamoff(h.blockOffset));
  in.read(compressed.data(), std::streamsize(compressed.size()));
  if (std::uint64_t(in.gcount()) != h.blockCompressedBytes)
    fail(path, "truncated: block needs " + std::to_string(h.blockCompressedBytes) + " bytes, file has " +
                   std::to_string(in.gcount()));
  if (XXH3_64bits(compressed.data(), compressed.size()) != h.blockChecksum)
    fail(path, "block checksum mismatch");
  const unsigned long long frameBytes = ZSTD_getFrameContentSize(compressed.data(), compressed.size());
  if (frameBytes != h.blockRawBytes) fail(path, "block size does not match its compressed frame");
  AlignedBytes raw(h.blockRawBytes);
  const std::size_t got = ZSTD_decompress(raw.data(), raw.size(), compressed.data(), compressed.size());
  if (ZSTD_isError(got) || got != h.blockRawBytes) fail(path, "block does not decompress");

  Octree octree;
  octree.transform.origin = {h.origin[0], h.origin[1], h.origin[2]};
  octree.transform.size = h.size;
  octree.parameters = {h.levels, h.geometryError, h.colorError, h.normalError, h.contours};
  try {
    octree.block = Block(std::move(raw));
  } catch (const std::exception& e) {
    fail(path, e.what());
  }
  return octree;
}

}  // namespace svo
