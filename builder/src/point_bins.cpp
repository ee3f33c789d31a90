// The out-of-core scan build's binned points (point_bins.hpp).
#include "point_bins.hpp"

#include <fstream>
#include <stdexcept>
#include <string>
#include <type_traits>

namespace svo::detail {
namespace {

// Bytes buffered across all cells before they go to disk: 64 MiB, as the mesh build's partition buffers.
constexpr std::size_t kBufferedBytes = std::size_t(64) << 20;

static_assert(std::is_trivially_copyable_v<BinnedPoint> && std::is_trivially_copyable_v<HaloPoint>);

template <class T>
void appendFile(const std::filesystem::path& path, const std::vector<T>& records) {
  std::ofstream out(path, std::ios::binary | std::ios::app);
  out.write(reinterpret_cast<const char*>(records.data()), std::streamsize(records.size() * sizeof(T)));
  if (!out.flush()) throw std::runtime_error(path.string() + ": cannot write (disk full?)");
}

template <class T>
std::vector<T> readFile(const std::filesystem::path& path) {
  std::error_code ec;
  const std::uint64_t bytes = std::filesystem::exists(path, ec) ? std::filesystem::file_size(path, ec) : 0;
  if (ec || bytes % sizeof(T) != 0) throw std::runtime_error(path.string() + ": damaged (not whole records)");
  std::vector<T> out(bytes / sizeof(T));
  if (bytes == 0) return out;
  std::ifstream in(path, std::ios::binary);
  if (!in.read(reinterpret_cast<char*>(out.data()), std::streamsize(bytes)))
    throw std::runtime_error(path.string() + ": cannot read");
  return out;
}

}  // namespace

PointBins::PointBins(std::filesystem::path folder, std::size_t cells)
    : folder_(std::move(folder)), own_(cells), halo_(cells) {
  std::filesystem::create_directories(folder_);
}

std::filesystem::path PointBins::fileOf(std::uint32_t cell, const char* kind) const {
  return folder_ / (std::to_string(cell) + "." + kind);
}

void PointBins::appendOwn(std::uint32_t cell, const BinnedPoint& p) {
  own_[cell].push_back(p);
  if ((buffered_ += sizeof p) >= kBufferedBytes) flush();
}

void PointBins::appendHalo(std::uint32_t cell, const HaloPoint& p) {
  halo_[cell].push_back(p);
  if ((buffered_ += sizeof p) >= kBufferedBytes) flush();
}

void PointBins::flush() {
  for (std::uint32_t c = 0; c < own_.size(); ++c) {
    if (!own_[c].empty()) appendFile(fileOf(c, "points"), own_[c]), std::vector<BinnedPoint>().swap(own_[c]);
    if (!halo_[c].empty()) appendFile(fileOf(c, "halo"), halo_[c]), std::vector<HaloPoint>().swap(halo_[c]);
  }
  buffered_ = 0;
}

std::vector<BinnedPoint> PointBins::readOwn(std::uint32_t cell) const {
  return readFile<BinnedPoint>(fileOf(cell, "points"));
}
std::vector<HaloPoint> PointBins::readHalo(std::uint32_t cell) const {
  return readFile<HaloPoint>(fileOf(cell, "halo"));
}
std::uint64_t PointBins::ownCount(std::uint32_t cell) const {
  std::error_code ec;
  const std::uint64_t bytes = std::filesystem::file_size(fileOf(cell, "points"), ec);
  return ec ? 0 : bytes / sizeof(BinnedPoint);
}

void PointBins::writeNormals(std::uint32_t cell, const std::vector<glm::vec3>& normals) const {
  const std::filesystem::path path = fileOf(cell, "normals"), temporary = fileOf(cell, "normals.tmp");
  std::filesystem::remove(temporary);
  appendFile(temporary, normals);
  std::filesystem::rename(temporary, path);
}
bool PointBins::hasNormals(std::uint32_t cell) const {
  return std::filesystem::exists(fileOf(cell, "normals"));
}
std::vector<glm::vec3> PointBins::readNormals(std::uint32_t cell) const {
  return readFile<glm::vec3>(fileOf(cell, "normals"));
}

}  // namespace svo::detail
