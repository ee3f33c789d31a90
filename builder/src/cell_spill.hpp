// The out-of-core build's spilled cells: one file per cell in the work folder, a checked header and the
// cell's zstd-compressed records, complete or absent (written under a temporary name, then renamed), so
// that any process sharing the folder can write a cell and a resume can trust what it finds.
#pragma once

#include <filesystem>
#include <optional>
#include <vector>

#include <glm/vec3.hpp>

#include "svo/builder/build.hpp"

namespace svo {

struct CellFileHeader {
  char magic[8];
  // XXH3-64 of this header (with checksum 0) and the compressed records: a resume trusts no unchecked byte.
  std::uint64_t recordCount = 0, compressedBytes = 0, checksum = 0;
  VoxelRecord root;
  double weight = 0.0, color[4] = {}, normal[3] = {};
  std::uint32_t hasColors = 0, hasNormals = 0;
};

std::filesystem::path cellPath(const std::filesystem::path& work, glm::ivec3 cell);
// Throws with the path on a write error (a full disk).
void writeCell(const std::filesystem::path& path, const VoxelTree& tree, const CellRoot& root);
// The header of a cell file that is complete and intact (and its payload when asked), or nullopt.
std::optional<CellFileHeader> readCellHeader(const std::filesystem::path& path, std::vector<char>* payload);
CellRoot rootOf(const CellFileHeader& h);
// Throws when the cell is missing or damaged.
VoxelTree readCell(const std::filesystem::path& path);

// The out-of-core store's slices (StoreFileWriter::appendForest) from `top`, the levels down to `cellLevel`,
// and the cells spilled in `work`. Adds the top's and the cells' voxels to report.stats (a cell's root
// counted once, as the top's leaf), counts report.cells and sets report.slices.
void appendSpilledForest(StoreFileWriter& writer, const VoxelTree& top, int cellLevel,
                         const std::filesystem::path& work, OutOfCoreReport& report);

}  // namespace svo
