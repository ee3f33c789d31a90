// `svo bench`: the benchmarks, each against a peer measured in the same run.
#pragma once

#include <CLI/CLI.hpp>

namespace svo::tools {

// Registers `svo bench raycast`, `build`, `accel`, `stability`, `quality`, `store`, `stream`, `serve` and
// `dimensions` and `volume` on `bench`.
void addBenchCommands(CLI::App& bench);

}  // namespace svo::tools
