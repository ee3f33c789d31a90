#include "svo/store/store_index.hpp"

#include <algorithm>
#include <cstring>
#include <utility>

#include "file_layout.hpp"
#include "svo/store/codec.hpp"

namespace svo {
namespace {

static_assert(sizeof(file::Header) == kStoreHeaderBytes);

// Largest decoded slice a reader accepts: a cube that cannot split further may exceed the slice size, but a
// slice claims at most one level of one cube, and 1 GiB bounds what a corrupt directory can make us allocate.
constexpr std::uint64_t kMaxSliceRawBytes = std::uint64_t(1) << 30;

// The header's fields, checked as far as they can be without the directory.
void checkHeader(const std::string& name, const file::Header& h, std::size_t headerRead,
                 std::uint64_t fileBytes) {
  using file::fail;
  if (headerRead < sizeof h.magic || std::memcmp(h.magic, kFileMagic, sizeof h.magic) != 0)
    fail(name, "not an svostream file (bad magic)");
  if (headerRead < offsetof(file::Header, headerBytes)) fail(name, "truncated header");
  if (h.version < kOldestReadVersion || h.version > kFileVersion)
    fail(name, "unsupported file version " + std::to_string(h.version) + " (this build reads " +
                   std::to_string(kOldestReadVersion) + " to " + std::to_string(kFileVersion) + ")");
  if (headerRead != sizeof h) fail(name, "truncated header");
  if (h.headerBytes != sizeof h || (file::kCheckChecksums && file::headerChecksum(h) != h.headerChecksum))
    fail(name, "header checksum mismatch");
  if (h.levels < 1 || h.levels > kMaxLevels || !(h.size > 0.0) || h.sliceBytes < file::kMinSliceBytes)
    fail(name, "header holds invalid scene parameters");
  if (h.directoryBytes != std::uint64_t(h.sliceCount) * sizeof(file::DirectoryEntry) ||
      h.directoryOffset < sizeof h)
    fail(name, "header holds an invalid directory location");
  if (h.directoryOffset + h.directoryBytes > fileBytes)
    fail(name, "truncated: the directory ends at byte " +
                   std::to_string(h.directoryOffset + h.directoryBytes) + ", the file has " +
                   std::to_string(fileBytes));
  if (h.directoryOffset + h.directoryBytes != fileBytes)
    fail(name, std::to_string(fileBytes - h.directoryOffset - h.directoryBytes) +
                   " unexpected bytes after the directory");
}

// A directory entry's fields against the header; entry `i`'s parent slice must come before it.
void checkEntry(const StoreIndex& index, std::size_t i, const file::DirectoryEntry& e) {
  const StoreHeader& h = index.header();
  const auto bad = [&](const std::string& what) {
    index.fail("directory entry " + std::to_string(i) + ": " + what);
  };
  if (e.offset < kStoreHeaderBytes || e.compressedBytes == 0 ||
      e.offset + e.compressedBytes > h.directoryOffset)
    bad("slice bytes out of place");
  if (e.rawBytes < sizeof(SliceHead) || e.rawBytes > kMaxSliceRawBytes) bad("invalid slice size");
  if (e.voxelLevel < 1 || e.voxelLevel > h.parameters.levels || e.cubeLevel >= e.voxelLevel)
    bad("invalid levels");
  for (const std::int32_t c : e.cubeCoord)
    if (c < 0 || std::int64_t(c) >= (std::int64_t(1) << e.cubeLevel)) bad("cube outside the octree");
  if (e.firstSlot > e.lastSlot || e.lastSlot > 7 ||
      (e.lastSlot - e.firstSlot < 7 && e.cubeLevel + 1 >= e.voxelLevel))
    bad("invalid run of sub-cubes");
  if (e.parentSlice != SliceInfo::kNoSlice && e.parentSlice >= i) bad("parent slice does not come first");
}

}  // namespace

StoreHeader parseStoreHeader(const std::string& name, std::span<const std::byte> bytes,
                             std::uint64_t fileBytes) {
  if (fileBytes == 0) file::fail(name, "empty file (0 bytes), not an svostream file");
  file::Header h{};
  const std::size_t headerRead = std::min(bytes.size(), sizeof h);
  std::memcpy(&h, bytes.data(), headerRead);
  checkHeader(name, h, headerRead, fileBytes);
  StoreHeader header;
  header.version = h.version;
  header.transform.origin = {h.origin[0], h.origin[1], h.origin[2]};
  header.transform.size = h.size;
  header.parameters = {h.levels, h.geometryError, h.colorError, h.normalError, h.contours};
  header.hasColors = h.attachmentTypes >> (std::uint32_t(AttachmentType::Color) - 1) & 1u;
  header.hasNormals = h.attachmentTypes >> (std::uint32_t(AttachmentType::Normal) - 1) & 1u;
  header.rootColor = h.rootColor;
  header.rootNormal = h.rootNormal;
  header.sliceBytes = h.sliceBytes;
  header.directoryOffset = h.directoryOffset;
  header.directoryBytes = h.directoryBytes;
  header.fileBytes = fileBytes;
  header.directoryChecksum = h.directoryChecksum;
  return header;
}

template <class Key>
StoreIndex::Groups StoreIndex::groupBy(std::size_t keys, std::size_t count, Key key) {
  Groups g;
  g.start.assign(keys + 1, 0);
  for (std::size_t i = 0; i < count; ++i) ++g.start[key(i) + 1];
  for (std::size_t k = 0; k < keys; ++k) g.start[k + 1] += g.start[k];
  std::vector<std::uint32_t> next(g.start.begin(), g.start.end() - 1);
  g.ids.resize(count);
  for (std::size_t i = 0; i < count; ++i) g.ids[next[key(i)]++] = std::uint32_t(i);
  return g;
}

StoreIndex::StoreIndex(std::string name, const StoreHeader& header, std::span<const std::byte> directory)
    : name_(std::move(name)), header_(header) {
  if (directory.size() != header.directoryBytes) fail("truncated: cannot read the directory");
  if (file::kCheckChecksums && XXH3_64bits(directory.data(), directory.size()) != header.directoryChecksum)
    fail("directory checksum mismatch");
  const std::size_t count = directory.size() / sizeof(file::DirectoryEntry);
  slices_.reserve(count);
  for (std::size_t i = 0; i < count; ++i) {
    file::DirectoryEntry e;
    std::memcpy(&e, directory.data() + i * sizeof e, sizeof e);
    checkEntry(*this, i, e);
    slices_.push_back(file::sliceOf(e));
  }
  // Slices tile the bytes between the header and the directory (in file order, which is not always the
  // directory's: an out-of-core build writes a slice spanning cells after its last cell), so every byte has
  // a checksum.
  std::vector<std::pair<std::uint64_t, std::uint32_t>> extents;  // (offset, compressed bytes)
  extents.reserve(count);
  for (const SliceInfo& s : slices_) extents.push_back({s.offset, s.compressedBytes});
  std::sort(extents.begin(), extents.end());
  std::uint64_t expectedOffset = kStoreHeaderBytes;
  for (const auto& [offset, bytes] : extents) {
    if (offset != expectedOffset) fail("slice bytes out of place at offset " + std::to_string(offset));
    expectedOffset += bytes;
  }
  if (expectedOffset != header.directoryOffset) fail("the slices do not end where the directory starts");
  children_ = groupBy(count + 1, count, [&](std::size_t i) {
    const std::uint32_t parent = slices_[i].parentSlice;
    return parent == SliceInfo::kNoSlice ? count : std::size_t(parent);
  });
  ofLevel_ = groupBy(std::size_t(header.parameters.levels) + 1, count,
                     [&](std::size_t i) { return std::size_t(slices_[i].voxelLevel); });
}

int StoreIndex::trunkLevels() const {
  int levels = 0;
  for (const SliceInfo& s : slices_)
    if (s.cubeLevel == 0 && s.wholeCube()) levels = std::max(levels, int(s.voxelLevel));
  return levels;
}

SliceError StoreIndex::sliceError(std::uint32_t id, const std::string& what) const {
  std::string name = "slice " + std::to_string(id);
  if (id < slices_.size()) {
    const SliceInfo& s = slices_[id];
    name += " (level " + std::to_string(s.voxelLevel) + ", cube (" + std::to_string(s.cubeCoord.x) + "," +
            std::to_string(s.cubeCoord.y) + "," + std::to_string(s.cubeCoord.z) + ") of level " +
            std::to_string(s.cubeLevel);
    if (!s.wholeCube())
      name += ", sub-cubes " + std::to_string(s.firstSlot) + "-" + std::to_string(s.lastSlot);
    name += ")";
  }
  return SliceError(id, name_ + ": " + name + ": " + what);
}

void StoreIndex::fail(const std::string& what) const {
  file::fail(name_, what);
}

StoreIndex readStoreIndex(const ByteSource& source) {
  const std::uint64_t fileBytes = source.size();
  std::vector<std::byte> header(std::min<std::uint64_t>(fileBytes, kStoreHeaderBytes));
  std::vector<std::byte> directory;
  try {
    header.resize(source.read(0, header));
    const StoreHeader parsed = parseStoreHeader(source.name(), header, fileBytes);
    directory.resize(parsed.directoryBytes);
    directory.resize(source.read(parsed.directoryOffset, directory));
    return StoreIndex(source.name(), parsed, directory);
  } catch (const ByteSourceError& e) {
    file::fail(source.name(), e.what());
  }
}

}  // namespace svo
