// The out-of-core build's triangles binned per cell on disk: each cell's triangles in input order, in
// zstd frames, read back when the cell is built. Records keep only what the source has, and each
// triangle's place in the input where asked.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <vector>

#include "svo/builder/mesh.hpp"

namespace svo {

class CellPartition {
 public:
  // `folder` is created empty (and removed with the partition unless kept). Records hold positions, and
  // vertex colors, UVs, materials and the triangle's order in the input when asked.
  CellPartition(std::filesystem::path folder, bool colors, bool uvs, bool materials, bool orders = false);
  // A partition in a shared folder (another process's, or one kept), to read its cells: neither created nor
  // removed here.
  static CellPartition attach(std::filesystem::path folder, bool colors, bool uvs, bool materials,
                              bool orders = false);
  CellPartition(CellPartition&& other) noexcept;  // the moved-from partition removes nothing
  CellPartition(const CellPartition&) = delete;
  CellPartition& operator=(const CellPartition&) = delete;
  ~CellPartition();  // removes the folder

  std::uint32_t addCell();  // a new empty cell's id
  // Buffered; all buffers go to disk together once they hold kBufferedBytes.
  void append(std::uint32_t cell, const SourceTriangle& t, std::uint32_t order = 0);
  void flush();
  // Leaves the folder in place when the partition goes (for other processes, or later passes, to attach).
  void keep() { owner_ = false; }
  // A cell's triangles, in the order appended (flush() first). Thread-safe once appending is over.
  std::vector<SourceTriangle> read(std::uint32_t cell) const;
  // The same one by one with their orders, frame by frame (a cell need not fit in memory).
  void forEach(std::uint32_t cell,
               const std::function<void(const SourceTriangle&, std::uint32_t order)>& visit) const;
  void remove(std::uint32_t cell) const;  // frees the cell's disk space
  std::uint64_t trianglesIn(std::uint32_t cell) const { return triangles_[cell]; }  // appended here

 private:
  CellPartition(std::filesystem::path folder, bool colors, bool uvs, bool materials, bool orders, bool owner);
  std::filesystem::path fileOf(std::uint32_t cell) const;
  std::filesystem::path folder_;
  bool colors_, uvs_, materials_, orders_, owner_;
  std::size_t recordBytes_;
  std::vector<std::vector<char>> buffers_;  // per cell, packed records not yet written
  std::vector<std::uint64_t> triangles_;    // per cell
  std::size_t buffered_ = 0;
};

}  // namespace svo
