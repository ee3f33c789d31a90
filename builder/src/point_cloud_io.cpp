// Point clouds in (points.hpp): PLY (ASCII and binary, either byte order) and .xyz text decoded here, Draco
// through point_cloud_draco.cpp. Kept apart from the rest of the builder (glm only) so that the point-cloud
// fuzz target links this file alone.
//
// No Debian package reads PLY point clouds with their header errors reported (assimp turns a PLY without
// faces into an empty scene), so the header and records are decoded here: elements of typed properties,
// lists walked, the vertex element's position, normal and color properties picked by name.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include <glm/geometric.hpp>

#include "file_extension.hpp"
#include "ply_format.hpp"
#include "point_cloud_draco.hpp"
#include "svo/builder/points.hpp"

namespace svo {

namespace detail {  // mesh_io.cpp
glm::vec4 displayToLinear(glm::vec4 c);
}  // namespace detail

namespace {

namespace fs = std::filesystem;

using detail::ply::kMaxHeaderBytes;
// How much of a file is read to tell a PLY point cloud from a PLY mesh: its header.
constexpr std::size_t kSniffBytes = kMaxHeaderBytes;

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

std::string readFile(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "no such file");
  if (!fs::is_regular_file(path, ec)) fail(path, "not a regular file");
  std::ifstream in(path, std::ios::binary);
  if (!in) fail(path, "cannot open file");
  std::ostringstream bytes;
  bytes << in.rdbuf();
  if (in.bad()) fail(path, "cannot read file");
  return std::move(bytes).str();
}

std::string readHead(const fs::path& path, std::size_t bytes) {
  std::ifstream in(path, std::ios::binary);
  std::string head(bytes, '\0');
  in.read(head.data(), std::streamsize(bytes));
  head.resize(std::size_t(std::max<std::streamsize>(in.gcount(), 0)));
  return head;
}

// ----- PLY -------------------------------------------------------------------------------------------------

using PlyType = detail::ply::Type;
using PlyProperty = detail::ply::Property;
using PlyElement = detail::ply::Element;
using detail::ply::sizeOf;
using detail::ply::valueAt;

// What a color property's largest value is: integers span their type, floats [0, 1].
double colorScale(PlyType t) {
  constexpr double kMax[] = {127.0, 255.0, 32767.0, 65535.0, 2147483647.0, 4294967295.0, 1.0, 1.0};
  return kMax[int(t)];
}

enum class PlyFormat : std::uint8_t { Ascii, BinaryLittleEndian, BinaryBigEndian };
struct PlyHeader {
  PlyFormat format = PlyFormat::Ascii;
  std::vector<PlyElement> elements;
  std::size_t bytes = 0;  // where the data starts
};

// The header's lines up to end_header; nullopt with `error` set when it is not a PLY header.
std::optional<PlyHeader> parsePlyHeader(std::string_view text, std::string& error) {
  const std::size_t end = text.substr(0, kMaxHeaderBytes).find("end_header");
  if (text.substr(0, 3) != "ply" || (text.size() > 3 && text[3] != '\n' && text[3] != '\r'))
    return error = "not a PLY file (no 'ply' line)", std::nullopt;
  if (end == std::string_view::npos)
    return error = "malformed PLY header: no end_header line in its first 64 KiB", std::nullopt;
  std::size_t dataStart = text.find('\n', end);
  if (dataStart == std::string_view::npos) return error = "malformed PLY header: no data", std::nullopt;
  PlyHeader header;
  header.bytes = dataStart + 1;
  std::istringstream lines{std::string(text.substr(0, end))};
  bool formatSeen = false;
  int lineNumber = 0;
  for (std::string line; std::getline(lines, line);) {
    ++lineNumber;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string word;
    words >> word;
    const auto bad = [&](const std::string& what) {
      error = "malformed PLY header, line " + std::to_string(lineNumber) + " ('" + line + "'): " + what;
      return std::nullopt;
    };
    if (word.empty() || word == "ply" || word == "comment" || word == "obj_info") continue;
    if (word == "format") {
      std::string kind, version;
      words >> kind >> version;
      if (kind == "ascii")
        header.format = PlyFormat::Ascii;
      else if (kind == "binary_little_endian")
        header.format = PlyFormat::BinaryLittleEndian;
      else if (kind == "binary_big_endian")
        header.format = PlyFormat::BinaryBigEndian;
      else
        return bad("unknown format");
      formatSeen = true;
    } else if (word == "element") {
      PlyElement e;
      std::string count;
      if (!(words >> e.name >> count)) return bad("an element needs a name and a count");
      const auto [p, ec] = std::from_chars(count.data(), count.data() + count.size(), e.count);
      if (ec != std::errc() || p != count.data() + count.size()) return bad("the count is not a number");
      header.elements.push_back(std::move(e));
    } else if (word == "property") {
      if (header.elements.empty()) return bad("a property before any element");
      std::string what;
      std::optional<PlyProperty> p = detail::ply::parseProperty(words, what);
      if (!p) return bad(what);
      header.elements.back().properties.push_back(std::move(*p));
    } else {
      return bad("unknown keyword");
    }
  }
  if (!formatSeen) return error = "malformed PLY header: no format line", std::nullopt;
  return header;
}

// The vertex element's properties that make a point, by index into its properties (-1: absent).
struct PointProperties {
  int position[3] = {-1, -1, -1}, normal[3] = {-1, -1, -1}, color[3] = {-1, -1, -1};
};

PointProperties pointProperties(const PlyElement& vertex) {
  PointProperties out;
  static constexpr const char* kPosition[] = {"x", "y", "z"};
  static constexpr const char* kNormal[] = {"nx", "ny", "nz"};
  static constexpr const char* kColor[] = {"red", "green", "blue"};
  static constexpr const char* kDiffuse[] = {"diffuse_red", "diffuse_green", "diffuse_blue"};
  for (int i = 0; i < int(vertex.properties.size()); ++i) {
    const PlyProperty& p = vertex.properties[std::size_t(i)];
    if (p.list) continue;
    for (int k = 0; k < 3; ++k) {
      if (p.name == kPosition[k]) out.position[k] = i;
      if (p.name == kNormal[k]) out.normal[k] = i;
      if (p.name == kColor[k] || p.name == kDiffuse[k]) out.color[k] = i;
    }
  }
  return out;
}

// Reads elements one record at a time, ASCII tokens or binary values, reporting truncation by element.
class PlyRecords {
 public:
  PlyRecords(const fs::path& path, std::string_view data, PlyFormat format)
      : path_(path), data_(data), format_(format) {}

