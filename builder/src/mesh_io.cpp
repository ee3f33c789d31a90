// loadMesh: triangle meshes from files. Draco `.drc` goes through the Draco decoder, everything else through
// assimp (which Debian builds with Draco, so KHR_draco_mesh_compression glTF files load too).
//
// Color spaces: Mesh colors end up linear like the textures. glTF stores vertex and material colors linear;
// the other formats' vertex colors are display values (8-bit sRGB in PLY, OBJ, FBX exports) and are decoded.
// Material colors are taken as stored: exporters write their linear base colors there.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

#include <assimp/importerdesc.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <draco/compression/decode.h>
#include <draco/mesh/mesh.h>
#include <spdlog/spdlog.h>
#include <assimp/Importer.hpp>
#include <glm/common.hpp>

#include "file_extension.hpp"
#include "svo/builder/mesh.hpp"

namespace svo {

namespace detail {
// Defined in texture.cpp.
std::shared_ptr<const TextureImage> decodeTexture(const std::string& name, const void* data,
                                                  std::size_t size);
std::shared_ptr<const TextureImage> textureFromSrgb8(int width, int height, const std::uint8_t* rgba);

// 8-bit display colors (PLY, OBJ, FBX vertex colors) to linear; triangle_source.cpp decodes PLY with it too.
float srgbToLinear(float c) {
  c = std::clamp(c, 0.0f, 1.0f);
  return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}

glm::vec4 displayToLinear(glm::vec4 c) {
  return glm::vec4(srgbToLinear(c.r), srgbToLinear(c.g), srgbToLinear(c.b), std::clamp(c.a, 0.0f, 1.0f));
}

}  // namespace detail

namespace {

using detail::displayToLinear;
using detail::lowerExtension;
namespace fs = std::filesystem;

// assimp's words for a file that parsed but holds nothing: those are empty meshes, not unknown formats.
constexpr const char* kAssimpEmptyMessages[] = {"too small", "No output meshes", "no meshes",
                                                "No meshes", "is empty",         "has no faces"};
// The diffuse color assimp's OBJ reader gives a material that no .mtl defines (a `usemtl` whose library is
// missing): not the file's color, so white like any uncolored mesh.
constexpr float kAssimpObjDefaultDiffuse = 0.6f;

// How much of a glTF file is searched for the Draco extension's name (the JSON part comes first).
constexpr std::size_t kGltfJsonScanBytes = 16u << 20;

[[noreturn]] void fail(const fs::path& path, const std::string& what) {
  std::string line = path.string() + ": " + what;
  std::replace(line.begin(), line.end(), '\n', ' ');
  std::replace(line.begin(), line.end(), '\r', ' ');
  throw std::runtime_error(line);
}

glm::vec4 clamp01(glm::vec4 c) {
  return glm::clamp(c, glm::vec4(0.0f), glm::vec4(1.0f));
}

bool gltfUsesDraco(const fs::path& path) {
  std::error_code ec;
  const std::uintmax_t size = fs::file_size(path, ec);
  if (ec) return false;
  std::ifstream in(path, std::ios::binary);
  std::string head(static_cast<std::size_t>(std::min<std::uintmax_t>(size, kGltfJsonScanBytes)), '\0');
  in.read(head.data(), static_cast<std::streamsize>(head.size()));
  head.resize(static_cast<std::size_t>(in.gcount()));
  return head.find("KHR_draco_mesh_compression") != std::string::npos;
}

// glTF URIs may be percent-encoded ("my%20texture.png").
std::string percentDecode(const std::string& s) {
  std::string out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
      out += static_cast<char>(std::stoi(s.substr(i + 1, 2), nullptr, 16));
      i += 2;
    } else {
      out += s[i];
    }
  }
  return out;
}

// ---- Draco `.drc`
// -------------------------------------------------------------------------------------------

