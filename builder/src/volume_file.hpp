// What the OpenVDB import and export share (volume_io.cpp): the library's one-time set-up, errors naming the
// file, and a file opened for reading with its grids listed from their metadata.
#pragma once

#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <openvdb/io/File.h>

#include "svo/builder/volume.hpp"

namespace svo::volume_file {

// Metadata `svo export` gives its shape grid: the octree depth whose voxels the grid's voxels are, with the
// scene cube's corner at index (0, 0, 0).
inline constexpr const char* kLevelsMetadata = "svo_levels";

// OpenVDB's grid types registered, once per process.
void initialize();
[[noreturn]] void fail(const std::filesystem::path& path, const std::string& what);

class Reader {
 public:
  // Throws naming the file when it is missing or not a readable OpenVDB file.
  explicit Reader(const std::filesystem::path& path);
  ~Reader();
  const std::filesystem::path& path() const { return path_; }
  const std::vector<VolumeGridInfo>& grids() const { return grids_; }
  openvdb::GridBase::Ptr read(const std::string& name);  // the first grid of that name, whole

 private:
  std::filesystem::path path_;
  std::unique_ptr<openvdb::io::File> file_;
  std::vector<VolumeGridInfo> grids_;
};

}  // namespace svo::volume_file
