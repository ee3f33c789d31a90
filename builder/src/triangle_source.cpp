// TriangleSource (mesh.hpp): triangles streamed in order for the out-of-core build. Binary little-endian PLY
// (what `svo gen` writes and what scanners export) is read straight from the file, holding only its vertex
// table; assimp loads a whole scene at once, so every other format goes through loadMesh.
//
// No Debian package offers a streaming PLY reader (assimp, and the header-only ones, load everything), so the
// binary layout is decoded here: a header of elements and typed properties, then the records. Anything the
// streaming reader does not cover (ASCII or big-endian files, lists in the vertex element, a face element
// before the vertices) is handed to loadMesh, which reads every PLY assimp can.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include <sys/types.h>

#include <glm/common.hpp>
#include <glm/gtc/type_precision.hpp>

#include "file_extension.hpp"
#include "hasher.hpp"
#include "ply_format.hpp"
#include "svo/builder/mesh.hpp"

namespace svo {

namespace detail {  // mesh_io.cpp
glm::vec4 displayToLinear(glm::vec4 c);
}  // namespace detail

namespace {

namespace fs = std::filesystem;

// Triangles handed over per call of the batch callback: ~2.5 MB of SourceTriangles.
constexpr std::size_t kBatchTriangles = std::size_t(1) << 14;
// Bytes read from the file at a time.
constexpr std::size_t kReadChunk = std::size_t(4) << 20;
// A streamed PLY notes where its faces are every this many triangles, so that a read of a range starts at
// most this many triangles before it (a rank's share of the input in a distributed build); ~24 bytes each.
constexpr std::uint64_t kCheckpointTriangles = std::uint64_t(1) << 16;

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  throw std::runtime_error(path.string() + ": " + what);
}

// What every source reports besides its triangles.
struct Summary {
  std::string format;
  std::uint64_t triangles = 0;
  std::size_t dropped = 0;
  glm::dvec3 lower{std::numeric_limits<double>::max()}, upper{-std::numeric_limits<double>::max()};
  bool color = false, vertexColors = false, uvs = false;
  std::vector<Material> materials;
  std::vector<std::shared_ptr<const TextureImage>> textures;
  std::uint64_t fingerprint = 0;
  std::size_t residentBytes = 0;
};

template <class T>
std::size_t bytesOf(const std::vector<T>& v) {
  return v.capacity() * sizeof(T);
}

class SummarizedSource : public TriangleSource {
 public:
  std::uint64_t triangleCount() const override { return summary_.triangles; }
  std::size_t droppedDegenerate() const override { return summary_.dropped; }
  const std::string& format() const override { return summary_.format; }
  glm::dvec3 lower() const override { return summary_.lower; }
  glm::dvec3 upper() const override { return summary_.upper; }
  bool hasColor() const override { return summary_.color; }
  bool hasVertexColors() const override { return summary_.vertexColors; }
  bool hasUvs() const override { return summary_.uvs; }
  const std::vector<Material>& materials() const override { return summary_.materials; }
  const std::vector<std::shared_ptr<const TextureImage>>& textures() const override {
    return summary_.textures;
  }
  std::uint64_t fingerprint() const override { return summary_.fingerprint; }
  std::size_t residentBytes() const override { return summary_.residentBytes; }

 protected:
  Summary summary_;
};

// ----- a mesh in memory ------------------------------------------------------------------------------------

class MeshSource : public SummarizedSource {
 public:
  MeshSource(const Mesh& mesh, std::unique_ptr<Mesh> owned = nullptr, std::string format = "",
             std::size_t dropped = 0)
      : owned_(std::move(owned)), mesh_(mesh) {
    summary_.format = format.empty() ? "mesh in memory" : std::move(format);
    summary_.triangles = mesh.triangles.size();
    summary_.dropped = dropped;
    for (const glm::uvec3& t : mesh.triangles)
      for (int k = 0; k < 3; ++k)
        summary_.lower = glm::min(summary_.lower, mesh.positions[t[k]]),
        summary_.upper = glm::max(summary_.upper, mesh.positions[t[k]]);
    summary_.color = mesh.hasColor();
    summary_.vertexColors = !mesh.colors.empty();
    summary_.uvs = !mesh.uvs.empty();
    summary_.materials = mesh.materials;
    summary_.textures = mesh.textures;
    Hasher f;
    const auto add = [&f](const auto& v) { f.add(v.data(), v.size()); };
    add(mesh.positions), add(mesh.triangles), add(mesh.colors), add(mesh.uvs), add(mesh.triangleMaterials),
        add(mesh.normals);
    summary_.fingerprint = f.digest();
    summary_.residentBytes = bytesOf(mesh.positions) + bytesOf(mesh.colors) + bytesOf(mesh.uvs) +
                             bytesOf(mesh.triangles) + bytesOf(mesh.triangleMaterials) +
                             mesh.triangles.size() * sizeof(Corners);  // made by the first read
  }

