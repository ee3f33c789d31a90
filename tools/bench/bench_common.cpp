#include "bench_common.hpp"

#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <numbers>
#include <set>
#include <stdexcept>
#include <system_error>

#include <fmt/format.h>
#include <spdlog/spdlog.h>
#include <tbb/info.h>
#include <glm/geometric.hpp>

#include "bench.hpp"
#include "svo/client/render.hpp"
#include "svo/store/format.hpp"
#include "svo/store/store_writer.hpp"

namespace svo::tools {

void addBenchCommands(CLI::App& bench) {
  bench::addRaycastBench(bench);
  bench::addBuildBench(bench);
  bench::addAccelBench(bench);
  bench::addStabilityBench(bench);
  bench::addQualityBench(bench);
  bench::addStoreBench(bench);
  bench::addStreamBench(bench);
  bench::addServeBench(bench);
  bench::addDimensionBench(bench);
  bench::addVolumeBench(bench);
}

}  // namespace svo::tools

namespace svo::tools::bench {

namespace {

std::string_view trim(std::string_view s) {
  while (!s.empty() && (s.front() == ' ' || s.front() == '\t')) s.remove_prefix(1);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\t')) s.remove_suffix(1);
  return s;
}

std::vector<std::string_view> splitCommas(std::string_view text) {
  std::vector<std::string_view> parts;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = text.find(',', start);
    parts.push_back(trim(text.substr(start, comma == std::string_view::npos ? text.npos : comma - start)));
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  return parts;
}

}  // namespace

void requireRuns(int runs, std::string_view option) {
  if (runs < 1) throw UsageError(fmt::format("{} must be at least 1 (got {})", option, runs));
}

int levelsOfResolution(std::int64_t resolution, std::string_view option) {
  if (resolution < 2 || resolution > (std::int64_t(1) << kMaxLevels) || (resolution & (resolution - 1)) != 0)
    throw UsageError(fmt::format("{}: resolution {} must be a power of two between 2 and 2^{} = {}", option,
                                 resolution, kMaxLevels, std::int64_t(1) << kMaxLevels));
  int levels = 0;
  while ((std::int64_t(1) << levels) < resolution) ++levels;
  return levels;
}

std::vector<std::int64_t> parseResolutions(const std::string& text, std::string_view option) {
  std::vector<std::int64_t> resolutions;
  std::set<std::int64_t> seen;
  for (const std::string_view part : splitCommas(text)) {
    std::int64_t value = 0;
    const auto [end, ec] = std::from_chars(part.data(), part.data() + part.size(), value);
    if (part.empty() || ec != std::errc() || end != part.data() + part.size())
      throw UsageError(fmt::format("{}: '{}' in '{}' is not an integer (expected a list like 256,512,1024)",
                                   option, std::string(part), text));
    levelsOfResolution(value, option);
    if (!seen.insert(value).second)
      throw UsageError(fmt::format("{}: resolution {} repeated", option, value));
    resolutions.push_back(value);
  }
  return resolutions;
}

std::string defaultViewText() {
  return fmt::format("{},{},{}", kDefaultViewDirection.x, kDefaultViewDirection.y, kDefaultViewDirection.z);
}

glm::dvec3 parseDirection(const std::string& text, std::string_view option) {
  const auto parts = splitCommas(text);
  if (parts.size() != 3)
    throw UsageError(fmt::format("{}: '{}' is not three comma-separated numbers x,y,z", option, text));
  glm::dvec3 v;
  for (int i = 0; i < 3; ++i) {
    const std::string part(parts[i]);
    std::size_t used = 0;
    try {
      v[i] = std::stod(part, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (part.empty() || used != part.size() || !std::isfinite(v[i]))
      throw UsageError(fmt::format("{}: '{}' is not a finite number", option, part));
  }
  if (v == glm::dvec3(0.0)) throw UsageError(fmt::format("{}: the direction must not be zero", option));
  return v;
}

int resolveThreads(int requested, std::string_view option) {
  if (requested < 0)
    throw UsageError(fmt::format("{} must be 0 (all cores) or positive (got {})", option, requested));
  return requested > 0 ? requested : tbb::info::default_concurrency();
}

Mesh loadBenchMesh(const std::filesystem::path& path) {
  MeshLoadReport report;
  Mesh mesh = loadMesh(path, &report);
  spdlog::info("mesh {}: {} vertices, {} triangles, read as {}{}", path.string(),
               formatCount(mesh.positions.size()), formatCount(mesh.triangles.size()), report.format,
               report.droppedDegenerate
                   ? fmt::format(", {} degenerate triangles dropped", report.droppedDegenerate)
                   : std::string());
  return mesh;
}

ScratchPath::ScratchPath(std::string_view name) {
  const std::filesystem::path file(name);
  path_ = std::filesystem::temp_directory_path() /
          fmt::format("{}-{}{}", file.stem().string(), ::getpid(), file.extension().string());
}

ScratchPath::~ScratchPath() {
  std::error_code ignored;
  std::filesystem::remove(path_, ignored);
}

WholeScene wholeSceneOf(const VoxelTree& tree, const SceneTransform& transform,
                        const BuildParameters& parameters, const std::filesystem::path& store,
                        LayoutStats* layout, AttributeOptions attributes) {
  try {
    LayoutOptions options;
    attributes.applyTo(options);
    return WholeScene(Octree{transform, parameters, layoutBlock(tree, options, layout)});
  } catch (const BlockTooLarge&) {
  }
  spdlog::info("{} levels exceed one block: paging the whole store through a pool ...", parameters.levels);
  if (!std::filesystem::exists(store)) writeStore(store, tree, transform, parameters);
  return WholeScene::paged(store, wholeStoreBudget(StoreReader(store).slices()), attributes);
}

AttributeError attributeError(const BlockView& raw, const BlockView& compressed) {
  const VoxelTree a = readBlock(raw), b = readBlock(compressed);
  if (a.voxels.size() != b.voxels.size())
    throw std::logic_error("attributeError: the two layouts hold different octrees");
  AttributeError e;
  double colorSquares = 0.0, angles = 0.0;
  for (std::size_t i = 1; i < a.voxels.size(); ++i) {  // the root's value is stored as it is
    if (a.hasColors)
      for (int shift = 0; shift < 24; shift += 8) {
        const double d =
            double((a.voxels[i].color >> shift) & 255u) - double((b.voxels[i].color >> shift) & 255u);
        colorSquares += d * d, e.colorMax = std::max(e.colorMax, std::abs(d));
      }
    if (a.hasNormals) {
      const double cosine = glm::dot(glm::dvec3(decodeNormal(a.voxels[i].normal)),
                                     glm::dvec3(decodeNormal(b.voxels[i].normal)));
      const double degrees = std::acos(std::clamp(cosine, -1.0, 1.0)) * 180.0 / std::numbers::pi;
      angles += degrees, e.normalMaxDegrees = std::max(e.normalMaxDegrees, degrees);
    }
  }
  e.voxels = a.voxels.size() - 1;
  const double n = double(std::max<std::uint64_t>(e.voxels, 1));
  e.colorRmse = std::sqrt(colorSquares / (3.0 * n));
  e.normalMeanDegrees = angles / n;
  return e;
}

}  // namespace svo::tools::bench
