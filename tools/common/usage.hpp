// What a bad command line is, for the commands and the benchmarks alike.
#pragma once

#include <filesystem>
#include <stdexcept>

namespace svo::tools {

// Thrown by subcommands for a bad command line: main prints "svo: <message>" and exits 2.
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Thrown where another process reports the failure (an MPI job's rank 0): main exits 1 without a message.
struct FailureReportedElsewhere : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Throws UsageError before any work when the output's folder is missing or not writable.
void checkWritableOutput(const std::filesystem::path& out);

}  // namespace svo::tools