  void readRange(std::uint64_t first, std::uint64_t last, const Batch& batch) const override {
    last = std::min<std::uint64_t>(last, mesh_.triangles.size());
    // On the first read only: an in-core build, which reads the mesh itself, never pays for them.
    std::call_once(cornersMade_, [&] { corners_ = cornerNormals(mesh_); });
    std::vector<SourceTriangle> out;
    out.reserve(std::size_t(std::min<std::uint64_t>(kBatchTriangles, last - std::min(first, last))));
    for (std::size_t i = std::size_t(first); i < last; ++i) {
      const glm::uvec3 t = mesh_.triangles[i];
      SourceTriangle s;
      for (int k = 0; k < 3; ++k) {
        s.positions[k] = mesh_.positions[t[k]];
        if (!mesh_.colors.empty()) s.colors[k] = mesh_.colors[t[k]];
        if (!mesh_.uvs.empty()) s.uvs[k] = mesh_.uvs[t[k]];
      }
      s.normals = corners_[i];
      s.material = mesh_.triangleMaterials.empty() ? 0 : mesh_.triangleMaterials[i];
      out.push_back(s);
      if (out.size() == kBatchTriangles) batch(out), out.clear();
    }
    if (!out.empty()) batch(out);
  }
  const Mesh* wholeMesh() const override { return &mesh_; }

