// The benches' triangle shading (tools/bench/mesh_shading.hpp) against albedos worked out by hand: a 2 x 2
// square textured with a 2 x 1 texture (red left, blue right), seen from above and at a slant. The texture is
// averaged over the pixel's footprint on the triangle, mapped to UV by the triangle's own UV gradients.
#include <gtest/gtest.h>

#include <cmath>

#include <glm/geometric.hpp>

#include "mesh_shading.hpp"

namespace {

using svo::tools::bench::MeshShading;
using svo::tools::bench::PixelFootprint;

// A pixel of `side` world units seen straight down, its sides along x and y.
PixelFootprint square(double side) {
  return {glm::dvec3(side, 0, 0), glm::dvec3(0, side, 0)};
}

svo::Mesh texturedSquare() {
  svo::Mesh mesh;
  mesh.positions = {{0, 0, 0}, {2, 0, 0}, {2, 2, 0}, {0, 2, 0}};
  mesh.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  mesh.textures.push_back(svo::makeTexture(2, 1, {{1, 0, 0, 1}, {0, 0, 1, 1}}));
  mesh.materials.push_back({glm::vec4(1.0f), 0});
  return mesh;
}

// What svo::render's shading gives a voxel of this albedo with the square's normal, seen straight down.
glm::vec3 expected(const glm::vec3& albedo, const svo::RenderOptions& options) {
  return svo::shadePhong(albedo, glm::vec3(0, 0, 1), glm::vec3(0, 0, -1),
                         glm::normalize(options.lightDirection));
}

void expectNear(const glm::vec3& a, const glm::vec3& b) {
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(a[c], b[c], 1e-5f) << "channel " << c;
}

TEST(MeshShading, SamplesTheTextureUnderASmallFootprint) {
  const svo::Mesh mesh = texturedSquare();
  const svo::RenderOptions options;
  const MeshShading shading(mesh, options);
  const glm::dvec3 down(0, 0, -1);
  // World (1.5, 1) in the first triangle (u = x/2 - y/2, v = y/2): UV (0.75, 0.5), the blue texel's centre.
  expectNear(shading.shade(0, 0.25, 0.5, down, square(1e-4)), expected({0, 0, 1}, options));
  // World (0.5, 1) in the second triangle (u = x/2, v = y/2 - x/2): UV (0.25, 0.5), the red texel's centre.
  expectNear(shading.shade(1, 0.25, 0.25, down, square(1e-4)), expected({1, 0, 0}, options));
}

TEST(MeshShading, AveragesTheTextureOverThePixelFootprint) {
  const svo::Mesh mesh = texturedSquare();
  const svo::RenderOptions options;
  const MeshShading shading(mesh, options);
  const glm::dvec3 down(0, 0, -1);
  // A footprint of 2 world units around the centre covers UV [0, 1]^2: half red, half blue.
  expectNear(shading.shade(0, 0.0, 0.5, down, square(2.0)), expected({0.5f, 0, 0.5f}, options));
  // 1 unit around world (0.5, 1): UV [0, 0.5] x [0.25, 0.75], the red texel alone.
  expectNear(shading.shade(1, 0.25, 0.25, down, square(1.0)), expected({1, 0, 0}, options));
  // 1 unit around world (1, 1): UV [0.25, 0.75]^2, half of each texel.
  expectNear(shading.shade(0, 0.0, 0.5, down, square(1.0)), expected({0.5f, 0, 0.5f}, options));
}

TEST(MeshShading, StretchesTheFootprintAlongASlantedRay) {
  const svo::Mesh mesh = texturedSquare();
  const svo::RenderOptions options;
  const MeshShading shading(mesh, options);
  // 60 degrees off the normal in the x-z plane: the pixel's side across the ray lands twice as long on the
  // square (1 / cos 60).
  const glm::dvec3 slant(std::sqrt(0.75), 0.0, -0.5);
  const PixelFootprint pixel{glm::dvec3(0.5, 0.0, std::sqrt(0.75)), glm::dvec3(0.0, 1.0, 0.0)};
  // Around world (0.5, 1): 2 units along x, UV u in [-0.25, 0.75] (wrapping): half red, half blue. Seen
  // straight down, the same pixel covers the red texel alone (the test above).
  const glm::vec3 shown = shading.shade(1, 0.25, 0.25, slant, pixel);
  const glm::vec3 want = svo::shadePhong({0.5f, 0.0f, 0.5f}, glm::vec3(0, 0, 1), glm::vec3(slant),
                                         glm::normalize(options.lightDirection));
  expectNear(shown, want);
}

TEST(MeshShading, LeavesAnUntexturedMeshGrey) {
  svo::Mesh mesh = texturedSquare();
  mesh.uvs.clear(), mesh.textures.clear(), mesh.materials.clear();
  const svo::RenderOptions options;
  expectNear(MeshShading(mesh, options).shade(0, 0.25, 0.5, glm::dvec3(0, 0, -1), square(1.0)),
             expected(glm::vec3(svo::kNeutralGreyAlbedo), options));
}

}  // namespace