  // One value of `type`; `what` names the record for the error of a value that is not a number. At the end
  // of the data it returns 0 and marks the data truncated.
  double next(PlyType type, const std::string& what) {
    if (format_ == PlyFormat::Ascii) return nextToken(what);
    const std::size_t n = sizeOf(type);
    if (data_.size() - pos_ < n) return truncated_ = true, pos_ = data_.size(), 0.0;
    const double v = valueAt(data_.data() + pos_, type, format_ == PlyFormat::BinaryBigEndian);
    pos_ += n;
    return v;
  }
  // Reads one record of `e`, with its non-list values in `values` (lists skipped); false when the data ends
  // before the record does.
  bool record(const PlyElement& e, std::uint64_t index, std::vector<double>& values) {
    const std::string what = e.name + " " + std::to_string(index) + " of " + std::to_string(e.count);
    values.resize(e.properties.size());
    for (std::size_t i = 0; i < e.properties.size() && !truncated_; ++i) {
      const PlyProperty& p = e.properties[i];
      if (!p.list) {
        values[i] = next(p.type, what);
        continue;
      }
      const double count = next(p.countType, what);
      if (truncated_) break;
      if (!(count >= 0.0) || count != std::floor(count)) fail(path_, "bad list length in " + what);
      for (double k = 0; k < count && !truncated_; ++k) next(p.type, what);
    }
    return !truncated_;
  }
  // Fewest bytes a record of `e` takes: a bound on how many records the rest of the file can hold.
  std::uint64_t recordsLeftAtMost(const PlyElement& e) const {
    std::size_t least = 0;  // ASCII: a digit and a separator per value
    for (const PlyProperty& p : e.properties)
      least += format_ == PlyFormat::Ascii ? 2 : sizeOf(p.list ? p.countType : p.type);
    return least == 0 ? std::numeric_limits<std::uint64_t>::max() : (data_.size() - pos_) / least;
  }

