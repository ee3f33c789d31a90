// `svo bench stability`: one row per stiff case (stability.hpp): max and mean error against the
// double-precision reference, iterations, pass or fail against the stated bounds, so a regression shows at
// a glance. Exits non-zero when a case fails.
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include "bench_common.hpp"
#include "stability.hpp"
#include "svo/client/raycast.hpp"

namespace svo::tools::bench {

void addStabilityBench(CLI::App& bench) {
  auto detail = std::make_shared<int>(3);
  CLI::App* cmd = bench.add_subcommand(
      "stability",
      "stiff and extreme cases against the double-precision reference: errors, iterations, pass/fail");
  cmd->add_option("--detail", *detail,
                  "scene size factor (1: the test suite's sizes; tiny triangles grow as its square)")
      ->check(CLI::Range(1, 30))
      ->capture_default_str();
  cmd->callback([detail] {
    const StabilityBounds bounds;
    spdlog::info("generating the stiff cases (detail {}) ...", *detail);
    const std::vector<StiffCase> cases = stiffCases(*detail);
    Table table({"case", "triangles", "rays", "ref hits", "see-through", "max t excess", "surface max",
                 "surface mean", "iter max", "iter mean", "accel err", "time", "result"});
    int failed = 0;
    for (const StiffCase& c : cases) {
      spdlog::info("{} ...", c.name);
      const CaseResult r = evaluateCase(c, bounds);
      failed += !r.pass();
      table.addRow({r.name, formatCount(r.triangles), formatCount(r.rays), formatCount(r.referenceHits),
                    formatCount(r.seeThrough), fmt::format("{:.3f} vox", r.maxSeeThrough),
                    fmt::format("{:.3f}", r.maxSurfaceError), fmt::format("{:.3f}", r.meanSurfaceError),
                    std::to_string(r.maxIterations), fmt::format("{:.1f}", r.meanIterations),
                    fmt::format("{:.1e}", r.maxAccelError), formatSeconds(r.seconds),
                    r.pass() ? std::string("pass") : "FAIL: " + r.failure});
    }
    printTitle(
        "Stiff and extreme cases: ESVO ray caster and every acceleration structure vs brute force (double)");
    table.print();
    fmt::print(
        "see-through: reference hits the caster missed or hit later than allowed (16 float ulps of the "
        "octree plus\n"
        "{:.0e} relative); max t excess in finest voxels. surface: hit point to mesh distance in hit-voxel\n"
        "diagonals (bound {:.1f}, plus float rounding). iter: ESVO loop iterations per ray (cap {}). accel "
        "err:\n"
        "largest relative t error of any structure vs brute force where the triangle differed (bound "
        "{:.0e}).\n",
        bounds.seeThroughRelative, bounds.surfaceDiagonals, CastOptions{}.maxIterations,
        bounds.accelRelative);
    if (failed) throw std::runtime_error(fmt::format("{} of {} stiff cases failed", failed, cases.size()));
  });
}

}  // namespace svo::tools::bench
