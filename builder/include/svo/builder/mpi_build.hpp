// The out-of-core build over MPI (Open MPI): one job, N ranks sharing the work folder. Rank 0 bins the
// input into cells and builds the levels above them, every rank builds cells handed out largest first and
// spills them to the shared work folder, and rank 0 writes the store. The store is byte-identical to the
// single-process buildStore's. Only in builds with SVO_MPI.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "svo/builder/build.hpp"

namespace svo {

// What one rank did: its cells, the seconds it spent building them and its peak resident memory.
struct RankReport {
  int rank = 0;
  std::string host;
  std::size_t cells = 0;  // built by this rank
  std::uint64_t peakResidentBytes = 0;
  double buildSeconds = 0.0;  // building those cells
};
struct MpiBuildReport {
  OutOfCoreReport build;
  std::vector<RankReport> ranks;  // by rank
};

// Thrown on the ranks other than 0 when the job fails: rank 0 reports why, they only exit non-zero.
struct MpiJobFailed : std::runtime_error {
  MpiJobFailed() : std::runtime_error("the MPI job failed (rank 0 says why)") {}
};

// MPI for the life of the object (MPI_Init_thread, MPI_Finalize); one per process.
class MpiJob {
 public:
  MpiJob();
  ~MpiJob();
  MpiJob(const MpiJob&) = delete;
  MpiJob& operator=(const MpiJob&) = delete;

  int rank() const { return rank_; }
  int size() const { return size_; }
  const std::string& host() const { return host_; }

  // Collective. Every rank passes what it opened: `source`, or null and `openError` saying why not. Checks
  // that all ranks read the same input with the same options and see the same work folder, then builds;
  // rank 0 returns the report, the others nullopt. Failures throw on rank 0 with a message naming the rank
  // and host at fault, and MpiJobFailed elsewhere; no store is written then.
  std::optional<MpiBuildReport> build(const TriangleSource* source, const std::string& openError,
                                      const BuildOptions& options, const StoreWriteOptions& write,
                                      const OutOfCoreOptions& ooc, const std::filesystem::path& store);

  // For a failure outside build() while other ranks may wait on this one: prints "svo: MESSAGE" on stderr
  // and ends the job (MPI_Abort).
  [[noreturn]] void abort(const std::string& message) const;

 private:
  int rank_ = 0, size_ = 1;
  std::string host_;
};

}  // namespace svo