 private:
  double nextToken(const std::string& what) {
    while (pos_ < data_.size() && std::isspace(static_cast<unsigned char>(data_[pos_]))) ++pos_;
    std::size_t end = pos_;
    while (end < data_.size() && !std::isspace(static_cast<unsigned char>(data_[end]))) ++end;
    if (end == pos_) return truncated_ = true, 0.0;
    double v = 0.0;
    const char* first = data_.data() + pos_;
    if (*first == '+') ++first;
    const auto [p, ec] = std::from_chars(first, data_.data() + end, v);
    if (ec != std::errc() || p != data_.data() + end)
      fail(path_, "'" + std::string(data_.substr(pos_, std::min<std::size_t>(end - pos_, 32))) +
                      "' is not a number, in " + what);
    pos_ = end;
    return v;
  }

  const fs::path& path_;
  std::string_view data_;
  PlyFormat format_;
  std::size_t pos_ = 0;
  bool truncated_ = false;
};

void readPlyVertices(const fs::path& path, PlyRecords& records, const PlyElement& vertex, PointCloud& cloud) {
  const PointProperties props = pointProperties(vertex);
  for (int k = 0; k < 3; ++k)
    if (props.position[k] < 0) fail(path, "the PLY vertex element has no x, y and z properties");
  const bool normals = props.normal[0] >= 0 && props.normal[1] >= 0 && props.normal[2] >= 0;
  const bool colors = props.color[0] >= 0 && props.color[1] >= 0 && props.color[2] >= 0;
  // A file that ends inside the vertex records (scans cut short in transfer, such as assimp's pond.0.ply)
  // gives the complete records before the cut; the caller reports the missing ones.
  const std::uint64_t reserve = std::min(vertex.count, records.recordsLeftAtMost(vertex));
  cloud.positions.reserve(std::size_t(reserve));
  if (normals) cloud.normals.reserve(std::size_t(reserve));
  if (colors) cloud.colors.reserve(std::size_t(reserve));
  std::vector<double> v;
  for (std::uint64_t i = 0; i < vertex.count; ++i) {
    if (!records.record(vertex, i, v)) {
      cloud.missing = vertex.count - i;
      if (i == 0) fail(path, "truncated PLY data: the file ends before its first vertex");
      return;
    }
    const auto at = [&](int prop) { return v[std::size_t(prop)]; };
    cloud.positions.emplace_back(at(props.position[0]), at(props.position[1]), at(props.position[2]));
    if (normals)
      cloud.normals.emplace_back(float(at(props.normal[0])), float(at(props.normal[1])),
                                 float(at(props.normal[2])));
    if (colors) {
      glm::vec4 c(1.0f);
      for (int k = 0; k < 3; ++k) {
        const PlyType type = vertex.properties[std::size_t(props.color[k])].type;
        c[k] = float(std::clamp(at(props.color[k]) / colorScale(type), 0.0, 1.0));
        if (!std::isfinite(c[k])) c[k] = 0.0f;
      }
      cloud.colors.push_back(detail::displayToLinear(c));
    }
  }
}

PointCloud loadPly(const fs::path& path) {
  const std::string bytes = readFile(path);
  std::string error;
  const std::optional<PlyHeader> header = parsePlyHeader(bytes, error);
  if (!header) fail(path, error);
  PlyRecords records(path, std::string_view(bytes).substr(header->bytes), header->format);
  PointCloud cloud;
  cloud.format = header->format == PlyFormat::Ascii ? "PLY point cloud (ASCII)" : "PLY point cloud (binary)";
  std::vector<double> skipped;
  for (const PlyElement& e : header->elements) {
    if ((e.name == "face" || e.name == "tristrips") && e.count > 0)
      fail(path, "the PLY file has faces: a mesh, not a point cloud");
    if (e.name == "vertex") {
      readPlyVertices(path, records, e, cloud);
      return cloud;  // what follows the vertices is not needed
    }
    if (e.properties.empty()) continue;  // records of nothing take no bytes, however many are declared
    for (std::uint64_t i = 0; i < e.count; ++i)
      if (!records.record(e, i, skipped))
        fail(path, "truncated PLY data: the file ends in " + e.name + " " + std::to_string(i) + " of " +
                       std::to_string(e.count) + ", before the vertices");
  }
  fail(path, "the PLY file has no vertex element");
}

// ----- .xyz ------------------------------------------------------------------------------------------------

// The column counts an .xyz line may have (see points.hpp for what each means).
constexpr std::size_t kXyzColumns[] = {3, 6, 9};

// Splits a line into numbers; the column count or the first bad word is reported by the caller.
bool parseXyzLine(std::string_view line, std::vector<double>& values, std::string& badWord) {
  values.clear();
  const auto separator = [](char c) { return c == ' ' || c == '\t' || c == ',' || c == '\r'; };
  std::size_t pos = 0;
  while (pos < line.size()) {
    while (pos < line.size() && separator(line[pos])) ++pos;
    std::size_t end = pos;
    while (end < line.size() && !separator(line[end])) ++end;
    if (end == pos) break;
    const char* first = line.data() + pos;
    if (*first == '+') ++first;
    double v = 0.0;
    const auto [p, ec] = std::from_chars(first, line.data() + end, v);
    if (ec != std::errc() || p != line.data() + end) {
      badWord = std::string(line.substr(pos, std::min<std::size_t>(end - pos, 32)));
      return false;
    }
    values.push_back(v);
    pos = end;
  }
  return true;
}

// Whether six-column lines carry colors: every value of columns 4-6 an integer in 0..255, some above 1.
bool sixColumnsAreColors(const std::vector<double>& rows) {
  bool aboveOne = false;
  for (std::size_t i = 0; i < rows.size(); i += 6)
    for (std::size_t k = 3; k < 6; ++k) {
      const double c = rows[i + k];
      if (!(c >= 0.0 && c <= 255.0) || c != std::floor(c)) return false;
      aboveOne = aboveOne || c > 1.0;
    }
  return aboveOne;
}

PointCloud loadXyz(const fs::path& path) {
  const std::string bytes = readFile(path);
  std::vector<double> rows, values;
  std::size_t columns = 0, firstLine = 0, lineNumber = 0;
  std::string badWord;
  for (std::size_t pos = 0; pos < bytes.size();) {
    std::size_t end = bytes.find('\n', pos);
    if (end == std::string::npos) end = bytes.size();
    std::string_view line = std::string_view(bytes).substr(pos, end - pos);
    pos = end + 1, ++lineNumber;
    if (const std::size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
    if (!parseXyzLine(line, values, badWord))
      fail(path, "line " + std::to_string(lineNumber) + ": '" + badWord + "' is not a number");
    if (values.empty()) continue;
    if (columns == 0) {
      if (std::find(std::begin(kXyzColumns), std::end(kXyzColumns), values.size()) == std::end(kXyzColumns))
        fail(path, "line " + std::to_string(lineNumber) + " has " + std::to_string(values.size()) +
                       " numbers; .xyz lines have 3 (x y z), 6 (x y z r g b, or x y z nx ny nz) or 9 "
                       "(x y z r g b nx ny nz)");
      columns = values.size(), firstLine = lineNumber;
    } else if (values.size() != columns) {
      fail(path, "line " + std::to_string(lineNumber) + " has " + std::to_string(values.size()) +
                     " numbers, line " + std::to_string(firstLine) + " has " + std::to_string(columns) +
                     " (a truncated or mixed file)");
    }
    rows.insert(rows.end(), values.begin(), values.end());
  }
  PointCloud cloud;
  cloud.format = ".xyz text";
  if (columns == 0) return cloud;
  const bool colors = columns == 9 || (columns == 6 && sixColumnsAreColors(rows));
  const bool normals = columns == 9 || (columns == 6 && !colors);
  const std::size_t normalColumn = columns == 9 ? 6 : 3;
  const std::size_t n = rows.size() / columns;
  cloud.positions.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double* r = rows.data() + i * columns;
    cloud.positions.emplace_back(r[0], r[1], r[2]);
    if (colors) {
      glm::vec4 c(1.0f);
      for (int k = 0; k < 3; ++k)
        c[k] = std::isfinite(r[3 + k]) ? float(std::clamp(r[3 + k] / 255.0, 0.0, 1.0)) : 0.0f;
      cloud.colors.push_back(detail::displayToLinear(c));
    }
    if (normals)
      cloud.normals.emplace_back(float(r[normalColumn]), float(r[normalColumn + 1]),
                                 float(r[normalColumn + 2]));
  }
  return cloud;
}

// A PLY header's verdict: vertices and no faces.
bool plyHeaderIsPointCloud(std::string_view head) {
  bool vertices = false;
  std::istringstream lines{std::string(head.substr(0, head.find("end_header")))};
  for (std::string line; std::getline(lines, line);) {
    std::istringstream words(line);
    std::string word, name;
    std::uint64_t count = 0;
    if (!(words >> word) || word != "element" || !(words >> name)) continue;
    if ((name == "face" || name == "tristrips") && (!(words >> count) || count > 0)) return false;
    vertices = vertices || name == "vertex";
  }
  return vertices;
}

}  // namespace