 private:
  std::unique_ptr<Mesh> owned_;
  const Mesh& mesh_;
  using Corners = std::array<glm::vec3, 3>;
  mutable std::once_flag cornersMade_;
  mutable std::vector<Corners> corners_;  // shading normals by triangle
};

// ----- binary little-endian PLY ----------------------------------------------------------------------------

using PlyType = detail::ply::Type;
using PlyProperty = detail::ply::Property;
using PlyElement = detail::ply::Element;
using detail::ply::sizeOf;
using detail::ply::valueAt;

// The layout the streaming reader handles: vertices (fixed-size records with x, y, z) before the faces (one
// index list, other properties fixed-size), elements between them fixed-size. nullopt for anything else.
struct PlyLayout {
  std::uint64_t headerBytes = 0, vertexOffset = 0, faceOffset = 0;
  PlyElement vertex, face;
};

std::optional<PlyLayout> parsePlyHeader(std::FILE* file, std::string& header) {
  header.clear();
  for (int c; header.size() < detail::ply::kMaxHeaderBytes && (c = std::fgetc(file)) != EOF;) {
    header += char(c);
    if (header.size() >= 11 && header.compare(header.size() - 11, 11, "end_header\n") == 0) break;
  }
  if (header.rfind("ply\n", 0) != 0 || header.size() < 11 ||
      header.compare(header.size() - 11, 11, "end_header\n") != 0)
    return std::nullopt;
  std::istringstream lines(header);
  std::vector<PlyElement> elements;
  bool binaryLittleEndian = false;
  for (std::string line; std::getline(lines, line);) {
    std::istringstream words(line);
    std::string word;
    words >> word;
    if (word == "format") {
      std::string kind;
      words >> kind;
      binaryLittleEndian = kind == "binary_little_endian";
    } else if (word == "element") {
      PlyElement e;
      if (!(words >> e.name >> e.count)) return std::nullopt;
      elements.push_back(e);
    } else if (word == "property") {
      if (elements.empty()) return std::nullopt;
      std::string ignored;
      const std::optional<PlyProperty> p = detail::ply::parseProperty(words, ignored);
      if (!p) return std::nullopt;
      elements.back().properties.push_back(*p);
    }
  }
  if (!binaryLittleEndian) return std::nullopt;
  PlyLayout layout;
  layout.headerBytes = header.size();
  std::uint64_t offset = header.size();
  bool vertexSeen = false, faceSeen = false;
  for (const PlyElement& e : elements) {
    if (e.name == "vertex" && !vertexSeen && !e.hasList()) {
      layout.vertex = e, layout.vertexOffset = offset, vertexSeen = true;
    } else if (e.name == "face" && vertexSeen && !faceSeen) {
      if (std::count_if(e.properties.begin(), e.properties.end(),
                        [](const PlyProperty& p) {
                          return p.list && (p.name == "vertex_indices" || p.name == "vertex_index");
                        }) != 1 ||
          std::count_if(e.properties.begin(), e.properties.end(),
                        [](const PlyProperty& p) { return p.list; }) != 1)
        return std::nullopt;
      layout.face = e, layout.faceOffset = offset, faceSeen = true;
      break;  // what follows the faces is not read
    } else if (e.hasList()) {
      return std::nullopt;
    }
    offset += e.count * e.fixedBytes();
  }
  if (!vertexSeen || !faceSeen) return std::nullopt;
  return layout;
}

// Sequential reads through a chunk buffer; `need` makes `n` bytes available at `data()`.
class ChunkReader {
 public:
  // `offset`: where in the file `file` stands.
  ChunkReader(std::FILE* file, Hasher* fingerprint, std::uint64_t offset)
      : file_(file), fingerprint_(fingerprint), bufferOffset_(offset) {
    buffer_.resize(kReadChunk);
  }
  bool need(std::size_t n) {
    if (end_ - pos_ >= n) return true;
    std::memmove(buffer_.data(), buffer_.data() + pos_, end_ - pos_);
    bufferOffset_ += pos_;
    end_ -= pos_, pos_ = 0;
    if (buffer_.size() < n) buffer_.resize(n);
    while (end_ < n) {
      const std::size_t got = std::fread(buffer_.data() + end_, 1, buffer_.size() - end_, file_);
      if (got == 0) return false;
      if (fingerprint_) fingerprint_->add(buffer_.data() + end_, got);
      end_ += got;
    }
    return true;
  }
  const char* data() const { return buffer_.data() + pos_; }
  void skip(std::size_t n) { pos_ += n; }
  std::uint64_t offset() const { return bufferOffset_ + pos_; }  // the file offset of data()

 private:
  std::FILE* file_;
  Hasher* fingerprint_;
  std::uint64_t bufferOffset_;  // the file offset of buffer_[0]
  std::vector<char> buffer_;
  std::size_t pos_ = 0, end_ = 0;
};

struct FileCloser {
  void operator()(std::FILE* f) const { std::fclose(f); }
};
using File = std::unique_ptr<std::FILE, FileCloser>;

class PlySource : public SummarizedSource {
 public:
  PlySource(const fs::path& path, PlyLayout layout, File file, const std::string& header)
      : path_(path), layout_(std::move(layout)) {
    summary_.format = "PLY (binary, streamed)";
    Hasher fingerprint;
    fingerprint.add(header.data(), header.size());
    ChunkReader reader(file.get(), &fingerprint, header.size());
    readVertices(reader);
    // Everything but the vertex table is read again per pass; this first pass counts, bounds and hashes, and
    // notes where each kCheckpointTriangles-th triangle's face begins.
    checkpoints_.push_back({0, reader.offset(), 0});
    const auto atFace = [&](std::uint64_t face) {
      if (summary_.triangles >= checkpoints_.back().ordinal + kCheckpointTriangles)
        checkpoints_.push_back({face, reader.offset(), summary_.triangles});
    };
    // Without the file's normals, the first pass also sums the vertex normals, which every later pass gives
    // the triangles' corners.
    fileNormals_ = !vertexNormals_.empty();
    VertexNormalSums normalSums(fileNormals_ ? 0 : vertexCount());
    summary_.dropped = scanFaces(reader, 0, atFace, [&](const SourceTriangle& t, const glm::uvec3& corners) {
      ++summary_.triangles;
      if (!fileNormals_) normalSums.add(corners, t.positions);
      for (int k = 0; k < 3; ++k) {
        summary_.lower = glm::min(summary_.lower, t.positions[k]);
        summary_.upper = glm::max(summary_.upper, t.positions[k]);
        summary_.color |= t.colors[k] != glm::vec4(1.0f);
      }
      return true;
    });
    while (reader.need(1)) reader.skip(1);  // the fingerprint covers the whole file
    summary_.fingerprint = fingerprint.digest();
    if (!fileNormals_) vertexNormals_ = normalSums.normals();
    summary_.residentBytes = bytesOf(floatPositions_) + bytesOf(doublePositions_) + bytesOf(colors_) +
                             bytesOf(vertexNormals_) + bytesOf(checkpoints_);
    if (summary_.triangles == 0)
      fail(path_, "mesh has no triangles" +
                      (summary_.dropped ? " (all " + std::to_string(summary_.dropped) + " are degenerate)"
                                        : std::string()));
  }

