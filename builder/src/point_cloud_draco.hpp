// Draco point clouds for point_cloud_io.cpp, in their own unit so that the point-cloud reader builds without
// Draco (the fuzz target stubs these two).
#pragma once

#include <filesystem>

#include "svo/builder/points.hpp"

namespace svo::detail {

// Whether the file's Draco header says point cloud (false for meshes and for what is not Draco at all).
bool isDracoPointCloud(const std::filesystem::path& path);
// POSITION, and NORMAL and COLOR where present, of every point; throws naming the file when it cannot be
// decoded (truncated, not Draco, a mesh).
PointCloud loadDracoPoints(const std::filesystem::path& path);

}  // namespace svo::detail
