// Running a helper program (dd, gnuplot) and reading what it printed.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace svo::tools {

struct ProcessOptions {
  std::filesystem::path workingDirectory;  // empty: this process's
  bool cLocale = false;  // LC_ALL=C and no other LC_* or LANG*: output in the untranslated form parsed here
};

struct ProcessResult {
  int exitCode = -1;   // -1 when a signal ended it
  std::string output;  // stdout and stderr, interleaved as written
  bool succeeded() const { return exitCode == 0; }
};

// Runs argv[0] (searched in PATH) with the arguments argv[1...] and waits for it. nullopt when it cannot be
// started (not installed, or no such working directory).
std::optional<ProcessResult> runProcess(const std::vector<std::string>& argv,
                                        const ProcessOptions& options = {});

}  // namespace svo::tools
