// Mesh ingest: every format read from a small file whose content the test wrote itself (or from Debian's
// assimp-testmodels), compared with what was written; textures compared with hand-computed averages.
#include <array>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <map>
#include <set>
#include <span>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include <OpenImageIO/imageio.h>
#include <draco/compression/encode.h>
#include <draco/mesh/triangle_soup_mesh_builder.h>
#include <gtest/gtest.h>
#include <glm/geometric.hpp>
#include <nlohmann/json.hpp>

#include "reference.hpp"
#include "svo/builder/gen.hpp"
#include "svo/builder/mesh.hpp"

namespace fs = std::filesystem;

namespace {

using svotest::errorOf;
using svotest::srgbToLinearRef;
using svotest::TempDir;

struct Box {
  glm::dvec3 lo{1e300}, hi{-1e300};
};
Box boundsOf(const svo::Mesh& m) {
  Box b;
  for (const auto& p : m.positions) {
    b.lo = glm::min(b.lo, p);
    b.hi = glm::max(b.hi, p);
  }
  return b;
}
double surfaceArea(const svo::Mesh& m) {
  double a = 0;
  for (const auto& t : m.triangles) {
    a += 0.5 *
         glm::length(glm::cross(m.positions[t.y] - m.positions[t.x], m.positions[t.z] - m.positions[t.x]));
  }
  return a;
}

void expectVec4Near(glm::vec4 got, glm::vec4 want, float tol, const std::string& what) {
  for (int k = 0; k < 4; ++k) EXPECT_NEAR(got[k], want[k], tol) << what << " component " << k;
}

// A 2x2 checker written as an 8-bit sRGB PNG: rows top to bottom are (red, green), (blue, white).
void writeChecker(const fs::path& png) {
  const unsigned char px[2][2][3] = {{{255, 0, 0}, {0, 255, 0}}, {{0, 0, 255}, {255, 255, 255}}};
  auto out = OIIO::ImageOutput::create(png.string());
  ASSERT_TRUE(out);
  OIIO::ImageSpec spec(2, 2, 3, OIIO::TypeDesc::UINT8);
  ASSERT_TRUE(out->open(png.string(), spec));
  ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px));
  out->close();
}
const glm::vec4 kRed(1, 0, 0, 1), kGreen(0, 1, 0, 1), kBlue(0, 0, 1, 1), kWhite(1, 1, 1, 1);

std::string base64(const std::string& bytes) {
  static const char* abc = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  std::size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const unsigned v =
        (unsigned char)bytes[i] << 16 | (unsigned char)bytes[i + 1] << 8 | (unsigned char)bytes[i + 2];
    out += {abc[v >> 18], abc[(v >> 12) & 63], abc[(v >> 6) & 63], abc[v & 63]};
  }
  if (i + 1 == bytes.size()) {
    const unsigned v = (unsigned char)bytes[i] << 16;
    out += {abc[v >> 18], abc[(v >> 12) & 63], '=', '='};
  } else if (i + 2 == bytes.size()) {
    const unsigned v = (unsigned char)bytes[i] << 16 | (unsigned char)bytes[i + 1] << 8;
    out += {abc[v >> 18], abc[(v >> 12) & 63], abc[(v >> 6) & 63], '='};
  }
  return out;
}

std::string readAll(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

// A glTF with two triangles in one textured material. glTF UVs have their origin at the image's top-left:
// triangle 0 lies inside the top-left (red) texel, triangle 1 inside the bottom-right (white) one, each with
// its centroid on the texel's center (a footprint under a texel is sampled there).
std::string texturedGltf(const std::string& imageUri) {
  struct V {
    float x, y, z, u, v;
  };
  const V verts[6] = {{0, 0, 0, 0.2f, 0.2f}, {1, 0, 0, 0.35f, 0.2f}, {0, 1, 0, 0.2f, 0.35f},
                      {2, 0, 0, 0.7f, 0.7f}, {3, 0, 0, 0.85f, 0.7f}, {2, 1, 0, 0.7f, 0.85f}};
  std::string bin;
  for (const V& v : verts) bin.append(reinterpret_cast<const char*>(&v.x), 12);
  for (const V& v : verts) bin.append(reinterpret_cast<const char*>(&v.u), 8);
  const std::uint16_t idx[6] = {0, 1, 2, 3, 4, 5};
  bin.append(reinterpret_cast<const char*>(idx), sizeof idx);
  return R"({"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
  "meshes":[{"primitives":[{"attributes":{"POSITION":0,"TEXCOORD_0":1},"indices":2,"material":0}]}],
  "materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0},"baseColorFactor":[1,1,1,1]}}],
  "textures":[{"source":0}],"images":[{"uri":")" +
         imageUri + R"("}],
  "buffers":[{"byteLength":)" +
         std::to_string(bin.size()) + R"(,"uri":"data:application/octet-stream;base64,)" + base64(bin) +
         R"("}],
  "bufferViews":[{"buffer":0,"byteOffset":0,"byteLength":72},{"buffer":0,"byteOffset":72,"byteLength":48},
                 {"buffer":0,"byteOffset":120,"byteLength":12}],
  "accessors":[{"bufferView":0,"componentType":5126,"count":6,"type":"VEC3","min":[0,0,0],"max":[3,1,0]},
               {"bufferView":1,"componentType":5126,"count":6,"type":"VEC2"},
               {"bufferView":2,"componentType":5123,"count":6,"type":"SCALAR"}]})";
}

