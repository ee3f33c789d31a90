// `svo stress IN.svo`: the memory-budget stress test (issue 5). Camera sequences that are hard on a pager —
// random teleports, a fly-through that enters the scene, a zoom from the whole scene to the finest voxels —
// stream against each budget. Every frame checks resident bytes <= budget and the pool's and pager's
// invariants; a violation prints the frame and exits 1. The table reports loads, evictions, thrash (slices
// loaded again after being evicted), the worst frame and the time the final view takes to converge.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <set>

#include <spdlog/spdlog.h>
#include <glm/geometric.hpp>

#include "bench_common.hpp"
#include "commands.hpp"
#include "streaming.hpp"

namespace svo::tools {
namespace {

struct StressArgs {
  std::string input;
  std::vector<std::size_t> budgets{std::size_t(4) << 20, std::size_t(64) << 20};
  int frames = 90;
  int size = 128;
  unsigned seed = 1;
  float lodPixels = 1.0f;
  double timeout = 120.0;
};

// Frames of one sequence in world space around the scene cube.
std::vector<Camera> sequence(const std::string& kind, const SceneTransform& scene, int frames, int size,
                             unsigned seed) {
  const glm::dvec3 centre = scene.origin + 0.5 * scene.size;
  const double finest = scene.size;  // refined below by the zoom
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Camera> out;
  for (int i = 0; i < frames; ++i) {
    Camera c;
    c.width = c.height = size;
    c.fovYDegrees = 50.0;
    const double s = double(i) / std::max(1, frames - 1);
    if (kind == "random") {  // teleports: anywhere from inside the scene to far outside, any direction
      c.target = centre + 0.5 * scene.size * glm::dvec3(u(rng), u(rng), u(rng));
      const glm::dvec3 dir = glm::normalize(glm::dvec3(u(rng), u(rng), u(rng)) + 1e-6);
      c.eye = c.target + dir * scene.size * std::pow(10.0, 1.3 * u(rng) - 0.3);
    } else if (kind == "flythrough") {  // a loop that passes through the scene cube, with fast turns
      const double a = 4.0 * M_PI * s;
      c.eye =
          centre + scene.size * glm::dvec3(0.9 * std::cos(a), 0.2 * std::sin(3 * a), 0.9 * std::sin(a) * s);
      c.target = c.eye + glm::dvec3(-std::sin(a + 0.6 * std::sin(7 * a)), 0.1, std::cos(a));
    } else {  // zoom: from the whole scene down to a few finest voxels across the view
      c.target = centre;
      const double far = 2.5 * scene.size, near = std::ldexp(finest, -12);
      c.eye = centre + glm::normalize(glm::dvec3(0.3, 0.5, 1.0)) * far * std::pow(near / far, s);
    }
    if (glm::length(glm::cross(c.target - c.eye, c.up)) < 1e-9 * glm::length(c.target - c.eye))
      c.up = glm::dvec3(1, 0, 0);
    out.push_back(c);
  }
  return out;
}

void runStress(const StressArgs& args) {
  keepFreedMemoryForReuse();
  bench::Table table({"budget", "sequence", "frames", "loads", "evictions", "thrash", "worst frame",
                      "p99 frame", "max resident", "converge", "failed"});
  bool violated = false;
  for (const std::size_t budget : args.budgets) {
    const std::string text = formatBytes(budget);
    for (const std::string kind : {"random", "flythrough", "zoom"}) {
      PagerOptions options;
      options.budgetBytes = budget;
      std::unique_ptr<Pager> pager;
      try {
        pager = std::make_unique<Pager>(args.input, options);
      } catch (const std::runtime_error& e) {
        table.addRow({text, kind, "-", "-", "-", "-", "-", "-", "-", "-", e.what()});
        break;
      }
      RenderOptions render;
      render.lodPixels = args.lodPixels;
      const std::vector<Camera> cameras =
          sequence(kind, pager->transform(), args.frames, args.size, args.seed);
      std::set<std::uint32_t> everEvicted;
      std::vector<std::uint32_t> before = pager->residentSlices();
      std::uint64_t loads = 0, evictions = 0, reloads = 0, failed = 0;
      std::vector<double> frameMs;
      std::size_t maxResident = 0;
      for (std::size_t f = 0; f < cameras.size(); ++f) {
        const StreamedFrame step = streamFrame(*pager, cameras[f], render);
        frameMs.push_back(step.seconds() * 1e3);
        maxResident = std::max(maxResident, step.stats.residentBytes);
        failed += step.stats.failed;
        try {
          if (step.stats.residentBytes > pager->budgetBytes())
            throw std::logic_error("resident bytes exceed the budget");
          pager->checkInvariants();
        } catch (const std::logic_error& e) {
          std::fprintf(stderr, "svo stress: budget %s, %s frame %zu: %s\n", text.c_str(), kind.c_str(), f,
                       e.what());
          violated = true;
          break;
        }
        const std::vector<std::uint32_t> after = pager->residentSlices();
        std::vector<std::uint32_t> added, removed;
        std::set_difference(after.begin(), after.end(), before.begin(), before.end(),
                            std::back_inserter(added));
        std::set_difference(before.begin(), before.end(), after.begin(), after.end(),
                            std::back_inserter(removed));
        loads += added.size(), evictions += removed.size();
        for (const std::uint32_t s : added) reloads += everEvicted.count(s);
        everEvicted.insert(removed.begin(), removed.end());
        before = after;
      }
      const double converge = convergeView(*pager, cameras.back(), render, args.timeout).seconds;
      const double p99 = percentile(frameMs, 0.99);
      const double worstMs = *std::max_element(frameMs.begin(), frameMs.end());
      char thrash[32], worst[32], p99Text[32], conv[32];
      std::snprintf(thrash, sizeof thrash, "%.1f%%", loads ? 100.0 * double(reloads) / double(loads) : 0.0);
      std::snprintf(worst, sizeof worst, "%.1f ms", worstMs);
      std::snprintf(p99Text, sizeof p99Text, "%.1f ms", p99);
      if (converge >= 0.0)
        std::snprintf(conv, sizeof conv, "%.2f s", converge);
      else
        std::snprintf(conv, sizeof conv, "> %.0f s", args.timeout);
      table.addRow({formatBytes(pager->budgetBytes()), kind, std::to_string(frameMs.size()),
                    std::to_string(loads), std::to_string(evictions), thrash, worst, p99Text,
                    formatBytes(maxResident), conv, std::to_string(failed)});
    }
  }
  bench::printTitle("svo stress " + args.input + " (" + std::to_string(args.size) + "^2 frames, LOD " +
                    std::to_string(args.lodPixels) + " px)");
  table.print();
  std::printf(
      "thrash: slices loaded again after an eviction, per load; every frame checked resident <= budget "
      "and the pool invariants\n");
  if (violated) throw std::runtime_error("stress: an invariant was violated (see above)");
}

}  // namespace

void addStressCommand(CLI::App& app) {
  auto args = std::make_shared<StressArgs>();
  auto* cmd =
      app.add_subcommand("stress", "memory-budget stress test: hostile camera sequences against budgets");
  cmd->add_option("input", args->input, "a .svo store")->required()->check(CLI::ExistingFile);
  cmd->add_option("--budgets", args->budgets, "pool budgets, e.g. 4M,64M (default 4M,64M)")
      ->delimiter(',')
      ->transform(CLI::AsSizeValue(false));
  cmd->add_option("--frames", args->frames, "frames per sequence")
      ->check(CLI::Range(2, 100000))
      ->capture_default_str();
  cmd->add_option("--size", args->size, "frame width and height")
      ->check(CLI::Range(8, 4096))
      ->capture_default_str();
  cmd->add_option("--seed", args->seed, "random sequence seed")->capture_default_str();
  cmd->add_option("--lod-pixels", args->lodPixels, "target voxel size in pixels")
      ->check(CLI::Range(0.01, 64.0))
      ->capture_default_str();
  cmd->add_option("--timeout", args->timeout, "seconds the final view may take to converge")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  cmd->callback([args] { runStress(*args); });
}

}  // namespace svo::tools
