#include "cell_partition.hpp"

#include <cstdio>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>

#include <zstd.h>

namespace svo {
namespace {

// Packed records held in memory before they are written, over all cells: bounds the partition pass's memory.
constexpr std::size_t kBufferedBytes = std::size_t(64) << 20;
// Zstd level of the binned triangles: fast, they are read once.
constexpr int kPartitionZstdLevel = 1;

struct FrameHeader {
  std::uint32_t rawBytes = 0, packedBytes = 0;
};

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};

template <class T>
char* put(char* out, const T& value) {
  std::memcpy(out, &value, sizeof value);
  return out + sizeof value;
}
template <class T>
const char* get(const char* in, T& value) {
  std::memcpy(&value, in, sizeof value);
  return in + sizeof value;
}

}  // namespace

CellPartition::CellPartition(std::filesystem::path folder, bool colors, bool uvs, bool materials, bool orders)
    : CellPartition(std::move(folder), colors, uvs, materials, orders, true) {}

CellPartition CellPartition::attach(std::filesystem::path folder, bool colors, bool uvs, bool materials,
                                    bool orders) {
  return CellPartition(std::move(folder), colors, uvs, materials, orders, false);
}

CellPartition::CellPartition(std::filesystem::path folder, bool colors, bool uvs, bool materials, bool orders,
                             bool owner)
    : folder_(std::move(folder)),
      colors_(colors),
      uvs_(uvs),
      materials_(materials),
      orders_(orders),
      owner_(owner) {
  recordBytes_ = sizeof(SourceTriangle::positions) + sizeof(SourceTriangle::normals) +
                 (colors ? sizeof(SourceTriangle::colors) : 0) + (uvs ? sizeof(SourceTriangle::uvs) : 0) +
                 (materials ? sizeof(SourceTriangle::material) : 0) + (orders ? sizeof(std::uint32_t) : 0);
  if (!owner_) return;
  std::filesystem::remove_all(folder_);
  std::filesystem::create_directories(folder_);
}

CellPartition::CellPartition(CellPartition&& other) noexcept
    : folder_(std::move(other.folder_)),
      colors_(other.colors_),
      uvs_(other.uvs_),
      materials_(other.materials_),
      orders_(other.orders_),
      owner_(std::exchange(other.owner_, false)),
      recordBytes_(other.recordBytes_),
      buffers_(std::move(other.buffers_)),
      triangles_(std::move(other.triangles_)),
      buffered_(other.buffered_) {}

CellPartition::~CellPartition() {
  if (!owner_) return;
  std::error_code ignored;
  std::filesystem::remove_all(folder_, ignored);
}

std::filesystem::path CellPartition::fileOf(std::uint32_t cell) const {
  return folder_ / ("cell_" + std::to_string(cell) + ".tri");
}

std::uint32_t CellPartition::addCell() {
  buffers_.emplace_back();
  triangles_.push_back(0);
  return std::uint32_t(buffers_.size() - 1);
}

void CellPartition::append(std::uint32_t cell, const SourceTriangle& t, std::uint32_t order) {
  std::vector<char>& b = buffers_[cell];
  ++triangles_[cell];
  const std::size_t at = b.size();
  b.resize(at + recordBytes_);
  char* out = put(b.data() + at, t.positions);
  out = put(out, t.normals);
  if (colors_) out = put(out, t.colors);
  if (uvs_) out = put(out, t.uvs);
  if (materials_) out = put(out, t.material);
  if (orders_) put(out, order);
  if ((buffered_ += recordBytes_) >= kBufferedBytes) flush();
}

void CellPartition::flush() {
  std::vector<char> packed;
  for (std::uint32_t cell = 0; cell < buffers_.size(); ++cell) {
    std::vector<char>& b = buffers_[cell];
    if (b.empty()) continue;
    packed.resize(ZSTD_compressBound(b.size()));
    const std::size_t n =
        ZSTD_compress(packed.data(), packed.size(), b.data(), b.size(), kPartitionZstdLevel);
    if (ZSTD_isError(n)) throw std::runtime_error(fileOf(cell).string() + ": compression failed");
    const FrameHeader header{std::uint32_t(b.size()), std::uint32_t(n)};
    std::unique_ptr<std::FILE, FileCloser> file(std::fopen(fileOf(cell).c_str(), "ab"));
    if (!file || std::fwrite(&header, sizeof header, 1, file.get()) != 1 ||
        std::fwrite(packed.data(), 1, n, file.get()) != n || std::fflush(file.get()) != 0)
      throw std::runtime_error(fileOf(cell).string() + ": cannot write (disk full?)");
    std::vector<char>().swap(b);  // frees (`b = {}` would keep the capacity)
  }
  buffered_ = 0;
}

std::vector<SourceTriangle> CellPartition::read(std::uint32_t cell) const {
  std::vector<SourceTriangle> out;
  forEach(cell, [&](const SourceTriangle& t, std::uint32_t) { out.push_back(t); });
  return out;
}

void CellPartition::forEach(
    std::uint32_t cell, const std::function<void(const SourceTriangle&, std::uint32_t order)>& visit) const {
  std::unique_ptr<std::FILE, FileCloser> file(std::fopen(fileOf(cell).c_str(), "rb"));
  if (!file) throw std::runtime_error(fileOf(cell).string() + ": binned triangles are missing");
  std::vector<char> packed, raw;
  for (FrameHeader header; std::fread(&header, sizeof header, 1, file.get()) == 1;) {
    packed.resize(header.packedBytes);
    raw.resize(header.rawBytes);
    if (std::fread(packed.data(), 1, packed.size(), file.get()) != packed.size() ||
        ZSTD_decompress(raw.data(), raw.size(), packed.data(), packed.size()) != raw.size() ||
        raw.size() % recordBytes_ != 0)
      throw std::runtime_error(fileOf(cell).string() + ": binned triangles are damaged");
    for (const char* in = raw.data(); in < raw.data() + raw.size();) {
      SourceTriangle t;
      std::uint32_t order = 0;
      in = get(in, t.positions);
      in = get(in, t.normals);
      if (colors_) in = get(in, t.colors);
      if (uvs_) in = get(in, t.uvs);
      if (materials_) in = get(in, t.material);
      if (orders_) in = get(in, order);
      visit(t, order);
    }
  }
}

void CellPartition::remove(std::uint32_t cell) const {
  std::error_code ignored;
  std::filesystem::remove(fileOf(cell), ignored);
}

}  // namespace svo