Mesh loadDraco(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (!in.good() && !in.eof()) fail(path, "cannot read file");
  draco::DecoderBuffer buffer;
  buffer.Init(bytes.data(), bytes.size());
  auto type = draco::Decoder::GetEncodedGeometryType(&buffer);
  if (!type.ok())
    fail(path, "unsupported or unreadable mesh format (Draco: " + type.status().error_msg_string() + ")");
  if (type.value() != draco::TRIANGULAR_MESH) fail(path, "mesh has no triangles (a Draco point cloud)");
  draco::Decoder decoder;
  auto decoded = decoder.DecodeMeshFromBuffer(&buffer);
  if (!decoded.ok()) {
    fail(path, "unsupported or unreadable mesh format (Draco: " + decoded.status().error_msg_string() + ")");
  }
  const draco::Mesh& dm = *decoded.value();

  Mesh mesh;
  const draco::PointAttribute* pos = dm.GetNamedAttribute(draco::GeometryAttribute::POSITION);
  if (!pos || pos->num_components() < 3) fail(path, "Draco mesh has no 3D positions");
  const std::size_t np = dm.num_points();
  mesh.positions.resize(np);
  for (draco::PointIndex p(0); p < static_cast<std::uint32_t>(np); ++p) {
    double v[3] = {0, 0, 0};
    if (!pos->ConvertValue<double>(pos->mapped_index(p), 3, v)) fail(path, "Draco position unreadable");
    mesh.positions[p.value()] = glm::dvec3(v[0], v[1], v[2]);
  }

  // Vertex colors; integer ones that were not flagged normalized still mean 0..max.
  if (const draco::PointAttribute* col = dm.GetNamedAttribute(draco::GeometryAttribute::COLOR);
      col && col->num_components() >= 3) {
    float scale = 1.0f;
    if (!col->normalized()) {
      switch (col->data_type()) {
        case draco::DT_UINT8:
          scale = 1.0f / 255.0f;
          break;
        case draco::DT_UINT16:
          scale = 1.0f / 65535.0f;
          break;
        case draco::DT_UINT32:
          scale = 1.0f / 4294967295.0f;
          break;
        default:
          break;
      }
    }
    mesh.colors.resize(np);
    for (draco::PointIndex p(0); p < static_cast<std::uint32_t>(np); ++p) {
      float c[4] = {1, 1, 1, 1};
      col->ConvertValue<float>(col->mapped_index(p),
                               static_cast<int8_t>(std::min<int>(col->num_components(), 4)), c);
      glm::vec4 rgba(c[0] * scale, c[1] * scale, c[2] * scale,
                     col->num_components() >= 4 ? c[3] * scale : 1.0f);
      mesh.colors[p.value()] = displayToLinear(rgba);
    }
  }

  if (const draco::PointAttribute* normal = dm.GetNamedAttribute(draco::GeometryAttribute::NORMAL);
      normal && normal->num_components() == 3) {
    mesh.normals.resize(np);
    for (draco::PointIndex p(0); p < static_cast<std::uint32_t>(np); ++p) {
      float n[3] = {0, 0, 0};
      if (!normal->ConvertValue<float>(normal->mapped_index(p), 3, n)) fail(path, "Draco normal unreadable");
      mesh.normals[p.value()] = glm::vec3(n[0], n[1], n[2]);
    }
  }

  mesh.triangles.reserve(dm.num_faces());
  for (draco::FaceIndex f(0); f < dm.num_faces(); ++f) {
    const draco::Mesh::Face& face = dm.face(f);
    mesh.triangles.emplace_back(face[0].value(), face[1].value(), face[2].value());
  }
  return mesh;
}

// ---- assimp
// -------------------------------------------------------------------------------------------------

class TextureResolver {
 public:
  TextureResolver(const aiScene& scene, const fs::path& meshPath, Mesh& mesh)
      : scene_(scene), meshPath_(meshPath), dir_(meshPath.parent_path()), mesh_(mesh) {}

  // Index into mesh.textures, or -1 when the texture cannot be had (warned, the base color still applies).
  int resolve(const std::string& ref) {
    if (auto it = cache_.find(ref); it != cache_.end()) return it->second;
    int index = -1;
    try {
      if (auto texture = load(ref)) {
        index = static_cast<int>(mesh_.textures.size());
        mesh_.textures.push_back(std::move(texture));
      }
    } catch (const std::exception& e) {
      spdlog::warn("{}: texture '{}' skipped: {}", meshPath_.string(), ref, e.what());
    }
    cache_[ref] = index;
    return index;
  }

 private:
  std::shared_ptr<const TextureImage> load(const std::string& ref) {
    if (const aiTexture* tex = scene_.GetEmbeddedTexture(ref.c_str())) return embedded(*tex, ref);
    std::string rel = percentDecode(ref);
    std::replace(rel.begin(), rel.end(), '\\', '/');  // paths written on Windows
    if (rel.rfind("file://", 0) == 0) rel = rel.substr(7);
    std::error_code ec;
    for (const fs::path& candidate : {dir_ / rel, fs::path(rel), dir_ / fs::path(rel).filename()}) {
      if (fs::is_regular_file(candidate, ec)) return loadTexture(candidate);
    }
    spdlog::warn("{}: texture '{}' not found; using the material's base color", meshPath_.string(), ref);
    return nullptr;
  }

