// Rank 0's side of a build shared out over MPI: it hands the cells out one at a time, largest first, to
// whichever rank asks (its own threads included), and collects their roots.
#pragma once

#include <string>
#include <vector>

#include "cell_voxelizer.hpp"
#include "mpi_wire.hpp"

namespace svo::mpi {

class Dispatcher {
 public:
  // `hosts`: each rank's host, by rank (for messages); `threads`: rank 0's own cell builders.
  Dispatcher(std::vector<std::string> hosts, int threads);

  // The CellRunner: returns when every cell is built and every other rank is told to stop; throws the
  // first failure (a rank's message names it) once all have stopped.
  std::vector<CellRoot> run(const CellJobs& jobs);
  // After a failure on rank 0 outside run(): every rank not yet stopped is told the job failed.
  void releaseAfterFailure();

  const std::vector<Totals>& totals() const { return totals_; }  // by rank, once run() returned

 private:
  struct Shared;
  // A report from rank `from`: record it and answer with the next cell or a stop.
  void answer(int from, const std::vector<char>& message, const CellJobs& jobs, Shared& shared);

  std::vector<std::string> hosts_;
  int threads_;
  std::vector<bool> stopped_;  // by rank; rank 0 is never sent anything
  std::vector<Totals> totals_;
};

}  // namespace svo::mpi