void checkTexturedGltf(const svo::Mesh& m) {
  ASSERT_EQ(m.triangles.size(), 2u);
  ASSERT_EQ(m.textures.size(), 1u);
  ASSERT_EQ(m.uvs.size(), m.positions.size());
  const auto& tex = *m.textures[0];
  EXPECT_EQ(tex.width(), 2);
  EXPECT_EQ(tex.height(), 2);
  ASSERT_GE(m.materialOf(0).texture, 0);
  EXPECT_TRUE(m.hasColor());
  // Each triangle's own UV polygon picks up the texel it was placed in (through the file's conventions).
  for (std::size_t t = 0; t < 2; ++t) {
    const glm::uvec3 tri = m.triangles[t];
    const glm::vec2 uv[3] = {m.uvs[tri.x], m.uvs[tri.y], m.uvs[tri.z]};
    const bool left = m.positions[tri.x].x < 1.5;
    expectVec4Near(tex.average(uv), left ? kRed : kWhite, 1e-4f, left ? "top-left triangle" : "bottom-right");
  }
}

}  // namespace

// ---- validateMesh and Mesh on meshes built in memory
// ----------------------------------------------------------

TEST(MeshValidate, DropsAndCountsDegenerateTriangles) {
  svo::Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 0, 0}, {1e-9, 1e-9, 0}};
  m.triangles = {{0, 1, 2}, {0, 0, 1}, {0, 1, 3}, {0, 2, 1}, {1, 2, 2}, {0, 1, 4}};
  m.triangleMaterials = {0, 1, 2, 3, 4, 5};
  m.materials.resize(6);
  // Kept: the two real triangles (one of them flipped), and the tiny one (1e-9 is small but not degenerate).
  EXPECT_EQ(svo::validateMesh(m, "mem"), 3u);
  ASSERT_EQ(m.triangles.size(), 3u);
  EXPECT_EQ(m.triangles[0], glm::uvec3(0, 1, 2));
  EXPECT_EQ(m.triangles[1], glm::uvec3(0, 2, 1));
  EXPECT_EQ(m.triangles[2], glm::uvec3(0, 1, 4));
  EXPECT_EQ(m.triangleMaterials, (std::vector<std::uint32_t>{0, 3, 5}));
}

TEST(MeshValidate, CollinearUpToRoundingIsDegenerate) {
  svo::Mesh m;
  // a, 2a, 3a lie on a line; rounding in 0.1 and friends leaves their cross product a few ulps from zero.
  const glm::dvec3 a(0.1, 0.2, 0.3);
  m.positions = {
      a, 2.0 * a, 3.0 * a, {1e7, 1e7, 1e7}, {1e7 + 0.5, 1e7 + 1, 1e7 + 1.5}, {1e7 + 1, 1e7 + 2, 1e7 + 3}};
  m.triangles = {{0, 1, 2}, {3, 4, 5}};
  EXPECT_EQ(svo::validateMesh(m, "mem"), 2u);
  EXPECT_TRUE(m.triangles.empty());
}

