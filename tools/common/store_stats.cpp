#include "store_stats.hpp"

#include <algorithm>

namespace svo::tools {

LevelSummary summarizeSlice(const SliceInfo& s, const StoreHeader& h) {
  LevelSummary l;
  l.slices = 1;
  l.voxels = s.voxelCount;
  l.parents = s.parentCount;
  l.contours = s.contourCount;
  l.colors = s.colorCount;
  l.normals = s.normalCount;
  l.rawBytes = s.rawBytes;
  l.diskBytes = s.compressedBytes;
  const SliceParts parts = slicePartsOf(s, h.hasColors, h.hasNormals);
  l.hierarchyBytes = parts.hierarchy;
  l.contourBytes = parts.contours;
  l.colorBytes = parts.colors;
  l.normalBytes = parts.normals;
  l.smallestSlice = l.largestSlice = s.rawBytes;
  return l;
}

void add(LevelSummary& to, const LevelSummary& l) {
  to.slices += l.slices, to.voxels += l.voxels, to.parents += l.parents, to.contours += l.contours;
  to.colors += l.colors, to.normals += l.normals, to.rawBytes += l.rawBytes, to.diskBytes += l.diskBytes;
  to.hierarchyBytes += l.hierarchyBytes, to.contourBytes += l.contourBytes, to.colorBytes += l.colorBytes;
  to.normalBytes += l.normalBytes;
  to.smallestSlice = std::min(to.smallestSlice, l.smallestSlice);
  to.largestSlice = std::max(to.largestSlice, l.largestSlice);
}

}  // namespace svo::tools
