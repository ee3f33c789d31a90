// A file's extension in lower case (".ply"), by which the readers pick a format (mesh_io.cpp,
// triangle_source.cpp, volume_io.cpp); inline so that the PLY fuzz target's slice of the builder links alone.
#pragma once

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <string>

namespace svo::detail {

inline std::string lowerExtension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

}  // namespace svo::detail