bool isPointCloudFile(const fs::path& path) {
  const std::string ext = detail::lowerExtension(path);
  if (ext == ".xyz") return true;
  if (ext == ".ply") return plyHeaderIsPointCloud(readHead(path, kSniffBytes));
  if (ext == ".drc") return detail::isDracoPointCloud(path);
  return false;
}

void validatePointCloud(const PointCloud& cloud, const std::string& source) {
  const auto bad = [&](const std::string& what) { throw std::runtime_error(source + ": " + what); };
  if (cloud.positions.empty()) bad("no points");
  if (!cloud.normals.empty() && cloud.normals.size() != cloud.positions.size())
    bad("the normals do not match the points in number");
  if (!cloud.colors.empty() && cloud.colors.size() != cloud.positions.size())
    bad("the colors do not match the points in number");
  for (std::size_t i = 0; i < cloud.positions.size(); ++i) {
    const glm::dvec3& p = cloud.positions[i];
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      bad("point " + std::to_string(i) + " has a non-finite position");
  }
}

PointCloud loadPointCloud(const fs::path& path) {
  const std::string ext = detail::lowerExtension(path);
  PointCloud cloud;
  if (ext == ".xyz")
    cloud = loadXyz(path);
  else if (ext == ".ply")
    cloud = loadPly(path);
  else if (ext == ".drc")
    cloud = detail::loadDracoPoints(path);
  else
    fail(path, "not a point cloud format (.ply, .drc or .xyz)");
  validatePointCloud(cloud, path.string());
  // A normal that is zero or not a number is unknown (scanners leave some so: pond.0.ply has NaNs), kept as
  // zero and estimated later; the others become unit length.
  for (glm::vec3& n : cloud.normals) {
    const float len = glm::length(n);
    n = std::isfinite(len) && len > 0.0f ? n / len : glm::vec3(0.0f);
  }
  return cloud;
}

}  // namespace svo
