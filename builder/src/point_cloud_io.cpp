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
#include <functional>
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
// Bytes read from a file at a time.
constexpr std::size_t kReadChunk = std::size_t(4) << 20;
// Points handed over per batch: 3.4 MB with normals and colors.
constexpr std::size_t kBatchPoints = std::size_t(1) << 16;
// How much of a file is read to tell a PLY point cloud from a PLY mesh: its header.
constexpr std::size_t kSniffBytes = kMaxHeaderBytes;

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

// A file read in chunks: view() is what is read past the cursor, more() reads the next chunk (dropping what
// lies before the cursor) and says whether it found any bytes.
class FileWindow {
 public:
  FileWindow(const fs::path& path, std::uint64_t offset) : path_(path), in_(path, std::ios::binary) {
    if (!in_) fail(path, "cannot open file");
    in_.seekg(std::streamoff(offset));
    std::error_code ec;
    fileBytes_ = fs::file_size(path, ec);
    read_ = offset;
  }
  // How much of the file lies before the cursor.
  double fraction() const {
    return fileBytes_ == 0 ? 1.0 : double(read_ - (buffer_.size() - pos_)) / double(fileBytes_);
  }
  std::string_view view() const { return std::string_view(buffer_).substr(pos_); }
  void advance(std::size_t n) { pos_ += n; }
  bool more() {
    if (eof_) return false;
    buffer_.erase(0, pos_);
    pos_ = 0;
    const std::size_t old = buffer_.size();
    buffer_.resize(old + kReadChunk);
    in_.read(buffer_.data() + old, std::streamsize(kReadChunk));
    const std::size_t got = std::size_t(std::max<std::streamsize>(in_.gcount(), 0));
    if (in_.bad()) fail(path_, "cannot read file");
    buffer_.resize(old + got);
    read_ += got;
    eof_ = got < kReadChunk;
    return got > 0;
  }

 private:
  const fs::path& path_;
  std::ifstream in_;
  std::string buffer_;
  std::size_t pos_ = 0;
  bool eof_ = false;
  std::uint64_t fileBytes_ = 0, read_ = 0;
};

void checkRegularFile(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "no such file");
  if (!fs::is_regular_file(path, ec)) fail(path, "not a regular file");
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

// Hands the points read to the caller in batches: positions checked finite (naming the point), a normal that
// is zero or not a number kept as zero (unknown, estimated later; scanners leave some so: pond.0.ply has
// NaNs), the others made unit length.
class BatchSink {
 public:
  BatchSink(const fs::path& path, const PointBatch& emit, std::function<double()> fraction)
      : path_(path), emit_(emit), fraction_(std::move(fraction)) {}
  void add(const glm::dvec3& p, const glm::vec3* normal, const glm::vec4* color) {
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
      fail(path_, "point " + std::to_string(count_ + batch_.positions.size()) + " has a non-finite position");
    batch_.positions.push_back(p);
    if (normal) {
      const float len = glm::length(*normal);
      batch_.normals.push_back(std::isfinite(len) && len > 0.0f ? *normal / len : glm::vec3(0.0f));
    }
    if (color) batch_.colors.push_back(*color);
    if (batch_.positions.size() == kBatchPoints) flush();
  }
  void flush() {
    if (batch_.positions.empty()) return;
    emit_(batch_, count_, fraction_());
    count_ += batch_.positions.size();
    batch_.positions.clear(), batch_.normals.clear(), batch_.colors.clear();
  }
  std::uint64_t count() const { return count_ + batch_.positions.size(); }

 private:
  const fs::path& path_;
  const PointBatch& emit_;
  std::function<double()> fraction_;
  PointCloud batch_;
  std::uint64_t count_ = 0;
};

// Reads elements one record at a time from the file, ASCII tokens or binary values.
class PlyRecords {
 public:
  PlyRecords(const fs::path& path, FileWindow& data, PlyFormat format)
      : path_(path), data_(data), format_(format) {}

