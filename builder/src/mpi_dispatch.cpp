#include "mpi_dispatch.hpp"

#include <algorithm>
#include <chrono>
#include <exception>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>

#include <tbb/task_arena.h>

namespace svo::mpi {

// What rank 0's threads and its MPI loop share while the cells are built.
struct Dispatcher::Shared {
  std::mutex mutex;
  std::size_t next = 0;            // the next task to hand out
  std::string failure;             // the first failure's message; no task is handed out after it
  std::exception_ptr localFailure;  // rank 0's own, rethrown as it is
  std::vector<CellRoot> roots;
  std::size_t localRunning = 0;

  std::optional<std::size_t> take() {
    std::lock_guard lock(mutex);
    if (!failure.empty() || next >= roots.size()) return std::nullopt;
    return next++;
  }
};

Dispatcher::Dispatcher(std::vector<std::string> hosts, int threads)
    : hosts_(std::move(hosts)), threads_(std::max(1, threads)) {
  stopped_.assign(hosts_.size(), false);
  stopped_[0] = true;
  totals_.resize(hosts_.size());
}

void Dispatcher::answer(int from, const std::vector<char>& message, const CellJobs& jobs, Shared& shared) {
  std::vector<char> rest;
  const Report report = front<Report>(message, &rest);
  totals_[std::size_t(from)] = report.totals;
  if (report.kind == Report::kBuilt) {
    if (report.task < 0 || std::size_t(report.task) >= jobs.tasks.size())
      throw std::runtime_error("MPI: rank " + std::to_string(from) + " reports a cell it was not given");
    CellRoot root;
    root.record = report.root;
    root.sums.weight = report.weight;
    root.sums.color = glm::dvec4(report.color[0], report.color[1], report.color[2], report.color[3]);
    root.sums.normal = glm::dvec3(report.normal[0], report.normal[1], report.normal[2]);
    {
      std::lock_guard lock(shared.mutex);
      shared.roots[std::size_t(report.task)] = root;
    }
    if (jobs.builtElsewhere) jobs.builtElsewhere(jobs.tasks[std::size_t(report.task)].coord, report.voxels);
  } else if (report.kind == Report::kFailed) {
    std::lock_guard lock(shared.mutex);
    if (shared.failure.empty())
      shared.failure = "rank " + std::to_string(from) + " on " + hosts_[std::size_t(from)] + ": " +
                       std::string(rest.begin(), rest.end());
  }
  Assignment a;
  const std::optional<std::size_t> task = shared.take();
  if (task) {
    const CellTask& t = jobs.tasks[*task];
    a.kind = Assignment::kTask;
    a.cellLevel = jobs.cellLevel;
    a.task = std::int64_t(*task);
    for (int k = 0; k < 3; ++k) a.coord[k] = t.coord[k];
    a.slabCount = t.slabs.size();
    a.partCount = t.parts.size();
    send(from, kAssignTag, pack(a, &t));
    return;
  }
  // No cell left, or the job failed: cells are never handed out twice, so the rank is not needed again.
  std::lock_guard lock(shared.mutex);
  a.kind = shared.failure.empty() ? Assignment::kStop : Assignment::kStopFailed;
  send(from, kAssignTag, pack(a));
  stopped_[std::size_t(from)] = true;
}

std::vector<CellRoot> Dispatcher::run(const CellJobs& jobs) {
  Shared shared;
  shared.roots.resize(jobs.tasks.size());
  const auto work = [&] {
    try {
      while (const std::optional<std::size_t> task = shared.take()) {
        const auto start = std::chrono::steady_clock::now();
        const CellRoot root = jobs.buildHere(*task);
        std::lock_guard lock(shared.mutex);
        shared.roots[*task] = root;
        ++totals_[0].cells;
        totals_[0].buildSeconds +=
            std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      }
    } catch (const std::exception& e) {
      std::lock_guard lock(shared.mutex);
      if (shared.failure.empty()) shared.failure = e.what(), shared.localFailure = std::current_exception();
    }
    std::lock_guard lock(shared.mutex);
    --shared.localRunning;
  };
  shared.localRunning = std::size_t(threads_);
  // The process may run more threads than its cell builders (the store is written on every core of the
  // host); the cells' own parallel loops stay within the builders' share.
  tbb::task_arena cells(threads_);
  std::vector<std::jthread> builders;
  for (int t = 0; t < threads_; ++t) builders.emplace_back([&] { cells.execute(work); });
  // This thread talks MPI (the job runs MPI_THREAD_FUNNELED) until every rank is stopped and every local
  // builder is done.
  std::vector<char> message;
  for (;;) {
    int from = 0;
    if (tryReceive(MPI_ANY_SOURCE, kReportTag, message, from)) {
      answer(from, message, jobs, shared);
      continue;
    }
    bool localDone = false;
    {
      std::lock_guard lock(shared.mutex);
      localDone = shared.localRunning == 0;
    }
    if (localDone && std::all_of(stopped_.begin(), stopped_.end(), [](bool s) { return s; })) break;
    pause();
  }
  builders.clear();
  if (shared.localFailure) std::rethrow_exception(shared.localFailure);
  if (!shared.failure.empty()) throw std::runtime_error(shared.failure);
  return std::move(shared.roots);
}

void Dispatcher::releaseAfterFailure() {
  for (std::size_t r = 1; r < stopped_.size(); ++r) {
    if (stopped_[r]) continue;
    // Its next report (it is building a cell, or waits with its first) is answered with the end.
    int from = 0;
    const std::vector<char> message = receive(int(r), kReportTag, &from);
    totals_[r] = front<Report>(message).totals;
    Assignment a;
    a.kind = Assignment::kStopFailed;
    send(int(r), kAssignTag, pack(a));
    stopped_[r] = true;
  }
}

}  // namespace svo::mpi