  void readRange(std::uint64_t first, std::uint64_t last, const Batch& batch) const override {
    last = std::min(last, summary_.triangles);
    if (first >= last) return;
    // The last face noted at or before the range's first triangle.
    const Checkpoint& from = *std::prev(
        std::upper_bound(checkpoints_.begin(), checkpoints_.end(), first,
                         [](std::uint64_t ordinal, const Checkpoint& c) { return ordinal < c.ordinal; }));
    File file(std::fopen(path_.c_str(), "rb"));
    if (!file || fseeko(file.get(), off_t(from.offset), SEEK_SET) != 0)
      fail(path_, "cannot read the file again");
    ChunkReader reader(file.get(), nullptr, from.offset);
    std::vector<SourceTriangle> out;
    out.reserve(std::size_t(std::min<std::uint64_t>(kBatchTriangles, last - first)));
    std::uint64_t ordinal = from.ordinal;
    scanFaces(
        reader, from.face, [](std::uint64_t) {},
        [&](const SourceTriangle& t, const glm::uvec3&) {
          if (ordinal++ < first) return true;
          out.push_back(t);
          if (out.size() == kBatchTriangles) batch(out), out.clear();
          return ordinal < last;
        });
    if (!out.empty()) batch(out);
  }

 private:
  // Where face `face`, whose first triangle is the `ordinal`-th, begins in the file.
  struct Checkpoint {
    std::uint64_t face = 0, offset = 0, ordinal = 0;
  };

  struct Channel {
    std::size_t offset = 0;
    PlyType type = PlyType::UInt8;
  };