TEST(MeshValidate, RejectsNonFiniteAndOutOfRange) {
  svo::Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, std::nan(""), 0}};
  m.triangles = {{0, 1, 2}};
  EXPECT_EQ(errorOf([&] { svo::validateMesh(m, "src.obj"); }),
            "src.obj: vertex 2 has a non-finite coordinate");
  m.positions[2] = {0, INFINITY, 0};
  EXPECT_EQ(errorOf([&] { svo::validateMesh(m, "src.obj"); }),
            "src.obj: vertex 2 has a non-finite coordinate");
  m.positions[2] = {0, 1, 0};
  m.triangles = {{0, 1, 3}};
  EXPECT_NE(errorOf([&] { svo::validateMesh(m, "src.obj"); }).find("src.obj: triangle 0 uses vertex 3"),
            std::string::npos);
  m.triangles = {{0, 1, 2}};
  m.colors = {glm::vec4(1)};  // one color for three vertices
  EXPECT_NE(errorOf([&] { svo::validateMesh(m, "src.obj"); }), "");
  m.colors.clear();
  m.triangleMaterials = {1};
  EXPECT_NE(errorOf([&] { svo::validateMesh(m, "src.obj"); }).find("material 1"), std::string::npos);
}

TEST(MeshValidate, HasColorAndMaterialOf) {
  svo::Mesh m;
  m.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}};
  m.triangles = {{0, 1, 2}, {1, 3, 2}};
  EXPECT_FALSE(m.hasColor());
  EXPECT_EQ(m.materialOf(1).baseColor, glm::vec4(1));
  EXPECT_EQ(m.materialOf(1).texture, -1);
  m.colors.assign(4, glm::vec4(1));
  EXPECT_FALSE(m.hasColor());
  m.colors[3] = glm::vec4(1, 0.5f, 1, 1);
  EXPECT_TRUE(m.hasColor());
  m.colors.clear();
  m.materials = {svo::Material{}, svo::Material{glm::vec4(0.2f, 0.3f, 0.4f, 1), -1}};
  m.triangleMaterials = {0, 0};
  EXPECT_FALSE(m.hasColor());  // the gray material is not used by any triangle
  m.triangleMaterials = {0, 1};
  EXPECT_TRUE(m.hasColor());
  EXPECT_EQ(m.materialOf(1).baseColor, glm::vec4(0.2f, 0.3f, 0.4f, 1));
}

// ---- textures
// ---------------------------------------------------------------------------------------------------

TEST(Texture, CheckerAveragesOverPolygons) {
  TempDir dir;
  const fs::path png = dir.path() / "checker.png";
  writeChecker(png);
  const auto tex = svo::loadTexture(png);
  ASSERT_EQ(tex->width(), 2);
  ASSERT_EQ(tex->height(), 2);
  const glm::vec4 mean = 0.25f * (kRed + kGreen + kBlue + kWhite);
  const std::vector<glm::vec2> square = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  expectVec4Near(tex->average(square), mean, 1e-5f, "whole square");
  // u runs left to right; v = 1 is the image's top row.
  const std::vector<glm::vec2> left = {{0, 0}, {0.5f, 0}, {0.5f, 1}, {0, 1}};
  expectVec4Near(tex->average(left), 0.5f * (kRed + kBlue), 1e-5f, "left half");
  const std::vector<glm::vec2> top = {{0, 0.5f}, {1, 0.5f}, {1, 1}, {0, 1}};
  expectVec4Near(tex->average(top), 0.5f * (kRed + kGreen), 1e-5f, "top half");
  // A triangle is weighted by what it covers: the lower-left triangle of the square covers blue fully and red
  // and white by half each (areas 1/4, 1/8, 1/8 of the square).
  const std::vector<glm::vec2> lowerLeft = {{0, 0}, {1, 0}, {0, 1}};
  expectVec4Near(tex->average(lowerLeft), (2.0f * kBlue + kRed + kWhite) / 4.0f, 1e-5f,
                 "lower-left triangle");
  // Wrapping: the square shifted by whole and half periods.
  const std::vector<glm::vec2> shifted = {{3, -2}, {4, -2}, {4, -1}, {3, -1}};
  expectVec4Near(tex->average(shifted), mean, 1e-5f, "shifted square");
  const std::vector<glm::vec2> straddle = {{0.5f, 0}, {1.5f, 0}, {1.5f, 1}, {0.5f, 1}};
  expectVec4Near(tex->average(straddle), mean, 1e-5f, "straddling square");
  const std::vector<glm::vec2> manyRepeats = {{0, 0}, {1000, 0}, {1000, 1000}, {0, 1000}};
  expectVec4Near(tex->average(manyRepeats), mean, 1e-5f, "many repeats");
  // Under a texel: bilinear at the centroid, which at a texel center is that texel.
  const std::vector<glm::vec2> dot = {{0.74f, 0.24f}, {0.76f, 0.24f}, {0.76f, 0.26f}, {0.74f, 0.26f}};
  expectVec4Near(tex->average(dot), kWhite, 1e-3f, "bottom-right texel center");
  const std::vector<glm::vec2> middle = {{0.49f, 0.49f}, {0.51f, 0.49f}, {0.5f, 0.51f}};
  expectVec4Near(tex->average(middle), mean, 2e-2f, "between all four texels");
}

