// The coarse pass of the beam optimization (sec. 6.2), as a front-to-back walk of the octree that keeps the
// cubes meeting the tile's beam (the pyramid of the four corner rays through the pixel edges) and stops at
// cubes as small as the beam is wide at their far side. The nearest such cube's distance bounds every fine
// ray of the tile from below.
#include "svo/client/beam.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <glm/geometric.hpp>

#include "level_descent.hpp"
#include "svo/client/render.hpp"

namespace svo {
namespace {

using glm::dvec3;
using namespace ray_setup;

// The beam's edges lie this many pixels outside the tile's outer pixel edges, far more than the float
// rounding of a fine ray's direction (2^-24 relative, against a pixel of ~1e-3 radians).
constexpr double kEdgeMarginPixels = 1.0 / 64.0;
// Cubes are grown by this much (octree units, ~16 float ulps in [1, 2]) before the plane and distance
// tests, so a fine ray that meets a cube only through its float rounding is still accounted for.
constexpr double kCubeMargin = 1.0 / double(1 << 20);
// The fine rays start this fraction of the bound earlier ("minus an appropriate constant", sec. 6.2): the
// float t-values of a fine ray's cube entries may round below the exact distance.
constexpr double kStartMargin = 1.0 / 1024.0;
// The coarse pass stops at cubes no larger than this many times the fine rays' level-of-detail footprint,
// so it always stops at or above the voxel a fine ray would stop at, float rounding included.
constexpr double kLodSafety = 2.0;

struct Beam {
  dvec3 eye;
  std::array<dvec3, 4> inward;  // normals of the four side planes through the eye, pointing into the beam
  double stopSlope = 0.0;       // stop at cubes no larger than stopSlope * (distance to their far corner)
};

Beam beamOf(const PixelRays& rays, const PixelTile& tile) {
  const double m = 0.5 + kEdgeMarginPixels;  // pixel centres sit at +0.5
  const double x0 = tile.x0 - m, x1 = tile.x1 - 1 + m, y0 = tile.y0 - m, y1 = tile.y1 - 1 + m;
  // Corners in order around the tile; the image plane maps the tile's rectangle to a convex quad of rays.
  const std::array<dvec3, 4> corner = {rays.direction(x0, y0), rays.direction(x1, y0), rays.direction(x1, y1),
                                       rays.direction(x0, y1)};
  const dvec3 centre = rays.direction(0.5 * (x0 + x1), 0.5 * (y0 + y1));
  Beam beam;
  beam.eye = dvec3(rays.origin());
  for (int i = 0; i < 4; ++i) {
    dvec3 n = glm::cross(corner[i], corner[(i + 1) % 4]);
    if (glm::dot(n, centre) < 0.0) n = -n;
    beam.inward[i] = n;
  }
  // The beam's width per unit distance, and the fine rays' footprint (sec. 6.1) with a safety factor: the
  // coarser of the two decides where the walk may stop.
  const double tilePixels = std::max(tile.x1 - tile.x0, tile.y1 - tile.y0);
  const double beamSlope = tilePixels * rays.camera().pixelAngle();
  const double lodSlope = kLodSafety * double(rays.footprintSlope()) * rays.sceneSize();
  beam.stopSlope = std::max(beamSlope, lodSlope);
  return beam;
}

// False when the (grown) cube lies wholly outside one side plane of the beam.
bool meetsBeam(const Beam& beam, const dvec3& lo, double size) {
  for (const dvec3& n : beam.inward) {
    // The cube's corner furthest into the plane's inner side.
    const dvec3 p(n.x > 0.0 ? lo.x + size : lo.x, n.y > 0.0 ? lo.y + size : lo.y,
                  n.z > 0.0 ? lo.z + size : lo.z);
    if (glm::dot(n, p - beam.eye) < 0.0) return false;
  }
  return true;
}

// Distance from the eye to the nearest and to the furthest point of the cube.
void cubeDistances(const dvec3& eye, const dvec3& lo, double size, double& nearest, double& furthest) {
  const dvec3 hi = lo + size;
  const dvec3 below = glm::max(lo - eye, dvec3(0.0)), above = glm::max(eye - hi, dvec3(0.0));
  nearest = glm::length(below + above);
  furthest = glm::length(glm::max(glm::abs(eye - lo), glm::abs(hi - eye)));
}

// The walk, reading the octree through `Descent` (ray_setup.hpp): a node's valid mask, and which children
// have children of their own, as the ray caster reads them, so that it stops where a fine ray would.
template <class Descent>
BeamResult walkBeam(typename Descent::Node root, const PixelRays& rays, const PixelTile& tile) {
  using Node = typename Descent::Node;
  BeamResult result;
  const Beam beam = beamOf(rays, tile);
  struct Entry {
    Node node;
    int scale;  // of the node's children (ray_setup's scale: kScaleMax - 1 below the root)
    dvec3 lo;
    double size;
    double nearest;
  };
  // Depth-first, nearest child on top: a path of at most kMaxLevels voxels with up to 7 siblings each.
  std::array<Entry, 8 * kMaxLevels> stack;
  int top = 0;
  double best = std::numeric_limits<double>::infinity();
  {
    const dvec3 lo(1.0 - kCubeMargin);
    const double size = 1.0 + 2.0 * kCubeMargin;
    ++result.cubesTested;
    if (!meetsBeam(beam, lo, size)) {
      result.tStart = std::numeric_limits<float>::infinity();
      return result;
    }
    double nearest, furthest;
    cubeDistances(beam.eye, lo, size, nearest, furthest);
    stack[top++] = {root, kScaleMax - 1, dvec3(1.0), 1.0, nearest};
  }
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.nearest >= best) continue;
    const typename Descent::Parent words = Descent::read(e.node, e.scale);
    const std::uint8_t valid = words.validMask;
    const double half = 0.5 * e.size;
    struct Child {
      int slot;
      double nearest;
      Node node;
    };
    std::array<Child, 8> children;
    int count = 0;
    for (int slot = 0; slot < 8; ++slot) {
      if (!(valid >> slot & 1u)) continue;
      const dvec3 lo = e.lo + half * dvec3(slot & 1, slot >> 1 & 1, slot >> 2 & 1);
      const dvec3 grownLo = lo - kCubeMargin;
      const double grownSize = half + 2.0 * kCubeMargin;
      ++result.cubesTested;
      if (!meetsBeam(beam, grownLo, grownSize)) continue;
      double nearest, furthest;
      cubeDistances(beam.eye, grownLo, grownSize, nearest, furthest);
      if (nearest >= best) continue;
      // A leaf (or a pool's voxel whose children are not resident), or a voxel as small as the beam (and
      // the fine rays' footprint) at its far side: some fine ray may stop in it, no earlier than its nearest
      // point.
      Node child;
      if (!Descent::child(e.node, words, slot, e.scale, child) || half <= beam.stopSlope * furthest) {
        best = nearest;
        continue;
      }
      children[count++] = {slot, nearest, child};
    }
    // Push the furthest first so the nearest child is walked next; pruning by `best` then cuts the rest.
    // (Insertion sort: at most 8 entries.)
    for (int i = 1; i < count; ++i)
      for (int j = i; j > 0 && children[j - 1].nearest < children[j].nearest; --j)
        std::swap(children[j - 1], children[j]);
    for (int i = 0; i < count; ++i) {
      const Child& c = children[i];
      if (c.nearest >= best) continue;
      const dvec3 lo = e.lo + half * dvec3(c.slot & 1, c.slot >> 1 & 1, c.slot >> 2 & 1);
      stack[top++] = {c.node, e.scale - 1, lo, half, c.nearest};
    }
  }
  // Octree distance to ray t: the fine rays' direction is the unit world direction / scene size.
  result.tStart = std::isfinite(best) ? float(best * rays.sceneSize() * (1.0 - kStartMargin))
                                      : std::numeric_limits<float>::infinity();
  return result;
}

}  // namespace

BeamResult castBeam(const BlockView& block, const PixelRays& rays, const PixelTile& tile) {
  return walkBeam<BlockDescent>(block.root(), rays, tile);
}

BeamResult castBeam(const LevelRegion& root, const PixelRays& rays, const PixelTile& tile) {
  if (!root.hasChildren()) return {.tStart = std::numeric_limits<float>::infinity()};
  return walkBeam<LevelDescent>(LevelNode{&root, 0}, rays, tile);
}

}  // namespace svo