  std::shared_ptr<const TextureImage> embedded(const aiTexture& tex, const std::string& ref) {
    if (tex.mHeight == 0) {  // compressed file bytes; the hint is the format's extension ("png", "jpg")
      std::string hint(tex.achFormatHint, strnlen(tex.achFormatHint, sizeof(tex.achFormatHint)));
      const std::string name = meshPath_.string() + ":" + ref + (hint.empty() ? "" : "." + hint);
      return detail::decodeTexture(name, tex.pcData, tex.mWidth);
    }
    std::vector<std::uint8_t> rgba(static_cast<std::size_t>(tex.mWidth) * tex.mHeight * 4);
    for (std::size_t i = 0; i < static_cast<std::size_t>(tex.mWidth) * tex.mHeight; ++i) {
      const aiTexel& t = tex.pcData[i];
      rgba[4 * i + 0] = t.r;
      rgba[4 * i + 1] = t.g;
      rgba[4 * i + 2] = t.b;
      rgba[4 * i + 3] = t.a;
    }
    return detail::textureFromSrgb8(static_cast<int>(tex.mWidth), static_cast<int>(tex.mHeight), rgba.data());
  }

  const aiScene& scene_;
  fs::path meshPath_, dir_;
  Mesh& mesh_;
  std::map<std::string, int> cache_;
};

std::string formatName(const Assimp::Importer& importer, const std::string& ext) {
  static const std::map<std::string, std::string> kNames = {
      {".obj", "OBJ"},  {".ply", "PLY"},     {".stl", "STL"}, {".gltf", "glTF"},
      {".glb", "glTF"}, {".dae", "COLLADA"}, {".fbx", "FBX"},
  };
  if (auto it = kNames.find(ext); it != kNames.end()) return it->second;
  if (const std::size_t i = importer.GetImporterIndex(ext.c_str()); i != ~std::size_t{0}) {
    return importer.GetImporterInfo(i)->mName;
  }
  return "assimp";
}

Material convertMaterial(const aiMaterial& m, bool obj, TextureResolver& textures) {
  Material out;
  aiString name;
  // Importers give colorless files a gray "DefaultMaterial"; such a file has no color, so white.
  if (m.Get(AI_MATKEY_NAME, name) == AI_SUCCESS && std::strcmp(name.C_Str(), AI_DEFAULT_MATERIAL_NAME) == 0 &&
      m.GetTextureCount(aiTextureType_DIFFUSE) == 0 && m.GetTextureCount(aiTextureType_BASE_COLOR) == 0) {
    return out;
  }
  aiColor4D color;
  if (m.Get(AI_MATKEY_BASE_COLOR, color) == AI_SUCCESS) {
    out.baseColor = clamp01(glm::vec4(color.r, color.g, color.b, color.a));
  } else if (m.Get(AI_MATKEY_COLOR_DIFFUSE, color) == AI_SUCCESS) {
    float opacity = 1.0f;
    m.Get(AI_MATKEY_OPACITY, opacity);
    const bool objDefault = obj && color.r == kAssimpObjDefaultDiffuse &&
                            color.g == kAssimpObjDefaultDiffuse && color.b == kAssimpObjDefaultDiffuse;
    if (!objDefault) out.baseColor = clamp01(glm::vec4(color.r, color.g, color.b, opacity));
  }
  for (aiTextureType type : {aiTextureType_BASE_COLOR, aiTextureType_DIFFUSE}) {
    aiString ref;
    if (m.GetTextureCount(type) > 0 && m.GetTexture(type, 0, &ref) == AI_SUCCESS && ref.length > 0) {
      out.texture = textures.resolve(ref.C_Str());
      if (out.texture >= 0) break;
    }
  }
  return out;
}