TEST(Texture, SrgbPngBecomesLinearAndGrayExpands) {
  TempDir dir;
  const fs::path png = dir.path() / "gray.png";
  {
    const unsigned char px[4] = {128, 128, 128, 128};
    auto out = OIIO::ImageOutput::create(png.string());
    ASSERT_TRUE(out);
    ASSERT_TRUE(out->open(png.string(), OIIO::ImageSpec(2, 2, 1, OIIO::TypeDesc::UINT8)));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, px));
    out->close();
  }
  const auto tex = svo::loadTexture(png);
  const float g = static_cast<float>(srgbToLinearRef(128.0 / 255.0));
  const std::vector<glm::vec2> square = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  expectVec4Near(tex->average(square), glm::vec4(g, g, g, 1), 1e-4f, "gray");
}

TEST(Texture, MipLevelsKeepTheMean) {
  // 37x19 texels (odd sizes exercise the clamped box filter) with a horizontal ramp in red.
  const int w = 37, h = 19;
  std::vector<glm::vec4> px(w * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) px[y * w + x] = glm::vec4((x + 0.5f) / w, 0.25f, 0, 1);
  const auto tex = svo::makeTexture(w, h, px);
  EXPECT_EQ(tex->width(), w);
  EXPECT_EQ(tex->height(), h);
  // The ramp's mean over u in [a, b] is (a + b) / 2, at any footprint size.
  for (float a : {0.0f, 0.1f, 0.3f}) {
    for (float b : {0.5f, 0.8f, 1.0f}) {
      const std::vector<glm::vec2> strip = {{a, 0.2f}, {b, 0.2f}, {b, 0.7f}, {a, 0.7f}};
      const glm::vec4 got = tex->average(strip);
      EXPECT_NEAR(got.r, 0.5f * (a + b), 0.01f) << a << ".." << b;
      EXPECT_NEAR(got.g, 0.25f, 1e-5f);
    }
  }
  EXPECT_THROW(svo::makeTexture(2, 2, std::vector<glm::vec4>(3)), std::runtime_error);
  EXPECT_THROW(svo::loadTexture("/nonexistent/texture.png"), std::runtime_error);
}

// ---- formats
// ----------------------------------------------------------------------------------------------------

TEST(MeshIo, ObjCube) {
  TempDir dir;
  std::string obj = "# unit cube scaled to [-1,2]x[0,1]x[5,7]\n";
  for (int i = 0; i < 8; ++i) {
    obj += "v " + std::to_string((i & 1) ? 2 : -1) + " " + std::to_string((i & 2) ? 1 : 0) + " " +
           std::to_string((i & 4) ? 7 : 5) + "\n";
  }
  // Six quads, each triangulated by the loader into two triangles.
  obj += "f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";
  svo::MeshLoadReport report;
  const svo::Mesh m = svo::loadMesh(dir.file("cube.obj", obj), &report);
  EXPECT_EQ(m.positions.size(), 8u);
  EXPECT_EQ(m.triangles.size(), 12u);
  EXPECT_EQ(report.droppedDegenerate, 0u);
  EXPECT_FALSE(report.format.empty());
  const Box b = boundsOf(m);
  EXPECT_EQ(b.lo, glm::dvec3(-1, 0, 5));
  EXPECT_EQ(b.hi, glm::dvec3(2, 1, 7));
  EXPECT_DOUBLE_EQ(surfaceArea(m), 2 * (3 * 1 + 3 * 2 + 1 * 2));
  EXPECT_TRUE(m.colors.empty());
  EXPECT_TRUE(m.uvs.empty());
  EXPECT_FALSE(m.hasColor());  // no material file: white, not assimp's gray default
}

