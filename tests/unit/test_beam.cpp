// The beam optimization (client/beam.hpp, paper sec. 6.2) against two independent references:
//  (1) the bound: for every ray of a tile, the beam's start t is no later than the first hit of the
//      brute-force double-precision caster over the same cube voxels (reference.hpp (c)), and a tile whose
//      beam meets nothing has no ray that hits anything;
//  (2) the frames: svo::render with the beam pass gives the same image, depth and voxel size, bit for bit, as
//      without it (the castRay path without a start t is checked against the reference in test_raycast.cpp).
// Cameras include the stiff ones: eye inside the scene cube, inside a voxel, looking straight along an axis,
// grazing a flat scene, a very narrow and a very wide field of view; tiles of 4, 8 and 13 pixels (a ragged
// last tile); level of detail 0 (finest), 1, 4 and 16 pixels.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <glm/geometric.hpp>

#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/beam.hpp"
#include "svo/client/render.hpp"

namespace {

// The beam starts rays kStartMargin (1/1024) of t early; the reference's t agrees with the caster's to 1e-5
// relative (test_raycast.cpp), so a bound above the reference's t by more than this is a failure.
constexpr double kBoundSlack = 1e-6;

struct BeamScene {
  std::string name;
  svo::Octree octree;
  std::unique_ptr<svotest::RefCaster> cubes;  // every leaf voxel as a cube: what the beam may not skip
};

std::unique_ptr<BeamScene> makeBeamScene(std::string name, const svo::Mesh& mesh, int levels) {
  auto s = std::make_unique<BeamScene>();
  s->name = std::move(name);
  svo::BuildOptions options;
  options.levels = levels;
  s->octree = svo::buildOctree(mesh, options);
  std::vector<svotest::Shape> shapes;
  for (const svotest::LeafVoxel& v : svotest::walkLeaves(s->octree.block.view()))
    shapes.push_back(svotest::shapeOf(v, false));
  s->cubes = std::make_unique<svotest::RefCaster>(std::move(shapes));
  return s;
}

const BeamScene& sphere() {
  static const auto s = makeBeamScene("sphere", svotest::makeSphere({0.3, -0.2, 0.1}, 1.0, 24, 24), 7);
  return *s;
}
const BeamScene& triangles() {
  static const auto s = makeBeamScene("random triangles",
                                      svotest::makeRandomTriangles(5, 120, {-1, -1, -1}, {1, 1, 1}, 0.3), 6);
  return *s;
}
const BeamScene& flat() {
  // A quad exactly in y = 0 plus a small tilted triangle so the scene cube is not flat.
  static const auto s = [] {
    svo::Mesh m;
    m.positions = {{-1, 0, -1},     {1, 0, -1},      {1, 0, 1},      {-1, 0, 1},
                   {0.2, 0.0, 0.2}, {0.3, 0.4, 0.2}, {0.2, 0.1, 0.5}};
    m.triangles = {{0, 1, 2}, {0, 2, 3}, {4, 5, 6}};
    return makeBeamScene("flat quad", m, 7);
  }();
  return *s;
}

struct View {
  std::string name;
  svo::Camera camera;
};

svo::Camera look(glm::dvec3 eye, glm::dvec3 target, glm::dvec3 up, double fov, int width, int height) {
  svo::Camera c;
  c.eye = eye, c.target = target, c.up = up, c.fovYDegrees = fov, c.width = width, c.height = height;
  return c;
}

std::vector<View> viewsOf(const BeamScene& s) {
  const svo::SceneTransform& t = s.octree.transform;
  const glm::dvec3 centre = t.toWorld(glm::dvec3(1.5));
  const double size = t.size;
  std::vector<View> views;
  views.push_back({"framing", svo::Camera::framing(t, {-0.35, -0.25, -1.0}, 61, 47)});
  views.push_back({"framing from below", svo::Camera::framing(t, {0.2, 1.0, 0.3}, 40, 40)});
  views.push_back({"along -z", look(centre + glm::dvec3(0, 0, 2 * size), centre, {0, 1, 0}, 50, 48, 48)});
  views.push_back(
      {"eye inside the scene cube", look(centre + glm::dvec3(0.05, 0.02, 0.01) * size,
                                         centre + glm::dvec3(1, 0.3, 0.2) * size, {0, 1, 0}, 100, 64, 40)});
  views.push_back({"eye at the centre, looking back",
                   look(centre, centre - glm::dvec3(0.3, 0.1, 1.0), {0, 1, 0}, 120, 50, 50)});
  views.push_back(
      {"grazing the y = 0 plane",
       look(t.toWorld({1.0, 1.5 + 1e-4, 1.0}) - glm::dvec3(size, 0, size), centre, {0, 1, 0}, 30, 64, 32)});
  views.push_back({"narrow field of view",
                   look(centre + glm::dvec3(0.4, 0.7, 3.0) * size, centre, {0, 1, 0}, 2, 33, 33)});
  views.push_back({"wide field of view",
                   look(centre + glm::dvec3(0.1, 0.2, 0.8) * size, centre, {0, 1, 0}, 170, 48, 48)});
  return views;
}

std::vector<const BeamScene*> scenes() {
  return {&sphere(), &triangles(), &flat()};
}

TEST(Beam, BoundIsNoLaterThanTheReferenceFirstHitOfAnyRayInTheTile) {
  std::size_t tiles = 0, emptyTiles = 0, rays = 0;
  for (const BeamScene* s : scenes()) {
    const svo::BlockView block = s->octree.block.view();
    for (const View& v : viewsOf(*s)) {
      for (const float lod : {0.0f, 1.0f, 4.0f, 16.0f}) {
        const svo::PixelRays pixelRays(s->octree.transform, v.camera, lod);
        for (const int tileSize : {4, 8, 13}) {
          svo::forEachTile(v.camera.width, v.camera.height, tileSize, 1, [&](const svo::PixelTile& tile) {
            const svo::BeamResult beam = svo::castBeam(block, pixelRays, tile);
            ++tiles;
            emptyTiles += std::isinf(beam.tStart);
            ASSERT_FALSE(std::isnan(beam.tStart));
            ASSERT_GE(beam.tStart, 0.0f);
            for (int y = tile.y0; y < tile.y1; ++y)
              for (int x = tile.x0; x < tile.x1; ++x) {
                const svo::OctreeRay ray = pixelRays(x, y);
                const glm::dvec3 d(ray.direction);
                // Reference t in octree units along the unit direction; the ray's t is world distance.
                const svotest::RefHit ref = s->cubes->first(glm::dvec3(ray.origin), glm::normalize(d));
                ++rays;
                if (!ref.hit()) continue;
                const double refT = ref.t0 / glm::length(d);
                ASSERT_LE(double(beam.tStart), refT * (1.0 + kBoundSlack))
                    << s->name << ", " << v.name << ", lod " << lod << ", tile " << tileSize << " at ("
                    << tile.x0 << ", " << tile.y0 << "), pixel (" << x << ", " << y << ")";
              }
          });
        }
      }
    }
  }
  std::printf("[ BEAM     ] %zu tiles (%zu with nothing in the beam), %zu rays checked\n", tiles, emptyTiles,
              rays);
  EXPECT_GT(emptyTiles, 0u);  // the views do include empty sky
  EXPECT_LT(emptyTiles, tiles);
}

TEST(Beam, RenderIsBitIdenticalWithAndWithoutTheBeamPass) {
  std::size_t frames = 0;
  for (const BeamScene* s : scenes()) {
    for (const View& v : viewsOf(*s)) {
      for (const float lod : {0.0f, 1.0f, 4.0f}) {
        for (const bool contours : {true, false}) {
          svo::RenderOptions plain;
          plain.lodPixels = lod;
          plain.cast.contours = contours;
          plain.beamTile = 0;
          plain.threads = 1;
          const svo::Frame reference = svo::render(s->octree, v.camera, plain);
          for (const int tile : {4, 8, 13}) {
            svo::RenderOptions beamed = plain;
            beamed.beamTile = tile;
            const svo::Frame frame = svo::render(s->octree, v.camera, beamed);
            ++frames;
            const std::string where = s->name + ", " + v.name + ", lod " + std::to_string(lod) +
                                      (contours ? ", contours" : ", cubes") + ", tile " +
                                      std::to_string(tile);
            ASSERT_EQ(frame.color.size(), reference.color.size()) << where;
            std::size_t differing = 0;
            for (std::size_t i = 0; i < frame.color.size(); ++i) {
              const bool same = frame.color[i] == reference.color[i] &&
                                frame.voxelPixels[i] == reference.voxelPixels[i] &&
                                (frame.depth[i] == reference.depth[i] ||
                                 (std::isinf(frame.depth[i]) && std::isinf(reference.depth[i])));
              differing += !same;
            }
            EXPECT_EQ(differing, 0u) << where;
          }
        }
      }
    }
  }
  std::printf("[ BEAM     ] %zu beam frames compared with their plain renders\n", frames);
}

TEST(Beam, RejectsBadTileSizes) {
  const svo::Camera camera = svo::Camera::framing(sphere().octree.transform, {0, 0, -1}, 16, 16);
  for (const int tile : {-1, 65}) {
    svo::RenderOptions options;
    options.beamTile = tile;
    try {
      (void)svo::render(sphere().octree, camera, options);
      ADD_FAILURE() << "beamTile " << tile << " was accepted";
    } catch (const std::runtime_error& e) {
      EXPECT_NE(std::string(e.what()).find("beamTile"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
