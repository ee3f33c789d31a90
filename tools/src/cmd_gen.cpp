// `svo gen KIND --triangles N --seed S -o scene.ply`: procedural test scenes (fractal terrain, a city of
// boxes, a hairball of thin tubes, a bumpy sphere), deterministic from the seed, streamed to binary PLY.
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <optional>

#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "commands.hpp"
#include "progress.hpp"
#include "report.hpp"
#include "stability.hpp"
#include "svo/builder/gen.hpp"

namespace svo::tools {
namespace {

// Upper bound of the generated mesh's memory per triangle: the city has 0.8 vertices per triangle at 40 bytes
// (double position + float RGBA) plus 12 bytes of indices per triangle; the other kinds need less.
constexpr double kMeshBytesPerTriangle = 48.0;
// Below this many triangles generating and writing take well under a second: no progress bar.
constexpr std::uint64_t kProgressTriangles = 1'000'000;

double physicalMemoryBytes() {
  const long pages = ::sysconf(_SC_PHYS_PAGES), pageSize = ::sysconf(_SC_PAGE_SIZE);
  return pages > 0 && pageSize > 0 ? double(pages) * double(pageSize) : 0.0;
}

std::string lowerExtension(const std::filesystem::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

struct GenArgs {
  std::string kind, triangles = "1M", out;
  std::uint64_t seed = 1;
};

GenOptions validate(const GenArgs& args) {
  GenOptions options;
  const std::optional<SceneKind> kind = parseSceneKind(args.kind);
  if (!kind)
    throw UsageError(fmt::format("unknown scene kind '{}' (expected one of {})", args.kind, sceneKindList()));
  options.kind = *kind;
  const std::optional<std::uint64_t> count = parseCount(args.triangles);
  if (!count)
    throw UsageError(fmt::format("--triangles: '{}' is not a count (like 20000, 500k, 20M)", args.triangles));
  if (*count < kMinGenTriangles || *count > kMaxGenTriangles)
    throw UsageError(
        fmt::format("--triangles {} is outside [{}, {}]", *count, kMinGenTriangles, kMaxGenTriangles));
  const double need = double(*count) * kMeshBytesPerTriangle, have = physicalMemoryBytes();
  if (have > 0.0 && need > have)
    throw UsageError(
        fmt::format("--triangles {}: the mesh would need about {:.1f} GiB, this machine has {:.1f} GiB",
                    *count, need / double(1 << 30), have / double(1 << 30)));
  options.triangles = *count;
  options.seed = args.seed;
  const std::filesystem::path out(args.out);
  const std::string ext = lowerExtension(out);
  if (ext != ".ply" && ext != ".glb")
    throw UsageError(fmt::format("{}: the output must be a .ply or .glb file", args.out));
  checkWritableOutput(out);
  return options;
}

// `svo gen stiff -o DIR`: every stiff case of `svo bench stability` (stability.hpp) as DIR/NAME.ply, so
// other tools can be pointed at them.
void runGenStiff(const GenArgs& args) {
  const std::filesystem::path dir(args.out);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec || !std::filesystem::is_directory(dir))
    throw UsageError(fmt::format("{}: cannot create the output folder ({})", args.out, ec.message()));
  for (const StiffCase& c : stiffCases(1)) {
    std::string slug = c.name;
    for (char& ch : slug)
      if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '-';
    const std::filesystem::path file = dir / (slug + ".ply");
    writePly(file, c.mesh, fmt::format("svo gen stiff: {} ({} levels): {}", c.name, c.levels, c.what));
    std::printf("wrote %s: %zu triangles, %d levels: %s\n", file.c_str(), c.mesh.triangles.size(), c.levels,
                c.what.c_str());
  }
}

void runGen(const GenArgs& args) {
  if (args.kind == "stiff") return runGenStiff(args);
  GenOptions options = validate(args);
  const bool bars = options.triangles >= kProgressTriangles;
  const auto start = std::chrono::steady_clock::now();
  Mesh mesh;
  {
    std::optional<ProgressBar> bar;
    if (bars) bar.emplace("generate");
    if (bar) options.progress = [&bar](double f) { bar->update(f); };
    mesh = generateScene(options);
  }
  const auto generated = std::chrono::steady_clock::now();
  {
    std::optional<ProgressBar> bar;
    if (bars) bar.emplace("write");
    const std::string comment =
        fmt::format("svo gen {} --triangles {} --seed {}", args.kind, options.triangles, options.seed);
    const std::function<void(double)> report =
        bar ? std::function<void(double)>([&bar](double f) { bar->update(f); }) : nullptr;
    if (lowerExtension(args.out) == ".ply")
      writePly(args.out, mesh, comment, report);
    else
      writeGlb(args.out, mesh, comment, report);
  }
  const auto written = std::chrono::steady_clock::now();
  const GenBounds bounds = sceneBounds(options.kind);
  const double deviation = 100.0 * (double(mesh.triangles.size()) / double(options.triangles) - 1.0);
  spdlog::info("{}: generated in {:.2f} s, written in {:.2f} s", args.kind,
               std::chrono::duration<double>(generated - start).count(),
               std::chrono::duration<double>(written - generated).count());
  std::printf(
      "wrote %s: %s seed %llu, %zu triangles (target %llu, %+.2f%%), %zu vertices, bounds "
      "[%g %g %g]..[%g %g %g], %.1f MiB\n",
      args.out.c_str(), args.kind.c_str(), static_cast<unsigned long long>(options.seed),
      mesh.triangles.size(), static_cast<unsigned long long>(options.triangles), deviation,
      mesh.positions.size(), bounds.min.x, bounds.min.y, bounds.min.z, bounds.max.x, bounds.max.y,
      bounds.max.z, double(std::filesystem::file_size(args.out)) / (1 << 20));
}

}  // namespace

void addGenCommand(CLI::App& app) {
  auto args = std::make_shared<GenArgs>();
  auto* cmd = app.add_subcommand("gen", "generate a procedural test scene (" + sceneKindList() +
                                            ") as PLY or GLB; `stiff -o DIR`: the stiff cases as PLY files");
  cmd->add_option("kind", args->kind, sceneKindList() + ", or stiff")->required();
  cmd->add_option("--triangles", args->triangles,
                  fmt::format("target triangle count, suffixes k M G (the result is within {:.0f}%)",
                              kGenTolerance * 100.0))
      ->capture_default_str();
  cmd->add_option("--seed", args->seed, "random seed: the same seed gives the same file")
      ->capture_default_str();
  cmd->add_option("-o,--output", args->out,
                  "output file: .ply (binary) or .glb (binary glTF); a folder for stiff")
      ->required();
  cmd->callback([args] { runGen(*args); });
}

}  // namespace svo::tools