  void readVertices(ChunkReader& reader) {
    skipElements(reader, layout_.vertexOffset - layout_.headerBytes, "vertices");
    const PlyElement& v = layout_.vertex;
    std::optional<Channel> xyz[3], nxyz[3], rgba[4];
    std::size_t offset = 0;
    for (const PlyProperty& p : v.properties) {
      static const char* const kPosition[] = {"x", "y", "z"};
      static const char* const kNormal[] = {"nx", "ny", "nz"};
      static const char* const kColor[][2] = {
          {"red", "diffuse_red"}, {"green", "diffuse_green"}, {"blue", "diffuse_blue"}, {"alpha", "alpha"}};
      for (int k = 0; k < 3; ++k)
        if (p.name == kPosition[k]) xyz[k] = Channel{offset, p.type};
      for (int k = 0; k < 3; ++k)
        if (p.name == kNormal[k]) nxyz[k] = Channel{offset, p.type};
      for (int k = 0; k < 4; ++k)
        if ((p.name == kColor[k][0] || p.name == kColor[k][1]) && p.type == PlyType::UInt8)
          rgba[k] = Channel{offset, p.type};
      offset += sizeOf(p.type);
    }
    if (!xyz[0] || !xyz[1] || !xyz[2]) fail(path_, "the vertex element has no x, y and z");
    const bool floats = xyz[0]->type == PlyType::Float32 && xyz[1]->type == PlyType::Float32 &&
                        xyz[2]->type == PlyType::Float32;
    summary_.vertexColors = rgba[0] && rgba[1] && rgba[2];
    const bool fileNormals = nxyz[0] && nxyz[1] && nxyz[2];
    // Each 8-bit value decoded once, as loadMesh decodes it (assimp divides by 255 in float); the channels
    // decode independently, so one table serves them all.
    for (int v = 0; v < 256; ++v)
      linear_[std::size_t(v)] = detail::displayToLinear(glm::vec4(float(v) / 255.0f));
    const std::size_t record = v.fixedBytes();
    if (v.count > 0xffffffffull) fail(path_, "more than 2^32 vertices");
    // Room for what the file can hold, not what a damaged header claims.
    std::error_code ec;
    const std::uint64_t fileBytes = fs::file_size(path_, ec);
    const std::size_t expected = std::size_t(std::min<std::uint64_t>(
        v.count, ec || record == 0 ? 0 : (fileBytes - std::min(fileBytes, layout_.vertexOffset)) / record));
    if (floats)
      floatPositions_.reserve(expected);
    else
      doublePositions_.reserve(expected);
    if (summary_.vertexColors) colors_.reserve(expected);
    if (fileNormals) vertexNormals_.reserve(expected);
    for (std::uint64_t i = 0; i < v.count; ++i) {
      if (!reader.need(record))
        fail(path_,
             "truncated: vertex " + std::to_string(i) + " of " + std::to_string(v.count) + " is missing");
      const char* r = reader.data();
      const glm::dvec3 p(valueAt(r + xyz[0]->offset, xyz[0]->type), valueAt(r + xyz[1]->offset, xyz[1]->type),
                         valueAt(r + xyz[2]->offset, xyz[2]->type));
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
        fail(path_, "vertex " + std::to_string(i) + " has a non-finite coordinate");
      if (floats)
        floatPositions_.emplace_back(p);
      else
        doublePositions_.push_back(p);
      // As assimp reads them: floats, taken as they are.
      if (fileNormals)
        vertexNormals_.emplace_back(valueAt(r + nxyz[0]->offset, nxyz[0]->type),
                                    valueAt(r + nxyz[1]->offset, nxyz[1]->type),
                                    valueAt(r + nxyz[2]->offset, nxyz[2]->type));
      if (summary_.vertexColors) {
        glm::u8vec4 c(255);
        for (int k = 0; k < 4; ++k)
          if (rgba[k]) c[k] = std::uint8_t(r[rgba[k]->offset]);
        colors_.push_back(c);
      }
      reader.skip(record);
    }
    skipElements(reader, layout_.faceOffset - layout_.vertexOffset - v.count * record, "faces");
  }

  // Skips the records of elements the reader does not use.
  void skipElements(ChunkReader& reader, std::uint64_t bytes, const char* before) const {
    while (bytes > 0) {
      const std::size_t n = std::size_t(std::min<std::uint64_t>(bytes, kReadChunk));
      if (!reader.need(n)) fail(path_, std::string("truncated before the ") + before);
      reader.skip(n), bytes -= n;
    }
  }

  glm::dvec3 position(std::uint32_t i) const {
    return floatPositions_.empty() ? doublePositions_[i] : glm::dvec3(floatPositions_[i]);
  }
  std::size_t vertexCount() const { return floatPositions_.size() + doublePositions_.size(); }

  // Linear colors as loadMesh decodes a PLY's 8-bit ones, from the table (every pass reads every corner).
  glm::vec4 color(std::uint32_t i) const {
    const glm::u8vec4 c = colors_[i];
    return {linear_[c.r].r, linear_[c.g].g, linear_[c.b].b, linear_[c.a].a};
  }

