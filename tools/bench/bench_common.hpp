// Shared pieces of `svo bench`: argument validation, repeated timing with median / min / max, scratch files
// and scenes. Each bench is one bench_*.cpp; the peers' headers (Embree, OpenVDB) stay inside the .cpp files
// that use them.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <CLI/CLI.hpp>
#include <glm/vec3.hpp>

#include "report.hpp"
#include "svo/builder/mesh.hpp"
#include "svo/client/whole_scene.hpp"
#include "usage.hpp"

namespace svo::tools::bench {

// Shown in place of a peer's numbers when the binary was built without SVO_BENCH_PEERS.
inline constexpr std::string_view kPeerNotBuilt = "peer not built";

// Errors drawn on a log axis are clamped up to this, so that an exact match stays on the plot.
inline constexpr double kSmallestPlottedError = 1e-4;

// Registered by addBenchCommands (bench_common.cpp).
void addRaycastBench(CLI::App& bench);    // bench_raycast.cpp
void addBuildBench(CLI::App& bench);      // bench_build.cpp
void addAccelBench(CLI::App& bench);      // bench_accel.cpp
void addStabilityBench(CLI::App& bench);  // bench_stability.cpp
void addQualityBench(CLI::App& bench);    // bench_quality.cpp
void addStoreBench(CLI::App& bench);      // bench_store.cpp
void addStreamBench(CLI::App& bench);     // bench_stream.cpp
void addServeBench(CLI::App& bench);      // bench_serve.cpp
void addDimensionBench(CLI::App& bench);  // bench_dimensions.cpp
void addVolumeBench(CLI::App& bench);     // bench_volume.cpp

// ----- the OpenVDB peer of a build (bench_build.cpp; shared by `bench build` and `bench store`) ----------
// OpenVDB's default narrow-band half width, in voxels (LEVEL_SET_HALF_WIDTH).
inline constexpr float kLevelSetHalfWidth = 3.0f;
struct LevelSetResult {
  Summary seconds;
  std::uint64_t activeVoxels = 0;  // of the last run's narrow band
  std::uint64_t memoryBytes = 0;   // Grid::memUsage of the last run
};
// `runs` timed calls of OpenVDB tools::meshToLevelSet<FloatGrid> over the mesh with voxels of `voxelSize`,
// points taken relative to `corner` (the scene cube's) so that the voxel grid lines up with the octree's.
// Threads: what the calling context allows TBB. nullopt when built without SVO_BENCH_PEERS.
std::optional<LevelSetResult> openVdbLevelSet(const Mesh& mesh, glm::dvec3 corner, double voxelSize,
                                              int runs);

// ----- `bench build --ranks`: the out-of-core build under mpirun (bench_build_mpi.cpp) -------------------
struct MpiBuildBenchArgs {
  std::string mesh;
  int levels = 0, cellLevel = 0, runs = 1;
  std::vector<int> ranks;
};
// `svo build` of the mesh as one plain process and under `mpirun -n R` for each R, one thread a rank: wall
// times, efficiency, MPI's own overhead, the serial part and the speed-up it allows (Amdahl).
void runMpiBuildBench(const MpiBuildBenchArgs& args);

// Wall-clock seconds of one call of `f`.
template <class F>
double timeSeconds(F&& f) {
  const auto start = std::chrono::steady_clock::now();
  f();
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Several methods timed over the same runs: one warm-up each, then each run times every method in turn, so a
// slow spell of a shared machine falls on all of them alike and their ratios stay fair. One summary per
// method.
template <class... F>
std::array<Summary, sizeof...(F)> timeInterleaved(int runs, F&&... methods) {
  (methods(), ...);  // warm-up: page faults, TBB workers, caches
  std::array<std::vector<double>, sizeof...(F)> samples;
  for (int i = 0; i < runs; ++i) {
    std::size_t m = 0;
    ((samples[m++].push_back(timeSeconds(methods))), ...);
  }
  std::array<Summary, sizeof...(F)> summaries;
  for (std::size_t m = 0; m < sizeof...(F); ++m) summaries[m] = summarize(std::move(samples[m]));
  return summaries;
}

// One warm-up, then `runs` timed runs of `run`; only the call itself is timed.
template <class F>
Summary timeRuns(int runs, F&& run) {
  return timeInterleaved(runs, std::forward<F>(run))[0];
}

// ----- argument validation: each throws UsageError with one line naming the option -----------------------
void requireRuns(int runs, std::string_view option = "--runs");
// A power of two in [2, 2^kMaxLevels]; returns log2.
int levelsOfResolution(std::int64_t resolution, std::string_view option);
// "256,512,1024" -> {256, 512, 1024}; each entry validated by levelsOfResolution, duplicates rejected.
std::vector<std::int64_t> parseResolutions(const std::string& text, std::string_view option);
// "x,y,z" -> a finite, non-zero vector.
glm::dvec3 parseDirection(const std::string& text, std::string_view option);
// kDefaultViewDirection (the default view of `svo render`) as parseDirection reads it.
std::string defaultViewText();
// Threads for the TBB arena: `requested` when > 0, else every core TBB sees. Throws on a negative count.
int resolveThreads(int requested, std::string_view option = "--threads");

// Loads the mesh (svo::loadMesh) and logs what was read. Throws std::runtime_error on failure.
Mesh loadBenchMesh(const std::filesystem::path& path);

// A file name in the system's temporary folder, unique to this process, removed with the object however the
// bench ends.
class ScratchPath {
 public:
  explicit ScratchPath(std::string_view name);  // "svo-bench-raycast.svo" -> /tmp/svo-bench-raycast-PID.svo
  ~ScratchPath();
  ScratchPath(const ScratchPath&) = delete;
  ScratchPath& operator=(const ScratchPath&) = delete;
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// A voxel tree at every depth, its attributes laid out as `attributes` says: as one block (`layout` receives
// its stats), or where it does not fit one, paged whole from the store at `store`, which is written from the
// tree when absent (the caller removes it after the scene).
WholeScene wholeSceneOf(const VoxelTree& tree, const SceneTransform& transform,
                        const BuildParameters& parameters, const std::filesystem::path& store,
                        LayoutStats* layout = nullptr, AttributeOptions attributes = {});

// The error of the compressed attribute layout against the raw one, voxel by voxel (readBlock of both):
// colors in 8-bit units over the RGB channels, normals in degrees.
struct AttributeError {
  double colorRmse = 0.0, colorMax = 0.0;
  double normalMeanDegrees = 0.0, normalMaxDegrees = 0.0;
  std::uint64_t voxels = 0;
};
AttributeError attributeError(const BlockView& raw, const BlockView& compressed);

}  // namespace svo::tools::bench
