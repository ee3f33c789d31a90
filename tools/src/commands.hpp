// Each subcommand registers itself on the `svo` app; the callback runs after parsing.
#pragma once

#include <CLI/CLI.hpp>

namespace svo::tools {

void addBuildCommand(CLI::App& app);     // cmd_build.cpp
void addRenderCommand(CLI::App& app);    // cmd_render.cpp
void addStoreCommands(CLI::App& app);    // cmd_store.cpp: `svo verify`, `svo inspect`
void addBenchCommands(CLI::App& bench);  // bench_*.cpp: `svo bench raycast`, `svo bench build`

// Thrown by subcommands for a bad command line: main prints "svo: <message>" and exits 2.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace svo::tools
