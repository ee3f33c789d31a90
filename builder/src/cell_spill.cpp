#include "cell_spill.hpp"

#include <cstring>
#include <fstream>
#include <mutex>
#include <stdexcept>
#include <string>

#include <zstd.h>

#include "hasher.hpp"

namespace svo {
namespace {

// Zstd level of the spilled cells: fast, they are read once.
constexpr int kSpillZstdLevel = 1;
constexpr char kCellMagic[8] = {'S', 'V', 'O', 'C', 'E', 'L', 'L', '1'};

std::uint64_t cellChecksum(CellFileHeader h, const char* payload, std::size_t bytes) {
  h.checksum = 0;
  return Hasher().add(&h, 1).add(payload, bytes).digest();
}

}  // namespace

std::filesystem::path cellPath(const std::filesystem::path& work, glm::ivec3 c) {
  return work /
         ("cell_" + std::to_string(c.x) + "_" + std::to_string(c.y) + "_" + std::to_string(c.z) + ".bin");
}

void writeCell(const std::filesystem::path& path, const VoxelTree& tree, const CellRoot& root) {
  const std::size_t rawBytes = tree.voxels.size() * sizeof(VoxelRecord);
  std::vector<char> packed(ZSTD_compressBound(rawBytes));
  const std::size_t n =
      ZSTD_compress(packed.data(), packed.size(), tree.voxels.data(), rawBytes, kSpillZstdLevel);
  if (ZSTD_isError(n)) throw std::runtime_error(path.string() + ": compression failed");
  CellFileHeader h{};
  std::memcpy(h.magic, kCellMagic, sizeof h.magic);
  h.recordCount = tree.voxels.size();
  h.compressedBytes = n;
  h.root = root.record;
  h.weight = root.sums.weight;
  for (int k = 0; k < 4; ++k) h.color[k] = root.sums.color[k];
  for (int k = 0; k < 3; ++k) h.normal[k] = root.sums.normal[k];
  h.hasColors = tree.hasColors, h.hasNormals = tree.hasNormals;
  h.checksum = cellChecksum(h, packed.data(), n);
  // Complete or absent: written under a temporary name, flushed, renamed.
  const std::filesystem::path temp = path.string() + ".tmp";
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(&h), sizeof h);
    out.write(packed.data(), std::streamsize(n));
    if (!out.flush()) {
      out.close();
      std::error_code ignored;
      std::filesystem::remove(temp, ignored);
      throw std::runtime_error(temp.string() + ": cannot write (disk full?)");
    }
  }
  std::filesystem::rename(temp, path);
}

std::optional<CellFileHeader> readCellHeader(const std::filesystem::path& path, std::vector<char>* payload) {
  std::ifstream in(path, std::ios::binary);
  CellFileHeader h{};
  if (!in.read(reinterpret_cast<char*>(&h), sizeof h) ||
      std::memcmp(h.magic, kCellMagic, sizeof h.magic) != 0)
    return std::nullopt;
  std::error_code ec;
  if (std::filesystem::file_size(path, ec) != sizeof h + h.compressedBytes || ec) return std::nullopt;
  std::vector<char> data(h.compressedBytes);
  if (!in.read(data.data(), std::streamsize(data.size())) ||
      cellChecksum(h, data.data(), data.size()) != h.checksum ||
      ZSTD_getFrameContentSize(data.data(), data.size()) != h.recordCount * sizeof(VoxelRecord))
    return std::nullopt;
  if (payload) *payload = std::move(data);
  return h;
}

CellRoot rootOf(const CellFileHeader& h) {
  CellRoot r;
  r.record = h.root;
  r.sums.weight = h.weight;
  r.sums.color = glm::dvec4(h.color[0], h.color[1], h.color[2], h.color[3]);
  r.sums.normal = glm::dvec3(h.normal[0], h.normal[1], h.normal[2]);
  return r;
}

VoxelTree readCell(const std::filesystem::path& path) {
  std::vector<char> payload;
  const std::optional<CellFileHeader> h = readCellHeader(path, &payload);
  if (!h)
    throw std::runtime_error(path.string() +
                             ": a spilled cell is missing or damaged; build again without --resume");
  VoxelTree tree;
  tree.hasColors = h->hasColors != 0, tree.hasNormals = h->hasNormals != 0;
  tree.voxels.resize(h->recordCount);
  const std::size_t n = ZSTD_decompress(tree.voxels.data(), tree.voxels.size() * sizeof(VoxelRecord),
                                        payload.data(), payload.size());
  if (ZSTD_isError(n) || n != tree.voxels.size() * sizeof(VoxelRecord))
    throw std::runtime_error(path.string() +
                             ": a spilled cell does not decompress; build again without --resume");
  return tree;
}

void appendSpilledForest(StoreFileWriter& writer, const VoxelTree& top, int cellLevel,
                         const std::filesystem::path& work, OutOfCoreReport& report) {
  BuildStats& stats = report.stats;
  addTreeStats(top, 0, stats);
  std::mutex statsMutex;  // cells are loaded on several threads
  writer.appendForest(top, cellLevel, [&](glm::ivec3 cell, bool counting) {
    VoxelTree tree = readCell(cellPath(work, cell));
    if (!counting) {
      std::lock_guard lock(statsMutex);
      // The cell's root is already counted by the top as a leaf voxel of the cell level.
      addTreeStats(tree, cellLevel, stats);
      --stats.voxelsPerLevel[std::size_t(cellLevel)];
      --stats.leafVoxels;
      stats.contours -= tree.voxels[0].hasContour;
      ++report.cells;
    }
    return tree;
  });
  report.slices = writer.slices();
}

}  // namespace svo