TEST(MeshIo, ObjWithMaterials) {
  TempDir dir;
  dir.file("m.mtl", "newmtl red\nKd 1 0 0\nnewmtl half\nKd 0.5 0.5 0.5\nd 0.5\n");
  const svo::Mesh m = svo::loadMesh(dir.file("m.obj",
                                             "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\n"
                                             "usemtl red\nf 1 2 3\nusemtl half\nf 2 4 3\n"));
  ASSERT_EQ(m.triangles.size(), 2u);
  EXPECT_TRUE(m.hasColor());
  std::multiset<std::tuple<float, float, float, float>> got;
  for (std::size_t t = 0; t < 2; ++t) {
    const glm::vec4 c = m.materialOf(t).baseColor;
    got.insert({c.r, c.g, c.b, c.a});
  }
  const std::multiset<std::tuple<float, float, float, float>> want = {{1, 0, 0, 1}, {0.5f, 0.5f, 0.5f, 0.5f}};
  EXPECT_EQ(got, want);
}

TEST(MeshIo, AsciiPlyWithVertexColors) {
  TempDir dir;
  const fs::path ply =
      dir.file("tri.ply",
               "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
               "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
               "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
               "0 0 0 255 0 0\n1 0 0 0 255 0\n0 1 0 0 0 255\n1 1 0.5 128 64 32\n"
               "3 0 1 2\n3 1 3 2\n");
  const svo::Mesh m = svo::loadMesh(ply);
  ASSERT_EQ(m.positions.size(), 4u);
  ASSERT_EQ(m.colors.size(), 4u);
  EXPECT_EQ(m.triangles.size(), 2u);
  EXPECT_TRUE(m.hasColor());
  // Vertex colors in PLY are 8-bit display values; the mesh holds them linear. Matched by position.
  const std::map<std::tuple<double, double, double>, glm::dvec3> want = {{{0, 0, 0}, {255, 0, 0}},
                                                                         {{1, 0, 0}, {0, 255, 0}},
                                                                         {{0, 1, 0}, {0, 0, 255}},
                                                                         {{1, 1, 0.5}, {128, 64, 32}}};
  for (std::size_t i = 0; i < 4; ++i) {
    const glm::dvec3 p = m.positions[i];
    auto it = want.find({p.x, p.y, p.z});
    ASSERT_NE(it, want.end()) << "unexpected vertex " << i;
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(m.colors[i][k], srgbToLinearRef(it->second[k] / 255.0), 1e-5);
    EXPECT_FLOAT_EQ(m.colors[i].a, 1.0f);
  }
}

TEST(MeshIo, AsciiStlTetrahedron) {
  TempDir dir;
  const glm::dvec3 v[4] = {{0, 0, 0}, {2, 0, 0}, {0, 3, 0}, {0, 0, 4}};
  const int faces[4][3] = {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}};
  std::string stl = "solid tet\n";
  for (const auto& f : faces) {
    stl += "facet normal 0 0 0\n outer loop\n";
    for (int k : f) {
      stl += "  vertex " + std::to_string(v[k].x) + " " + std::to_string(v[k].y) + " " +
             std::to_string(v[k].z) + "\n";
    }
    stl += " endloop\nendfacet\n";
  }
  stl += "endsolid tet\n";
  const svo::Mesh m = svo::loadMesh(dir.file("tet.stl", stl));
  EXPECT_EQ(m.positions.size(), 4u);
  EXPECT_EQ(m.triangles.size(), 4u);
  EXPECT_EQ(boundsOf(m).hi, glm::dvec3(2, 3, 4));
  // Three right-triangle faces plus the slanted one, from the edge vectors.
  const double slanted = 0.5 * glm::length(glm::cross(v[2] - v[1], v[3] - v[1]));
  EXPECT_NEAR(surfaceArea(m), 0.5 * (2 * 3 + 2 * 4 + 3 * 4) + slanted, 1e-12);
  EXPECT_FALSE(m.hasColor());
}

