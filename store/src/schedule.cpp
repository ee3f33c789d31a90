#include "svo/store/schedule.hpp"

#include <algorithm>
#include <cmath>

namespace svo {
namespace {

// Nearest distance from p to the box.
double distanceToBox(const glm::dvec3& p, const SliceBox& box) {
  double d2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double d = std::max({box.lower[a] - p[a], p[a] - box.upper[a], 0.0});
    d2 += d * d;
  }
  return std::sqrt(d2);
}

// False when the box lies wholly on the outer side of one plane.
bool boxInView(const ViewQuery& view, const SliceBox& box) {
  for (const auto& plane : view.frustum) {
    double best = -plane[3];
    for (int a = 0; a < 3; ++a) best += plane[a] * (plane[a] > 0.0 ? box.upper[a] : box.lower[a]);
    if (best < 0.0) return false;
  }
  return true;
}

}  // namespace

std::vector<SliceRequest> scheduleSlices(const StoreIndex& index, const ViewQuery& view,
                                         std::size_t* visited) {
  const std::vector<SliceInfo>& slices = index.slices();
  std::vector<SliceRequest> wanted;
  // Depth first: a slice is looked at once its parent slice is wanted, and carries the parent's priority.
  struct Visit {
    std::uint32_t slice;
    double parentPriority;
  };
  std::vector<Visit> stack;
  for (const std::uint32_t root : index.rootSlices()) stack.push_back({root, HUGE_VAL});
  std::size_t looked = 0;
  while (!stack.empty()) {
    const auto [i, parentPriority] = stack.back();
    stack.pop_back();
    ++looked;
    const SliceInfo& s = slices[i];
    const SliceBox box = sliceBox(s);
    const double parentVoxel = std::ldexp(1.0, -(s.voxelLevel - 1));
    // Inside the box the nearest parent voxel is at most half a voxel away: no infinite sizes.
    const double nearest = std::max(distanceToBox(view.eye, box), 0.5 * parentVoxel);
    SliceRequest r;
    r.slice = i;
    r.parentPixels = parentVoxel / (nearest * view.pixelAngle);
    r.inFrustum = boxInView(view, box);
    const glm::dvec3 extent = box.upper - box.lower;
    const double halfExtent = 0.5 * std::max({extent.x, extent.y, extent.z});
    const double pixelsAtCentre = parentVoxel / ((nearest + halfExtent) * view.pixelAngle);
    // Never above the slice holding the parents.
    r.priority = std::min(pixelsAtCentre * (r.inFrustum ? 1.0 : view.outsideWeight), parentPriority);
    if (!(r.parentPixels > view.lodPixels)) continue;
    wanted.push_back(r);
    for (const std::uint32_t child : index.childSlices(i)) stack.push_back({child, r.priority});
  }
  if (visited) *visited = looked;
  std::sort(wanted.begin(), wanted.end(), [&](const SliceRequest& a, const SliceRequest& b) {
    if (a.priority != b.priority) return a.priority > b.priority;
    if (slices[a.slice].voxelLevel != slices[b.slice].voxelLevel)
      return slices[a.slice].voxelLevel < slices[b.slice].voxelLevel;
    return a.slice < b.slice;
  });
  return wanted;
}

}  // namespace svo