  // Visits the non-degenerate triangles of the faces from `firstFace` on, whose records `reader` starts at,
  // in file order (polygons fanned from their first corner), calling `atFace(face)` as each face begins;
  // `visit(triangle, its vertex indices)` stops the scan by returning false. Returns how many degenerate
  // triangles it dropped.
  template <class AtFace, class Visit>
  std::size_t scanFaces(ChunkReader& reader, std::uint64_t firstFace, AtFace&& atFace, Visit&& visit) const {
    std::size_t dropped = 0;
    const PlyElement& f = layout_.face;
    const std::size_t nv = vertexCount();
    std::vector<std::uint32_t> corners;
    for (std::uint64_t face = firstFace; face < f.count; ++face) {
      atFace(face);
      corners.clear();
      for (const PlyProperty& p : f.properties) {
        const auto truncated = [&] {
          fail(path_,
               "truncated: face " + std::to_string(face) + " of " + std::to_string(f.count) + " is missing");
        };
        if (!p.list) {
          if (!reader.need(sizeOf(p.type))) truncated();
          reader.skip(sizeOf(p.type));
          continue;
        }
        if (!reader.need(sizeOf(p.countType))) truncated();
        const double count = valueAt(reader.data(), p.countType);
        reader.skip(sizeOf(p.countType));
        if (count < 0 || count > double(kReadChunk / 8))
          fail(path_,
               "face " + std::to_string(face) + " has " + std::to_string(std::llround(count)) + " corners");
        const std::size_t n = std::size_t(count), bytes = n * sizeOf(p.type);
        if (!reader.need(bytes)) truncated();
        for (std::size_t k = 0; k < n; ++k) {  // the header check left one list: the indices
          const double index = valueAt(reader.data() + k * sizeOf(p.type), p.type);
          if (!(index >= 0 && index < double(nv)))
            fail(path_, "face " + std::to_string(face) + " uses vertex " +
                            std::to_string(std::llround(index)) + ", but there are only " +
                            std::to_string(nv));
          corners.push_back(std::uint32_t(index));
        }
        reader.skip(bytes);
      }
      for (std::size_t k = 2; k < corners.size(); ++k) {  // points and lines carry no surface
        const std::uint32_t a = corners[0], b = corners[k - 1], c = corners[k];
        SourceTriangle t;
        t.positions = {position(a), position(b), position(c)};
        if (a == b || b == c || a == c || isDegenerate(t.positions[0], t.positions[1], t.positions[2])) {
          ++dropped;
          continue;
        }
        if (!colors_.empty()) t.colors = {color(a), color(b), color(c)};
        if (fileNormals_)
          t.normals = {vertexNormals_[a], vertexNormals_[b], vertexNormals_[c]};
        else if (!vertexNormals_.empty())
          t.normals = creasedCorners(t.positions, {vertexNormals_[a], vertexNormals_[b], vertexNormals_[c]});
        if (!visit(t, glm::uvec3(a, b, c))) return dropped;
      }
    }
    return dropped;
  }

  fs::path path_;
  PlyLayout layout_;
  std::vector<Checkpoint> checkpoints_;      // ascending; the first is the first face's
  std::vector<glm::vec3> floatPositions_;    // when x, y, z are floats
  std::vector<glm::dvec3> doublePositions_;  // otherwise
  std::vector<glm::u8vec4> colors_;
  std::vector<glm::vec3> vertexNormals_;  // the file's, else unit sums from the first pass (empty during it)
  bool fileNormals_ = false;
  std::array<glm::vec4, 256> linear_;  // 8-bit value -> linear, per channel (alpha is linear already)
};

}  // namespace

std::unique_ptr<TriangleSource> meshTriangleSource(const Mesh& mesh, std::string name) {
  if (mesh.triangles.empty()) throw std::runtime_error(name + ": mesh has no triangles");
  return std::make_unique<MeshSource>(mesh);
}

std::unique_ptr<TriangleSource> openTriangleSource(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "no such file");
  if (!fs::is_regular_file(path, ec)) fail(path, "not a regular file");
  if (detail::lowerExtension(path) == ".ply") {
    File file(std::fopen(path.c_str(), "rb"));
    if (!file) fail(path, "cannot open");
    std::string header;
    if (std::optional<PlyLayout> layout = parsePlyHeader(file.get(), header))
      return std::make_unique<PlySource>(path, std::move(*layout), std::move(file), header);
  }
  MeshLoadReport report;
  auto mesh = std::make_unique<Mesh>(loadMesh(path, &report));
  const Mesh& view = *mesh;
  return std::make_unique<MeshSource>(view, std::move(mesh), report.format, report.droppedDegenerate);
}

}  // namespace svo
