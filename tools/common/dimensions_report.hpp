// The dimensional analysis (svo/store/dimensions.hpp) as the commands show it: `svo inspect --dimensions`
// prints N and the D values per cube and voxel level, plots them and predicts how a view's data changes
// with its distance and image size; `svo bench dimensions` checks that prediction against a pager.
#pragma once

#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "svo/client/render.hpp"
#include "svo/store/dimensions.hpp"

namespace svo::tools {

// Decoded slice bytes per voxel of each level 0 to the finest, from the directory: what a voxel of that
// level weighs in a view's data (VoxelDimensions::viewData). The root has no slice and weighs nothing.
std::vector<double> decodedBytesPerVoxel(const StoreIndex& index, int finestLevel);

// Where a view stands in the analysis: the voxel level it resolves and the cube level of its extent.
struct ViewLevels {
  double cube = 0.0, voxel = 0.0;
};
// A view `pixels` wide resolving `voxelLevel` with voxels `lodPixels` wide spans pixels / lodPixels voxels
// of that level.
ViewLevels viewLevels(double voxelLevel, double pixels, double lodPixels);
// Where voxels of level x look lodPixels wide, a pager loads down to the first whole level whose voxels are
// at most that wide, ceil(x) (the view query, svo/store/schedule.hpp): over content spread in distance,
// half a level finer than x on average.
inline constexpr double kLoadedLevelOffset = 0.5;
// A camera's, at its target: the level it loads there (the level whose voxels look `lodPixels` wide, plus
// kLoadedLevelOffset), and the cube as wide as the image there.
ViewLevels viewLevelsOf(const SceneTransform& scene, const Camera& camera, double lodPixels);

// One view of a prediction: `distance` and `size` are multiples of the base view's.
struct PredictedView {
  double distance = 1.0, size = 1.0;
  ViewLevels levels;
  // log2 of the step's change in N at the resolved level: D_scale for a doubled distance, D_local for a
  // doubled image size; NaN for the base view and where a level lies outside the store.
  double dimension = NAN;
  double relative = 1.0;  // the view's data (every level down to the resolved one) over the base view's
};
// The base view and `steps` doublings of its distance, then `steps` doublings of its image size.
std::vector<PredictedView> predictViews(const VoxelDimensions& dims, std::span<const double> weights,
                                        ViewLevels base, int steps);

// The tables of N, D_local, D_global and D_scale per cube level (rows) and voxel level (columns).
void printDimensions(const VoxelDimensions& dims, std::FILE* out = stdout);
// The prediction as a table; `base` says what the base view is.
void printPrediction(const std::vector<PredictedView>& views, const std::string& base,
                     std::FILE* out = stdout);
nlohmann::json dimensionsJson(const VoxelDimensions& dims, const std::vector<PredictedView>& views);
// dimensions.png (with .csv and .gp) in `folder`: log2 N and the three dimensions against the voxel level,
// one line per cube level. Returns the PNG's path.
std::filesystem::path writeDimensionsPlot(const std::filesystem::path& folder, const VoxelDimensions& dims);

}  // namespace svo::tools