TEST(MeshIo, DracoMeshWithColors) {
  TempDir dir;
  // A unit cube whose corner colors encode the corner: color = 255 * position.
  draco::TriangleSoupMeshBuilder builder;
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  builder.Start(12);
  const int pos = builder.AddAttribute(draco::GeometryAttribute::POSITION, 3, draco::DT_FLOAT32);
  const int col = builder.AddAttribute(draco::GeometryAttribute::COLOR, 3, draco::DT_UINT8, true);
  auto corner = [](int i) {
    return std::array<float, 3>{float(i & 1), float((i >> 1) & 1), float((i >> 2) & 1)};
  };
  auto color = [](int i) {
    return std::array<std::uint8_t, 3>{std::uint8_t((i & 1) * 255), std::uint8_t(((i >> 1) & 1) * 255),
                                       std::uint8_t(((i >> 2) & 1) * 255)};
  };
  int face = 0;
  for (const auto& q : quads) {
    for (const auto& tri : {std::array<int, 3>{q[0], q[1], q[2]}, std::array<int, 3>{q[0], q[2], q[3]}}) {
      const auto a = corner(tri[0]), b = corner(tri[1]), c = corner(tri[2]);
      const auto ca = color(tri[0]), cb = color(tri[1]), cc = color(tri[2]);
      builder.SetAttributeValuesForFace(pos, draco::FaceIndex(face), a.data(), b.data(), c.data());
      builder.SetAttributeValuesForFace(col, draco::FaceIndex(face), ca.data(), cb.data(), cc.data());
      ++face;
    }
  }
  std::unique_ptr<draco::Mesh> dm = builder.Finalize();
  ASSERT_TRUE(dm);
  draco::Encoder encoder;  // no quantization: positions stay exact
  draco::EncoderBuffer buffer;
  ASSERT_TRUE(encoder.EncodeMeshToBuffer(*dm, &buffer).ok());
  const fs::path drc = dir.file("cube.drc", std::string(buffer.data(), buffer.size()));

  svo::MeshLoadReport report;
  const svo::Mesh m = svo::loadMesh(drc, &report);
  EXPECT_EQ(report.format, "Draco");
  EXPECT_EQ(m.triangles.size(), 12u);
  EXPECT_EQ(boundsOf(m).lo, glm::dvec3(0));
  EXPECT_EQ(boundsOf(m).hi, glm::dvec3(1));
  EXPECT_DOUBLE_EQ(surfaceArea(m), 6.0);
  ASSERT_EQ(m.colors.size(), m.positions.size());
  for (std::size_t i = 0; i < m.positions.size(); ++i) {
    const glm::dvec3 p = m.positions[i];
    EXPECT_TRUE((p.x == 0 || p.x == 1) && (p.y == 0 || p.y == 1) && (p.z == 0 || p.z == 1)) << "vertex " << i;
    expectVec4Near(m.colors[i], glm::vec4(glm::vec3(p), 1), 1e-6f, "corner color");
  }

  // A Draco point cloud is not a mesh.
  draco::PointCloud cloud;
  cloud.set_num_points(1);
  draco::GeometryAttribute ga;
  ga.Init(draco::GeometryAttribute::POSITION, nullptr, 3, draco::DT_FLOAT32, false, 12, 0);
  const int att = cloud.AddAttribute(ga, true, 1);
  const float p0[3] = {1, 2, 3};
  cloud.attribute(att)->SetAttributeValue(draco::AttributeValueIndex(0), p0);
  draco::EncoderBuffer cloudBuffer;
  ASSERT_TRUE(encoder.EncodePointCloudToBuffer(cloud, &cloudBuffer).ok());
  const fs::path pc = dir.file("cloud.drc", std::string(cloudBuffer.data(), cloudBuffer.size()));
  EXPECT_EQ(errorOf([&] { svo::loadMesh(pc); }).rfind(pc.string() + ": mesh has no triangles", 0), 0u)
      << errorOf([&] { svo::loadMesh(pc); });
  const fs::path junk = dir.file("junk.drc", "DRACO but not really");
  EXPECT_EQ(errorOf([&] { svo::loadMesh(junk); }).rfind(junk.string() + ": unsupported or unreadable", 0),
            0u);
}

TEST(MeshIo, GltfWithEmbeddedPngTexture) {
  TempDir dir;
  const fs::path png = dir.path() / "checker.png";
  writeChecker(png);
  const std::string uri = "data:image/png;base64," + base64(readAll(png));
  fs::remove(png);  // the texture exists only inside the glTF
  svo::MeshLoadReport report;
  const svo::Mesh m = svo::loadMesh(dir.file("embedded.gltf", texturedGltf(uri)), &report);
  checkTexturedGltf(m);
  EXPECT_NE(report.format.find("glTF"), std::string::npos) << report.format;
}

TEST(MeshIo, GltfWithExternalTexture) {
  TempDir dir;
  fs::create_directories(dir.path() / "tex");
  writeChecker(dir.path() / "tex" / "checker.png");
  checkTexturedGltf(svo::loadMesh(dir.file("external.gltf", texturedGltf("tex/checker.png"))));
  // A texture that is not there costs the texture, not the mesh.
  const svo::Mesh m = svo::loadMesh(dir.file("missing.gltf", texturedGltf("nowhere.png")));
  EXPECT_EQ(m.triangles.size(), 2u);
  EXPECT_EQ(m.materialOf(0).texture, -1);
}

