// `svo`: one binary, subcommands. Errors from bad input reach the user as one line and a non-zero exit.
#include <cstdio>
#include <exception>
#include <new>

#include <spdlog/spdlog.h>

#include "bench.hpp"
#include "commands.hpp"

int main(int argc, char** argv) {
  CLI::App app{"svostream: sparse voxel octree builder, store and renderer"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "svo 0.1.0");
  svo::tools::addBuildCommand(app);
  svo::tools::addRenderCommand(app);
  svo::tools::addStoreCommands(app);
  svo::tools::addGenCommand(app);
  svo::tools::addStressCommand(app);
  svo::tools::addServeCommand(app);
  svo::tools::addViewCommand(app);
  svo::tools::addExportCommand(app);
  auto* bench = app.add_subcommand("bench", "benchmarks against peers measured in the same run");
  bench->require_subcommand(1);
  svo::tools::addBenchCommands(*bench);
  // Exit codes: 0 success (help and --version too), 1 bad input or a failure while working, 2 a bad command
  // line.
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    std::fprintf(stderr, "svo: %s\n", e.what());
    return 2;
  } catch (const svo::tools::UsageError& e) {
    std::fprintf(stderr, "svo: %s\n", e.what());
    return 2;
  } catch (const svo::tools::FailureReportedElsewhere&) {
    return 1;
  } catch (const std::bad_alloc&) {
    std::fprintf(stderr, "svo: out of memory (an allocation failed; try a smaller input or budget)\n");
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "svo: %s\n", e.what());
    return 1;
  }
  return 0;
}
