// Beam optimization (paper sec. 6.2): before the rays of a pixel tile are cast, one coarse pass over the
// tile's beam finds a distance before which no ray of the tile can meet a voxel, and every ray starts there.
//
// The paper casts coarse rays at the tile corners, which can step past a voxel that pokes into the beam
// between them. Here the coarse pass tests whole cubes against the beam's four side planes instead, so the
// bound is conservative: a ray's result is the same with and without the beam, and a tile whose beam meets
// no voxel casts no ray at all.
#pragma once

#include "svo/client/raycast.hpp"

namespace svo {

class PixelRays;
struct LevelRegion;

// Pixels [x0, x1) x [y0, y1) of the image.
struct PixelTile {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;
};

struct BeamResult {
  float tStart = 0.0f;  // no ray of the tile meets a voxel before this t; +infinity: none meets any
  int cubesTested = 0;  // coarse-pass work, for statistics
};

// The coarse pass over `tile`. Cube voxels only (contours can only remove parts of a cube), and it stops
// at voxels as coarse as the fine rays' own level-of-detail stop, so it never cuts a fine ray short.
BeamResult castBeam(const BlockView& block, const PixelRays& rays, const PixelTile& tile);
// The same pass over level arrays (level_raycast.hpp): the regions linked from `root`, the root's region. It
// reads the octree as their caster does, so its result is the block's on the same octree.
BeamResult castBeam(const LevelRegion& root, const PixelRays& rays, const PixelTile& tile);

}  // namespace svo