TEST(MeshIo, BadInputsGiveOneLineErrors) {
  TempDir dir;
  const fs::path missing = dir.path() / "missing.obj";
  EXPECT_EQ(errorOf([&] { svo::loadMesh(missing); }), missing.string() + ": no such file");

  const fs::path garbage = dir.file("notes.txt", "this is not\x01\x02 a mesh at all\n");
  const std::string g = errorOf([&] { svo::loadMesh(garbage); });
  EXPECT_EQ(g.rfind(garbage.string() + ": unsupported or unreadable mesh format (", 0), 0u) << g;

  for (const std::string& content :
       {std::string(), std::string("# nothing\n"), std::string("v 0 0 0\nv 1 0 0\n")}) {
    const fs::path empty = dir.file("empty.obj", content);
    const std::string e = errorOf([&] { svo::loadMesh(empty); });
    EXPECT_EQ(e.rfind(empty.string() + ": ", 0), 0u) << e;
    EXPECT_NE(e.find("no triangles"), std::string::npos) << "for '" << content << "': " << e;
  }

  const fs::path nan = dir.file("nan.obj", "v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n");
  const std::string n = errorOf([&] { svo::loadMesh(nan); });
  EXPECT_EQ(n.rfind(nan.string() + ": vertex ", 0), 0u) << n;
  EXPECT_NE(n.find("has a non-finite coordinate"), std::string::npos) << n;

  for (const std::string& e : {g, n}) EXPECT_EQ(e.find('\n'), std::string::npos) << e;
  EXPECT_THROW(svo::loadMesh(dir.path()), std::runtime_error);  // a folder
}

TEST(MeshIo, DegenerateTrianglesAreDroppedAndCounted) {
  TempDir dir;
  // One real triangle, one with a repeated vertex, one with three collinear vertices.
  const fs::path obj = dir.file("degenerate.obj",
                                "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nv 3 0 0\n"
                                "f 1 2 3\nf 1 1 2\nf 2 4 5\n");
  svo::MeshLoadReport report;
  const svo::Mesh m = svo::loadMesh(obj, &report);
  EXPECT_EQ(m.triangles.size(), 1u);
  EXPECT_EQ(report.droppedDegenerate, 2u);
  EXPECT_DOUBLE_EQ(surfaceArea(m), 0.5);

  const fs::path allBad = dir.file("allbad.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n");
  EXPECT_NE(errorOf([&] { svo::loadMesh(allBad); }).find("no triangles"), std::string::npos);
}

TEST(MeshIo, FlatMeshLoads) {
  TempDir dir;
  const svo::Mesh m = svo::loadMesh(dir.file("flat.obj", "v 0 0 3\nv 4 0 3\nv 4 5 3\nv 0 5 3\nf 1 2 3 4\n"));
  EXPECT_EQ(m.triangles.size(), 2u);
  const Box b = boundsOf(m);
  EXPECT_EQ(b.lo, glm::dvec3(0, 0, 3));
  EXPECT_EQ(b.hi, glm::dvec3(4, 5, 3));
  EXPECT_DOUBLE_EQ(surfaceArea(m), 20.0);
}

// ---- real files
// ---------------------------------------------------------------------------------------------------

namespace {
// Debian's assimp-testmodels, when installed.
fs::path assimpModel(const std::string& rel) {
  for (const char* root : {"/usr/share/assimp/models", "/usr/share/assimp-testmodels"}) {
    if (fs::exists(fs::path(root) / rel)) return fs::path(root) / rel;
  }
  return {};
}
}  // namespace

TEST(MeshIoReal, AssimpTestModelsBoxes) {
  // Each is a (rotated, in the FBX) box: 8 corners, 12 triangles, closed. Corners are matched by position
  // since the files split them per face for normals and UVs.
  for (const std::string rel : {"FBX/box.fbx", "Collada/cube_triangulate.dae"}) {
    const fs::path p = assimpModel(rel);
    if (p.empty()) GTEST_SKIP() << "assimp-testmodels not installed";
    svo::MeshLoadReport report;
    const svo::Mesh m = svo::loadMesh(p, &report);
    EXPECT_EQ(m.triangles.size(), 12u) << rel;
    EXPECT_EQ(report.droppedDegenerate, 0u) << rel;
    std::map<std::tuple<double, double, double>, int> corner;
    std::vector<int> id(m.positions.size());
    for (std::size_t i = 0; i < m.positions.size(); ++i) {
      const auto key = std::make_tuple(m.positions[i].x, m.positions[i].y, m.positions[i].z);
      id[i] = corner.emplace(key, static_cast<int>(corner.size())).first->second;
    }
    EXPECT_EQ(corner.size(), 8u) << rel;
    std::map<std::pair<int, int>, int> edgeUse;
    for (const auto& t : m.triangles) {
      for (int k = 0; k < 3; ++k) {
        const int a = id[t[k]], b = id[t[(k + 1) % 3]];
        ++edgeUse[{std::min(a, b), std::max(a, b)}];
      }
    }
    for (const auto& [edge, uses] : edgeUse)
      EXPECT_EQ(uses, 2) << rel << " edge " << edge.first << "-" << edge.second;
  }
}

