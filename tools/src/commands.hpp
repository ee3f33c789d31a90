// Each subcommand registers itself on the `svo` app; the callback runs after parsing.
#pragma once

#include <CLI/CLI.hpp>

#include "usage.hpp"

namespace svo::tools {

void addBuildCommand(CLI::App& app);   // cmd_build.cpp
void addRenderCommand(CLI::App& app);  // cmd_render.cpp
void addStoreCommands(CLI::App& app);  // cmd_store.cpp: `svo verify`, `svo inspect`
void addGenCommand(CLI::App& app);     // cmd_gen.cpp: `svo gen`
void addStressCommand(CLI::App& app);  // cmd_stress.cpp: `svo stress`
void addServeCommand(CLI::App& app);   // cmd_serve.cpp: `svo serve`
void addViewCommand(CLI::App& app);    // cmd_view.cpp: `svo view`
void addExportCommand(CLI::App& app);  // cmd_export.cpp: `svo export`

}  // namespace svo::tools