Mesh loadAssimp(const fs::path& path, std::string& format) {
  Assimp::Importer importer;
  // Points and lines carry no surface: leave them out rather than failing on them.
  importer.SetPropertyInteger(AI_CONFIG_PP_SBP_REMOVE, aiPrimitiveType_POINT | aiPrimitiveType_LINE);
  const unsigned flags = aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                         aiProcess_PreTransformVertices | aiProcess_SortByPType;
  const aiScene* scene = nullptr;
  try {
    scene = importer.ReadFile(path.string(), flags);
  } catch (const std::exception& e) {
    fail(path, std::string("unsupported or unreadable mesh format (") + e.what() + ")");
  }
  if (!scene) {
    const std::string why = importer.GetErrorString();
    std::error_code ec;
    const bool emptyFile = fs::file_size(path, ec) == 0 && !ec;
    const bool emptyScene = std::any_of(std::begin(kAssimpEmptyMessages), std::end(kAssimpEmptyMessages),
                                        [&](const char* m) { return why.find(m) != std::string::npos; });
    if (emptyFile || emptyScene) fail(path, "mesh has no triangles");
    fail(path, "unsupported or unreadable mesh format (" + why + ")");
  }
  if (!scene->HasMeshes()) fail(path, "mesh has no triangles");

  const std::string ext = lowerExtension(path);
  const bool gltf = ext == ".gltf" || ext == ".glb";
  const bool obj = ext == ".obj";
  format = formatName(importer, ext);
  if (gltf && gltfUsesDraco(path)) format += " (Draco-compressed)";

  Mesh mesh;
  TextureResolver textures(*scene, path, mesh);
  mesh.materials.reserve(scene->mNumMaterials);
  for (unsigned i = 0; i < scene->mNumMaterials; ++i)
    mesh.materials.push_back(convertMaterial(*scene->mMaterials[i], obj, textures));
  const bool anyTexture = std::any_of(mesh.materials.begin(), mesh.materials.end(),
                                      [](const Material& m) { return m.texture >= 0; });
  bool anyColors = false, allNormals = true;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    anyColors |= scene->mMeshes[i]->HasVertexColors(0);
    allNormals &= scene->mMeshes[i]->HasNormals();  // a part without them: every part's are derived
  }

  std::size_t vertexCount = 0, faceCount = 0;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    vertexCount += scene->mMeshes[i]->mNumVertices;
    faceCount += scene->mMeshes[i]->mNumFaces;
  }
  mesh.positions.reserve(vertexCount);
  mesh.triangles.reserve(faceCount);
  if (anyColors) mesh.colors.reserve(vertexCount);
  if (allNormals) mesh.normals.reserve(vertexCount);
  if (anyTexture) mesh.uvs.reserve(vertexCount);
  const bool perTriangleMaterial = scene->mNumMaterials > 1;
  if (perTriangleMaterial) mesh.triangleMaterials.reserve(faceCount);

  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    const aiMesh& am = *scene->mMeshes[i];
    const std::size_t base = mesh.positions.size();
    if (base + am.mNumVertices > 0xffffffffull) fail(path, "more than 2^32 vertices");
    for (unsigned v = 0; v < am.mNumVertices; ++v) {
      const aiVector3D& p = am.mVertices[v];
      mesh.positions.emplace_back(p.x, p.y, p.z);
      if (allNormals) mesh.normals.emplace_back(am.mNormals[v].x, am.mNormals[v].y, am.mNormals[v].z);
      if (anyColors) {
        if (am.HasVertexColors(0)) {
          const aiColor4D& c = am.mColors[0][v];
          const glm::vec4 rgba(c.r, c.g, c.b, c.a);
          mesh.colors.push_back(gltf ? clamp01(rgba) : displayToLinear(rgba));
        } else {
          mesh.colors.emplace_back(1.0f);
        }
      }
      if (anyTexture) {
        mesh.uvs.push_back(am.HasTextureCoords(0)
                               ? glm::vec2(am.mTextureCoords[0][v].x, am.mTextureCoords[0][v].y)
                               : glm::vec2(0.0f));
      }
    }
    for (unsigned f = 0; f < am.mNumFaces; ++f) {
      const aiFace& face = am.mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines that survived
      mesh.triangles.emplace_back(base + face.mIndices[0], base + face.mIndices[1], base + face.mIndices[2]);
      if (perTriangleMaterial) mesh.triangleMaterials.push_back(am.mMaterialIndex);
    }
  }
  return mesh;
}

}  // namespace

Mesh loadMesh(const std::filesystem::path& path, MeshLoadReport* report) {
  std::error_code ec;
  if (!fs::exists(path, ec)) fail(path, "no such file");
  if (!fs::is_regular_file(path, ec)) fail(path, "not a regular file");

  std::string format;
  Mesh mesh;
  if (lowerExtension(path) == ".drc") {
    mesh = loadDraco(path);
    format = "Draco";
  } else {
    mesh = loadAssimp(path, format);
  }
  if (mesh.triangles.empty()) fail(path, "mesh has no triangles");
  const std::size_t dropped = validateMesh(mesh, path.string());
  if (mesh.triangles.empty())
    fail(path, "mesh has no triangles (all " + std::to_string(dropped) + " are degenerate)");
  if (report) {
    report->droppedDegenerate = dropped;
    report->format = format;
  }
  return mesh;
}

}  // namespace svo