TEST(MeshIoReal, AssimpTestModelsTexturedGlb) {
  // The Khronos BoxTextured sample: a cube with the Cesium logo embedded in the GLB; the same PNG ships
  // beside the .gltf variant, and OpenImageIO's own reading of it gives the expected size.
  const fs::path p = assimpModel("glTF2/BoxTextured-glTF-Binary/BoxTextured.glb");
  const fs::path png = assimpModel("glTF2/BoxTextured-glTF/CesiumLogoFlat.png");
  if (p.empty() || png.empty()) GTEST_SKIP() << "assimp-testmodels not installed";
  auto in = OIIO::ImageInput::open(png.string());
  ASSERT_TRUE(in);
  const OIIO::ImageSpec spec = in->spec();
  const svo::Mesh m = svo::loadMesh(p);
  EXPECT_EQ(m.triangles.size(), 12u);
  ASSERT_EQ(m.textures.size(), 1u);
  EXPECT_EQ(m.textures[0]->width(), spec.width);
  EXPECT_EQ(m.textures[0]->height(), spec.height);
  EXPECT_EQ(m.uvs.size(), m.positions.size());
  EXPECT_TRUE(m.hasColor());
}

TEST(MeshIoReal, AssimpTestModelsDracoGltf) {
  // KHR_draco_mesh_compression, decoded through assimp's Draco support. Reference: the triangle count the
  // glTF JSON itself declares (indices accessor counts of every primitive, once per node instance).
  const fs::path p = assimpModel("glTF2/draco/2CylinderEngine.gltf");
  if (p.empty()) GTEST_SKIP() << "assimp-testmodels not installed";
  const nlohmann::json j = nlohmann::json::parse(readAll(p));
  std::size_t declared = 0;
  std::vector<int> stack;
  for (int n : j["scenes"][j.value("scene", 0)]["nodes"]) stack.push_back(n);
  while (!stack.empty()) {
    const nlohmann::json& node = j["nodes"][stack.back()];
    stack.pop_back();
    if (node.contains("mesh")) {
      for (const auto& prim : j["meshes"][node["mesh"].get<int>()]["primitives"]) {
        ASSERT_EQ(prim.value("mode", 4), 4);  // triangles
        ASSERT_TRUE(prim["extensions"].contains("KHR_draco_mesh_compression"));
        declared += j["accessors"][prim["indices"].get<int>()]["count"].get<std::size_t>() / 3;
      }
    }
    if (node.contains("children")) {
      for (int c : node["children"]) stack.push_back(c);
    }
  }
  svo::MeshLoadReport report;
  const svo::Mesh m = svo::loadMesh(p, &report);
  EXPECT_NE(report.format.find("Draco"), std::string::npos) << report.format;
  EXPECT_EQ(m.triangles.size() + report.droppedDegenerate, declared);
  EXPECT_LT(report.droppedDegenerate, declared / 1000);
}

TEST(MeshIoReal, StanfordBunny) {
  // Written by tools/scripts/fetch-data.sh from the npm package `bunny` (1839 vertices, 3674 triangles).
  fs::path p;
  if (const char* env = std::getenv("SVO_BUNNY")) p = env;
  if (p.empty()) p = fs::path(SVO_SOURCE_DIR) / "build" / "data" / "bunny.ply";
  if (!fs::exists(p)) GTEST_SKIP() << p << " absent: run tools/scripts/fetch-data.sh";
  svo::MeshLoadReport report;
  const svo::Mesh m = svo::loadMesh(p, &report);
  EXPECT_EQ(m.positions.size(), 1839u);
  EXPECT_EQ(m.triangles.size() + report.droppedDegenerate, 3674u);
  EXPECT_FALSE(m.hasColor());
}
