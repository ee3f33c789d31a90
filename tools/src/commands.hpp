// Each subcommand registers itself on the `svo` app; the callback runs after parsing.
#pragma once

#include <filesystem>

#include <CLI/CLI.hpp>

namespace svo::tools {

void addBuildCommand(CLI::App& app);     // cmd_build.cpp
void addRenderCommand(CLI::App& app);    // cmd_render.cpp
void addStoreCommands(CLI::App& app);    // cmd_store.cpp: `svo verify`, `svo inspect`
void addGenCommand(CLI::App& app);       // cmd_gen.cpp: `svo gen`
void addStressCommand(CLI::App& app);    // cmd_stress.cpp: `svo stress`
void addBenchCommands(CLI::App& bench);  // bench_*.cpp: `svo bench raycast`, `build`, `store`

// Thrown by subcommands for a bad command line: main prints "svo: <message>" and exits 2.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Throws UsageError before any work when the output's folder is missing or not writable (cmd_build.cpp).
void checkWritableOutput(const std::filesystem::path& out);

}  // namespace svo::tools
