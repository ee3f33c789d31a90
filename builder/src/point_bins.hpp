// The out-of-core scan build's points binned per cell in its work folder: each cell's own points in file
// order, its halo (copies of neighbouring cells' points near its faces, with the cell that owns each and
// its index there) and, once estimated, its own points' final normals. Files are raw records, appended
// through buffers; a normals file appears complete or not at all (written under a temporary name).
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include <glm/vec3.hpp>
#include <glm/vec4.hpp>

namespace svo::detail {

struct BinnedPoint {
  glm::dvec3 position{0.0};
  glm::vec3 normal{0.0f};  // zero: unknown
  glm::vec4 color{1.0f};
};
struct HaloPoint {
  BinnedPoint point;
  std::uint32_t owner = 0;  // the cell whose own point it is
  std::uint32_t index = 0;  // among that cell's own points
};

class PointBins {
 public:
  // Cells are numbered 0 .. cells - 1; `folder` is created when missing and kept (the caller removes it).
  PointBins(std::filesystem::path folder, std::size_t cells);
  // Buffered; every buffer goes to disk once they hold kBufferedBytes together.
  void appendOwn(std::uint32_t cell, const BinnedPoint& p);
  void appendHalo(std::uint32_t cell, const HaloPoint& p);
  void flush();
  // Throws naming the file when it is missing or damaged.
  std::vector<BinnedPoint> readOwn(std::uint32_t cell) const;
  std::vector<HaloPoint> readHalo(std::uint32_t cell) const;
  std::uint64_t ownCount(std::uint32_t cell) const;  // from the file's size
  void writeNormals(std::uint32_t cell, const std::vector<glm::vec3>& normals) const;
  bool hasNormals(std::uint32_t cell) const;
  std::vector<glm::vec3> readNormals(std::uint32_t cell) const;

 private:
  std::filesystem::path fileOf(std::uint32_t cell, const char* kind) const;
  std::filesystem::path folder_;
  std::vector<std::vector<BinnedPoint>> own_;
  std::vector<std::vector<HaloPoint>> halo_;
  std::size_t buffered_ = 0;
};

}  // namespace svo::detail
