// Draco point clouds (point_cloud_draco.hpp), decoded by the Draco library.
#include "point_cloud_draco.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>
#include <vector>

#include <draco/compression/decode.h>
#include <draco/point_cloud/point_cloud.h>
#include <glm/common.hpp>

namespace svo::detail {

glm::vec4 displayToLinear(glm::vec4 c);  // mesh_io.cpp

namespace {

namespace fs = std::filesystem;

// The header's magic, version and geometry type: enough to tell a point cloud from a mesh.
constexpr std::size_t kDracoHeaderBytes = 16;

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

std::vector<char> readBytes(const fs::path& path, std::size_t limit) {
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "cannot open file");
  std::vector<char> bytes;
  if (limit == 0) {
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  } else {
    bytes.resize(limit);
    in.read(bytes.data(), std::streamsize(limit));
    bytes.resize(std::size_t(std::max<std::streamsize>(in.gcount(), 0)));
  }
  if (in.bad()) fail(path, "cannot read file");
  return bytes;
}

// Integer colors that are not flagged normalized still mean 0..max (as mesh_io.cpp reads them); divided in
// double, as the PLY reader divides, so that the same codes give the same colors.
double colorMax(const draco::PointAttribute& col) {
  if (col.normalized()) return 1.0;
  switch (col.data_type()) {
    case draco::DT_UINT8:
      return 255.0;
    case draco::DT_UINT16:
      return 65535.0;
    case draco::DT_UINT32:
      return 4294967295.0;
    default:
      return 1.0;
  }
}

}  // namespace

bool isDracoPointCloud(const fs::path& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;
  std::vector<char> head = readBytes(path, kDracoHeaderBytes);
  draco::DecoderBuffer buffer;
  buffer.Init(head.data(), head.size());
  const auto type = draco::Decoder::GetEncodedGeometryType(&buffer);
  return type.ok() && type.value() == draco::POINT_CLOUD;
}

PointCloud loadDracoPoints(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "no such file");
  std::vector<char> bytes = readBytes(path, 0);
  draco::DecoderBuffer buffer;
  buffer.Init(bytes.data(), bytes.size());
  draco::Decoder decoder;
  auto decoded = decoder.DecodePointCloudFromBuffer(&buffer);
  if (!decoded.ok())
    fail(path, "not a readable Draco point cloud (Draco: " + decoded.status().error_msg_string() + ")");
  const draco::PointCloud& dc = *decoded.value();
  const draco::PointAttribute* pos = dc.GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (!pos || pos->num_components() < 3) fail(path, "the Draco point cloud has no 3D positions");
  const std::size_t n = dc.num_points();
  PointCloud cloud;
  cloud.format = "Draco point cloud";
  cloud.positions.resize(n);
  for (draco::PointIndex p(0); p < static_cast<std::uint32_t>(n); ++p) {
    double v[3] = {0, 0, 0};
    if (!pos->ConvertValue<double>(pos->mapped_index(p), 3, v)) fail(path, "a Draco position is unreadable");
    cloud.positions[p.value()] = glm::dvec3(v[0], v[1], v[2]);
  }
  if (const draco::PointAttribute* nor = dc.GetNamedAttribute(draco::GeometryAttribute::NORMAL);
      nor && nor->num_components() >= 3) {
    cloud.normals.resize(n);
    for (draco::PointIndex p(0); p < static_cast<std::uint32_t>(n); ++p) {
      float v[3] = {0, 0, 0};
      if (!nor->ConvertValue<float>(nor->mapped_index(p), 3, v)) fail(path, "a Draco normal is unreadable");
      cloud.normals[p.value()] = glm::vec3(v[0], v[1], v[2]);
    }
  }
  if (const draco::PointAttribute* col = dc.GetNamedAttribute(draco::GeometryAttribute::COLOR);
      col && col->num_components() >= 3) {
    const double max = colorMax(*col);
    cloud.colors.resize(n);
    for (draco::PointIndex p(0); p < static_cast<std::uint32_t>(n); ++p) {
      double c[3] = {1, 1, 1};
      col->ConvertValue<double>(col->mapped_index(p), 3, c);
      glm::vec4 rgba(1.0f);
      for (int k = 0; k < 3; ++k)  // a color that is not a number is black
        rgba[k] = std::isfinite(c[k]) ? float(std::clamp(c[k] / max, 0.0, 1.0)) : 0.0f;
      cloud.colors[p.value()] = displayToLinear(rgba);
    }
  }
  return cloud;
}

}  // namespace svo::detail