  // Reads one record of `e` (`index` names it in errors), with its non-list values in `values` (lists
  // skipped); false when the file ends before the record does.
  bool record(const PlyElement& e, std::uint64_t index, std::vector<double>& values) {
    const auto what = [&] { return e.name + " " + std::to_string(index) + " of " + std::to_string(e.count); };
    values.resize(e.properties.size());
    for (std::size_t i = 0; i < e.properties.size() && !truncated_; ++i) {
      const PlyProperty& p = e.properties[i];
      if (!p.list) {
        values[i] = next(p.type, what);
        continue;
      }
      const double count = next(p.countType, what);
      if (truncated_) break;
      if (!(count >= 0.0) || count != std::floor(count)) fail(path_, "bad list length in " + what());
      for (double k = 0; k < count && !truncated_; ++k) next(p.type, what);
    }
    return !truncated_;
  }

 private:
  // One value of `type`; at the end of the file it returns 0 and marks the data truncated.
  template <class What>
  double next(PlyType type, const What& what) {
    if (format_ == PlyFormat::Ascii) return nextToken(what);
    const std::size_t n = sizeOf(type);
    while (data_.view().size() < n)
      if (!data_.more()) return truncated_ = true, 0.0;
    const double v = valueAt(data_.view().data(), type, format_ == PlyFormat::BinaryBigEndian);
    data_.advance(n);
    return v;
  }
  template <class What>
  double nextToken(const What& what) {
    const auto space = [](char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; };
    for (;;) {  // past the white space
      const std::string_view rest = data_.view();
      const auto start = std::find_if_not(rest.begin(), rest.end(), space);
      data_.advance(std::size_t(start - rest.begin()));
      if (start != rest.end()) break;
      if (!data_.more()) return truncated_ = true, 0.0;
    }
    std::string_view rest = data_.view();
    std::size_t end = std::size_t(std::find_if(rest.begin(), rest.end(), space) - rest.begin());
    while (end == rest.size() && data_.more())  // the token may go on in the next chunk
      rest = data_.view(), end = std::size_t(std::find_if(rest.begin(), rest.end(), space) - rest.begin());
    double v = 0.0;
    const char* first = rest.data();
    if (*first == '+') ++first;
    const auto [p, ec] = std::from_chars(first, rest.data() + end, v);
    if (ec != std::errc() || p != rest.data() + end)
      fail(path_, "'" + std::string(rest.substr(0, std::min<std::size_t>(end, 32))) +
                      "' is not a number, in " + what());
    data_.advance(end);
    return v;
  }

  const fs::path& path_;
  FileWindow& data_;
  PlyFormat format_;
  bool truncated_ = false;
};

// The vertex element's records as points; returns how many the header declares that the file lacks.
std::uint64_t readPlyVertices(const fs::path& path, PlyRecords& records, const PlyElement& vertex,
                              BatchSink& sink) {
  const PointProperties props = pointProperties(vertex);
  for (int k = 0; k < 3; ++k)
    if (props.position[k] < 0) fail(path, "the PLY vertex element has no x, y and z properties");
  const bool normals = props.normal[0] >= 0 && props.normal[1] >= 0 && props.normal[2] >= 0;
  const bool colors = props.color[0] >= 0 && props.color[1] >= 0 && props.color[2] >= 0;
  std::vector<double> v;
  for (std::uint64_t i = 0; i < vertex.count; ++i) {
    // A file that ends inside the vertex records (scans cut short in transfer, such as assimp's pond.0.ply)
    // gives the complete records before the cut; the caller reports the missing ones.
    if (!records.record(vertex, i, v)) {
      if (i == 0) fail(path, "truncated PLY data: the file ends before its first vertex");
      return vertex.count - i;
    }
    const auto at = [&](int prop) { return v[std::size_t(prop)]; };
    const glm::dvec3 p(at(props.position[0]), at(props.position[1]), at(props.position[2]));
    glm::vec3 n(0.0f);
    if (normals) n = {float(at(props.normal[0])), float(at(props.normal[1])), float(at(props.normal[2]))};
    glm::vec4 c(1.0f);
    if (colors) {
      for (int k = 0; k < 3; ++k) {
        const PlyType type = vertex.properties[std::size_t(props.color[k])].type;
        c[k] = float(std::clamp(at(props.color[k]) / colorScale(type), 0.0, 1.0));
        if (!std::isfinite(c[k])) c[k] = 0.0f;
      }
      c = detail::displayToLinear(c);
    }
    sink.add(p, normals ? &n : nullptr, colors ? &c : nullptr);
  }
  return 0;
}

