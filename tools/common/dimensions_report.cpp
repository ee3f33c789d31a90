#include "dimensions_report.hpp"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>
#include <glm/geometric.hpp>

#include "plot.hpp"
#include "report.hpp"

namespace svo::tools {
namespace {

// Lines a plot panel draws at most: the plot's palette has ten colors, and more lines would repeat them.
constexpr int kMostPlottedCubeLevels = 10;

std::string formatDimension(double d) {
  return std::isfinite(d) ? fmt::format("{:.2f}", d) : "";
}

// log2 of N at the second view's levels over N at the first's: both whole levels, cubes beyond the scene
// (c < 0) holding all of it as the scene cube does.
double stepDimension(const VoxelDimensions& dims, ViewLevels from, ViewLevels to) {
  const int f = dims.finestLevel();
  if (from.voxel < 0 || to.voxel < 0 || from.voxel > f || to.voxel > f) return NAN;
  const auto n = [&](ViewLevels v) { return dims.count(std::max(0, int(v.cube)), int(v.voxel)); };
  return std::log2(n(to) / n(from));
}

// The cube levels the plot draws a line for: all of them, or as many as it can, spread from the scene
// cube to the finest.
std::vector<int> plottedCubeLevels(int finest) {
  std::vector<int> levels;
  const int count = std::min(finest, kMostPlottedCubeLevels);
  for (int i = 0; i < count; ++i) {
    const int c = count == 1 ? 0 : int(std::lround(double(i) * double(finest - 1) / double(count - 1)));
    if (levels.empty() || levels.back() != c) levels.push_back(c);
  }
  return levels;
}

}  // namespace

std::vector<double> decodedBytesPerVoxel(const StoreIndex& index, int finestLevel) {
  std::vector<double> bytes(std::size_t(finestLevel + 1), 0.0), voxels(bytes.size(), 0.0);
  for (const SliceInfo& s : index.slices())
    if (s.voxelLevel <= finestLevel) {
      bytes[std::size_t(s.voxelLevel)] += double(s.rawBytes);
      voxels[std::size_t(s.voxelLevel)] += double(s.voxelCount);
    }
  for (std::size_t l = 0; l < bytes.size(); ++l) bytes[l] = voxels[l] > 0.0 ? bytes[l] / voxels[l] : 0.0;
  return bytes;
}

ViewLevels viewLevels(double voxelLevel, double pixels, double lodPixels) {
  return {voxelLevel - std::log2(pixels / lodPixels), voxelLevel};
}

ViewLevels viewLevelsOf(const SceneTransform& scene, const Camera& camera, double lodPixels) {
  // Octree units: the scene cube's edge is 1, a voxel of level L 2^-L wide.
  const double distance = glm::length(camera.target - camera.eye) / scene.size;
  const double pixel = camera.pixelAngle() * distance;  // a pixel's width at the target
  return {-std::log2(pixel * double(std::max(camera.width, camera.height))),
          -std::log2(lodPixels * pixel) + kLoadedLevelOffset};
}

std::vector<PredictedView> predictViews(const VoxelDimensions& dims, std::span<const double> weights,
                                        ViewLevels base, int steps) {
  const double baseData = dims.viewData(base.cube, base.voxel, weights);
  std::vector<PredictedView> views;
  const auto add = [&](double distance, double size, ViewLevels levels, ViewLevels previous) {
    PredictedView v{distance, size, levels, NAN,
                    dims.viewData(levels.cube, levels.voxel, weights) / baseData};
    if (!views.empty()) v.dimension = stepDimension(dims, previous, levels);
    views.push_back(v);
  };
  add(1.0, 1.0, base, base);
  for (int k = 1; k <= steps; ++k)
    add(std::ldexp(1.0, k), 1.0, {base.cube - k, base.voxel - k}, {base.cube - k + 1, base.voxel - k + 1});
  for (int k = 1; k <= steps; ++k)
    add(1.0, std::ldexp(1.0, k), {base.cube, base.voxel + k}, {base.cube, base.voxel + k - 1});
  return views;
}

void printDimensions(const VoxelDimensions& dims, std::FILE* out) {
  const int f = dims.finestLevel();
  std::vector<std::string> header{"cube \\ voxel level"};
  for (int l = 1; l <= f; ++l) header.push_back(std::to_string(l));
  // Rows from `firstCube`: the global and scale dimensions have none for the scene cube (nothing above it).
  const auto grid = [&](const std::string& title, int firstCube, auto cell) {
    printTitle(title, out);
    Table table(header);
    for (int c = firstCube; c < f; ++c) {
      std::vector<std::string> row{std::to_string(c)};
      for (int l = 1; l <= f; ++l) row.push_back(cell(c, l));
      table.addRow(row);
    }
    table.print(out);
  };
  std::vector<std::string> levels{"voxel level"}, totals{"voxels"};
  for (int l = 1; l <= f; ++l)
    levels.push_back(std::to_string(l)), totals.push_back(formatCount(dims.voxels(l)));
  Table perLevel(levels);
  perLevel.addRow(totals);
  printTitle("voxels per level", out);
  perLevel.print(out);
  grid("N(c, L): mean voxels of level L in a cube of level c around a point of the content", 0,
       [&](int c, int l) { return c < l ? fmt::format("{:.4g}", dims.count(c, l)) : ""; });
  grid("D_local(c, L) = log2 N(c, L) / N(c, L-1): voxels halved", 0,
       [&](int c, int l) { return formatDimension(dims.local(c, l)); });
  grid("D_global(c, L) = log2 N(c-1, L) / N(c, L): cube doubled", 1,
       [&](int c, int l) { return formatDimension(dims.global(c, l)); });
  grid("D_scale(c, L) = log2 N(c-1, L-1) / N(c, L) = D_global(c, L) - D_local(c-1, L): both", 1,
       [&](int c, int l) { return formatDimension(dims.scale(c, l)); });
  fmt::print(out,
             "levels: a cube of level c is 2^-c of the scene cube wide, a voxel of level L 2^-L (the paper's "
             "l = -c, s = -L); the points are the {} voxels of level {}, each one's cube the octree's cube "
             "of level c holding it\n",
             formatCount(dims.voxels(f)), f);
}

void printPrediction(const std::vector<PredictedView>& views, const std::string& base, std::FILE* out) {
  printTitle("prediction: the data a view needs, relative to " + base, out);
  Table table({"view", "cube level", "voxel level", "step D", "step x", "relative data"});
  for (const PredictedView& v : views) {
    const std::string name = v.distance == 1.0 && v.size == 1.0 ? "d, w (base)"
                             : v.size == 1.0                    ? fmt::format("{:g}d", v.distance)
                                                                : fmt::format("{:g}w", v.size);
    table.addRow({name, fmt::format("{:.2f}", v.levels.cube), fmt::format("{:.2f}", v.levels.voxel),
                  formatDimension(v.dimension),
                  std::isfinite(v.dimension) ? fmt::format("{:.3g}", std::exp2(v.dimension)) : "",
                  fmt::format("{:.3g}", v.relative)});
  }
  table.print(out);
  fmt::print(
      out,
      "d: distance, w: image size; a doubled distance doubles the view's cube and its voxels (step D = "
      "D_scale), a doubled image size halves its voxels (step D = D_local); relative data: decoded "
      "bytes of every level down to the resolved one in the view's cube, cubes beyond the scene "
      "holding all of it, levels beyond the finest none more\n");
}

nlohmann::json dimensionsJson(const VoxelDimensions& dims, const std::vector<PredictedView>& views) {
  nlohmann::json j;
  const int f = dims.finestLevel();
  j["finestLevel"] = f;
  for (int l = 0; l <= f; ++l) j["voxels"].push_back(dims.voxels(l));
  const auto finite = [](double d) { return std::isfinite(d) ? nlohmann::json(d) : nlohmann::json(nullptr); };
  for (int c = 0; c < f; ++c)
    for (int l = c + 1; l <= f; ++l)
      j["cubes"].push_back({{"cubeLevel", c},
                            {"voxelLevel", l},
                            {"N", dims.count(c, l)},
                            {"local", finite(dims.local(c, l))},
                            {"global", finite(dims.global(c, l))},
                            {"scale", finite(dims.scale(c, l))}});
  for (const PredictedView& v : views)
    j["prediction"].push_back({{"distance", v.distance},
                               {"size", v.size},
                               {"cubeLevel", v.levels.cube},
                               {"voxelLevel", v.levels.voxel},
                               {"stepDimension", finite(v.dimension)},
                               {"relativeData", v.relative}});
  return j;
}

std::filesystem::path writeDimensionsPlot(const std::filesystem::path& folder, const VoxelDimensions& dims) {
  const int f = dims.finestLevel();
  std::vector<plot::Panel> panels{{"log2 N(c, L): voxels of level L per cube of level c", {}},
                                  {"D_local(c, L): voxels halved", {}},
                                  {"D_global(c, L): cube doubled", {}},
                                  {"D_scale(c, L): cube doubled and voxels halved", {}}};
  for (const int c : plottedCubeLevels(f)) {
    const std::string name = fmt::format("cube level {}", c);
    std::vector<plot::Series> series(panels.size(), plot::Series{name, {}});
    for (int l = c + 1; l <= f; ++l) {
      series[0].points.push_back({double(l), std::log2(dims.count(c, l))});
      series[1].points.push_back({double(l), dims.local(c, l)});
      series[2].points.push_back({double(l), dims.global(c, l)});
      series[3].points.push_back({double(l), dims.scale(c, l)});
    }
    for (std::size_t p = 0; p < panels.size(); ++p) panels[p].series.push_back(std::move(series[p]));
  }
  const std::filesystem::path png = folder / "dimensions.png";
  plot::writePlot(png, panels, "voxel level L (voxels 2^-L of the scene cube wide)", "", plot::Scale::Linear,
                  plot::Scale::Linear);
  return png;
}

}  // namespace svo::tools
