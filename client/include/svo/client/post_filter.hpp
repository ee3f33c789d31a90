// The post-process filter (sec. 6.3, Fig. 19): an adaptive blur that hides the blocks of voxels wider than a
// pixel. Each pixel asks for a radius from its voxel's size on screen; the blur gathers samples of a fixed
// kernel in order of distance, shrinking the radius to the smallest one any sample asks for, so the radius
// changes smoothly across octree levels and never reaches over a silhouette into the background.
#pragma once

#include <vector>

#include "svo/client/render.hpp"

namespace svo {

// One sample of the kernel: a pixel offset, its distance and the disc area it stands for.
struct FilterSample {
  int dx = 0, dy = 0;
  float distance = 0.0f;
  float weight = 0.0f;
};

// The pixel itself and 96 samples around it (48 mirrored pairs, so a linear ramp stays unshifted) within
// 24 pixels, sorted by distance; the density falls with the square root of distance (sec. 6.3).
const std::vector<FilterSample>& postFilterKernel();

struct PostFilterOptions {
  float radiusPerVoxel = kPostFilterRadiusPerVoxel;
  int threads = 0;  // 0 = all cores
};

// Filters frame.color of hit pixels in place (alpha, depth and misses are left as they are) from
// frame.voxelPixels. Pixels asking for a radius of one pixel or less keep their colour bit for bit. Throws
// std::invalid_argument when the frame's arrays do not match its size or the options are out of range.
void postFilter(Frame& frame, const PostFilterOptions& options = {});

}  // namespace svo