// What the header says of the points: their format and which attributes they carry.
PointFileInfo plyPointInfo(const PlyHeader& header, const PlyElement& vertex) {
  const PointProperties props = pointProperties(vertex);
  PointFileInfo info;
  info.format = header.format == PlyFormat::Ascii ? "PLY point cloud (ASCII)" : "PLY point cloud (binary)";
  info.normals = props.normal[0] >= 0 && props.normal[1] >= 0 && props.normal[2] >= 0;
  info.colors = props.color[0] >= 0 && props.color[1] >= 0 && props.color[2] >= 0;
  return info;
}

PointFileInfo readPly(const fs::path& path, const PointBatch& emit) {
  std::string error;
  const std::optional<PlyHeader> header = parsePlyHeader(readHead(path, kMaxHeaderBytes + kReadChunk), error);
  if (!header) fail(path, error);
  FileWindow window(path, header->bytes);
  PlyRecords records(path, window, header->format);
  BatchSink sink(path, emit, [&window] { return window.fraction(); });
  std::vector<double> skipped;
  for (const PlyElement& e : header->elements) {
    if ((e.name == "face" || e.name == "tristrips") && e.count > 0)
      fail(path, "the PLY file has faces: a mesh, not a point cloud");
    if (e.name == "vertex") {
      PointFileInfo info = plyPointInfo(*header, e);
      info.missing = readPlyVertices(path, records, e, sink);
      sink.flush();
      info.points = sink.count();
      return info;  // what follows the vertices is not needed
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

// Calls `row` with each line's numbers (lines of none skipped) while it returns true; returns the column
// count. Lines of another count than the first's, or of a count no layout has, are errors.
template <class Row>
std::size_t forEachXyzRow(const fs::path& path, Row&& row, double* fraction = nullptr) {
  FileWindow window(path, 0);
  std::vector<double> values;
  std::size_t columns = 0, firstLine = 0, lineNumber = 0;
  std::string badWord;
  bool more = window.more();
  for (;;) {
    std::string_view rest = window.view();
    std::size_t end = rest.find('\n');
    if (end == std::string_view::npos && more) {  // the line may go on in the next chunk
      more = window.more();
      continue;
    }
    if (rest.empty()) return columns;
    if (end == std::string_view::npos) end = rest.size();
    std::string_view line = rest.substr(0, end);
    window.advance(std::min(end + 1, rest.size()));
    ++lineNumber;
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
    if (fraction) *fraction = window.fraction();
    if (!row(values)) return columns;
  }
}

// Whether six-column lines carry colors: every value of columns 4-6 an integer in 0..255, some above 1.
// Read through the whole file first, as the meaning of the columns depends on all of them.
bool sixColumnsAreColors(const fs::path& path) {
  bool colors = true, aboveOne = false;
  const std::size_t columns = forEachXyzRow(path, [&](const std::vector<double>& values) {
    if (values.size() != 6) return false;
    for (std::size_t k = 3; k < 6; ++k) {
      const double c = values[k];
      if (!(c >= 0.0 && c <= 255.0) || c != std::floor(c)) return colors = false;
      aboveOne = aboveOne || c > 1.0;
    }
    return true;
  });
  return columns == 6 && colors && aboveOne;
}

PointFileInfo readXyz(const fs::path& path, const PointBatch& emit) {
  PointFileInfo info;
  info.format = ".xyz text";
  double fraction = 0.0;
  BatchSink sink(path, emit, [&fraction] { return fraction; });
  bool known = false, sixAreColors = false;
  forEachXyzRow(
      path,
      [&](const std::vector<double>& r) {
        const std::size_t columns = r.size();
        if (!known) sixAreColors = columns == 6 && sixColumnsAreColors(path), known = true;
        info.colors = columns == 9 || (columns == 6 && sixAreColors);
        info.normals = columns == 9 || (columns == 6 && !sixAreColors);
        const std::size_t normalColumn = columns == 9 ? 6 : 3;
        glm::vec4 c(1.0f);
        if (info.colors) {
          for (int k = 0; k < 3; ++k)
            c[k] = std::isfinite(r[3 + std::size_t(k)])
                       ? float(std::clamp(r[3 + std::size_t(k)] / 255.0, 0.0, 1.0))
                       : 0.0f;
          c = detail::displayToLinear(c);
        }
        glm::vec3 n(0.0f);
        if (info.normals)
          n = {float(r[normalColumn]), float(r[normalColumn + 1]), float(r[normalColumn + 2])};
        sink.add(glm::dvec3(r[0], r[1], r[2]), info.normals ? &n : nullptr, info.colors ? &c : nullptr);
        return true;
      },
      &fraction);
  sink.flush();
  info.points = sink.count();
  return info;
}

PointFileInfo readDraco(const fs::path& path, const PointBatch& emit) {
  PointCloud whole = detail::loadDracoPoints(path);  // Draco decodes a whole buffer at once
  PointFileInfo info;
  info.format = whole.format;
  info.normals = !whole.normals.empty();
  info.colors = !whole.colors.empty();
  std::size_t done = 0;
  BatchSink sink(path, emit,
                 [&] { return double(done) / double(std::max<std::size_t>(whole.positions.size(), 1)); });
  for (; done < whole.positions.size(); ++done)
    sink.add(whole.positions[done], info.normals ? &whole.normals[done] : nullptr,
             info.colors ? &whole.colors[done] : nullptr);
  sink.flush();
  info.points = sink.count();
  return info;
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

PointFileInfo readPointCloud(const fs::path& path, const PointBatch& batch) {
  checkRegularFile(path);
  const std::string ext = detail::lowerExtension(path);
  PointFileInfo info;
  if (ext == ".xyz")
    info = readXyz(path, batch);
  else if (ext == ".ply")
    info = readPly(path, batch);
  else if (ext == ".drc")
    info = readDraco(path, batch);
  else
    fail(path, "not a point cloud format (.ply, .drc or .xyz)");
  if (info.points == 0) fail(path, "no points");
  return info;
}

PointFileInfo surveyPointFile(const fs::path& path) {
  if (detail::lowerExtension(path) != ".ply")
    return readPointCloud(path, [](const PointCloud&, std::uint64_t, double) {});
  checkRegularFile(path);
  std::string error;
  const std::optional<PlyHeader> header = parsePlyHeader(readHead(path, kMaxHeaderBytes + kReadChunk), error);
  if (!header) fail(path, error);
  for (const PlyElement& e : header->elements) {
    if (e.name != "vertex") continue;
    PointFileInfo info = plyPointInfo(*header, e);
    info.points = e.count;
    return info;
  }
  fail(path, "the PLY file has no vertex element");
}

PointCloud loadPointCloud(const fs::path& path) {
  PointCloud cloud;
  const PointFileInfo info = readPointCloud(path, [&](const PointCloud& batch, std::uint64_t, double) {
    cloud.positions.insert(cloud.positions.end(), batch.positions.begin(), batch.positions.end());
    cloud.normals.insert(cloud.normals.end(), batch.normals.begin(), batch.normals.end());
    cloud.colors.insert(cloud.colors.end(), batch.colors.begin(), batch.colors.end());
  });
  cloud.format = info.format;
  cloud.missing = info.missing;
  validatePointCloud(cloud, path.string());
  return cloud;
}

}  // namespace svo
