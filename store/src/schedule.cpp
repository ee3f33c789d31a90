#include "svo/store/schedule.hpp"

#include <algorithm>
#include <cmath>

namespace svo {
namespace {

// Nearest distance from p to the axis-aligned cube [lo, lo + size].
double distanceToCube(const glm::dvec3& p, const glm::dvec3& lo, double size) {
  double d2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double below = lo[a] - p[a], above = p[a] - (lo[a] + size);
    const double d = std::max({below, above, 0.0});
    d2 += d * d;
  }
  return std::sqrt(d2);
}

// False when the cube lies wholly on the outer side of one plane.
bool cubeInView(const ViewQuery& view, const glm::dvec3& lo, double size) {
  for (const auto& plane : view.frustum) {
    double best = -plane[3];
    for (int a = 0; a < 3; ++a) best += plane[a] * (plane[a] > 0.0 ? lo[a] + size : lo[a]);
    if (best < 0.0) return false;
  }
  return true;
}

}  // namespace

std::vector<SliceRequest> scheduleSlices(const std::vector<SliceInfo>& slices, const ViewQuery& view) {
  std::vector<double> priority(slices.size(), 0.0);
  std::vector<SliceRequest> wanted;
  for (std::uint32_t i = 0; i < slices.size(); ++i) {
    const SliceInfo& s = slices[i];
    const double cubeSize = std::ldexp(1.0, -s.cubeLevel);
    const glm::dvec3 lo = glm::dvec3(1.0) + glm::dvec3(s.cubeCoord) * cubeSize;
    const double parentVoxel = std::ldexp(1.0, -(s.voxelLevel - 1));
    // Inside the cube the nearest parent voxel is at most half a voxel away: no infinite sizes.
    const double nearest = std::max(distanceToCube(view.eye, lo, cubeSize), 0.5 * parentVoxel);
    SliceRequest r;
    r.slice = i;
    r.parentPixels = parentVoxel / (nearest * view.pixelAngle);
    r.inFrustum = cubeInView(view, lo, cubeSize);
    const double pixelsAtCentre = parentVoxel / ((nearest + 0.5 * cubeSize) * view.pixelAngle);
    priority[i] = pixelsAtCentre * (r.inFrustum ? 1.0 : view.outsideWeight);
    // Never above the slice holding the parents (the reader guarantees it comes first).
    if (s.parentSlice != SliceInfo::kNoSlice && s.parentSlice < i)
      priority[i] = std::min(priority[i], priority[s.parentSlice]);
    r.priority = priority[i];
    if (r.parentPixels > view.lodPixels) wanted.push_back(r);
  }
  std::stable_sort(wanted.begin(), wanted.end(), [&](const SliceRequest& a, const SliceRequest& b) {
    if (a.priority != b.priority) return a.priority > b.priority;
    return slices[a.slice].voxelLevel < slices[b.slice].voxelLevel;
  });
  return wanted;
}

}  // namespace svo
