// `svo bench build MESH --ranks 1,2`: the out-of-core build as one plain process and under mpirun, each a
// separate run of this very binary, timed from outside (MPI's start-up included) and read back from its
// build report (phases, per-rank cells).
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "bench_common.hpp"

namespace svo::tools::bench {
namespace {

// The phases of the out-of-core build that run on rank 0 alone while the other ranks wait: opening the input,
// planning the cells, writing the store.
const std::vector<std::string> kSerialPhases = {"load", "plan", "write"};
// The passes over the input, shared: each rank bins its share of the triangles, and the octants' top voxels
// are gathered by up to 8 ranks.
const std::vector<std::string> kInputPhases = {"partition", "contours"};
// Rank counts the serial part's Amdahl bound is printed for: a rack, and a large job.
const std::vector<int> kAmdahlRanks = {16, 256};

struct RunResult {
  Summary wall;                  // seconds, mpirun (or the process) from start to exit
  nlohmann::json report;         // the last run's build report
  std::map<std::string, double> phases;
};

// Lines of a failed run's output quoted in the error.
constexpr std::size_t kQuotedLogLines = 4;

// `runs` runs of `command` (its output to `log`), timed from outside; throws with the output's last lines
// when one fails.
RunResult timeCommand(const std::string& command, const std::filesystem::path& reportPath,
                      const std::filesystem::path& log, int runs) {
  RunResult result;
  std::vector<double> samples;
  for (int i = 0; i < runs; ++i) {
    int status = 0;
    samples.push_back(timeSeconds([&] { status = std::system((command + " >" + log.string() + " 2>&1").c_str()); }));
    if (status != 0) {
      std::vector<std::string> lines;
      std::ifstream in(log);
      for (std::string line; std::getline(in, line);) lines.push_back(line);
      std::string tail;
      for (std::size_t k = lines.size() > kQuotedLogLines ? lines.size() - kQuotedLogLines : 0; k < lines.size(); ++k)
        tail += " | " + lines[k];
      throw std::runtime_error("a benchmark build failed (" + command + "):" + tail);
    }
  }
  result.wall = summarize(std::move(samples));
  std::ifstream(reportPath) >> result.report;
  for (const auto& [phase, seconds] : result.report.at("phaseSeconds").items())
    result.phases[phase] = seconds.get<double>();
  return result;
}

double amdahl(double serialShare, int ranks) { return 1.0 / (serialShare + (1.0 - serialShare) / ranks); }

}  // namespace

void runMpiBuildBench(const MpiBuildBenchArgs& args) {
  if (std::system("command -v mpirun >/dev/null 2>&1") != 0)
    throw std::runtime_error("--ranks needs mpirun (Open MPI; tools/scripts/install-deps.sh installs it)");
  const std::string self = std::filesystem::read_symlink("/proc/self/exe").string();
  const ScratchPath store("svo-bench-mpi.svo"), report("svo-bench-mpi.json"), log("svo-bench-mpi.log");
  const auto buildWith = [&](int threads) {
    return fmt::format("{} build {} -o {} --levels {} --cell-level {} --threads {} --report {}", self,
                       args.mesh, store.path().string(), args.levels, args.cellLevel, threads,
                       report.path().string());
  };
  const std::string build = buildWith(1);
  // More ranks than cores is allowed (the bench may ask for it); root needs Open MPI's consent. Ranks are not
  // bound to a core each (mpirun's default for up to 2 ranks): like the plain process, each has the
  // machine's cores for its helper threads, and rank 0 writes the store on them.
  const std::string mpirun = std::string("mpirun --oversubscribe --bind-to none") +
                             (::geteuid() == 0 ? " --allow-run-as-root" : "") + " -n ";

  spdlog::info("plain svo build, {} runs ...", args.runs);
  const RunResult plain = timeCommand(build, report.path(), log.path(), args.runs);
  // The same cores as threads of one process: what this machine's cores give the build without MPI.
  std::vector<std::pair<int, RunResult>> threaded, mpi;
  for (const int ranks : args.ranks) {
    if (ranks == 1) continue;
    spdlog::info("svo build --threads {}, {} runs ...", ranks, args.runs);
    threaded.emplace_back(ranks, timeCommand(buildWith(ranks), report.path(), log.path(), args.runs));
  }
  for (const int ranks : args.ranks) {
    spdlog::info("mpirun -n {} svo build, {} runs ...", ranks, args.runs);
    mpi.emplace_back(ranks, timeCommand(mpirun + std::to_string(ranks) + " " + build, report.path(),
                                        log.path(), args.runs));
  }

  // Speed-up and efficiency against the 1-rank job when measured, else against the plain build.
  const auto one = std::find_if(mpi.begin(), mpi.end(), [](const auto& m) { return m.first == 1; });
  const double base = one != mpi.end() ? one->second.wall.median : plain.wall.median;
  Table table({"run", "ranks", "wall", "input", "voxelize", "serial", "speed-up", "efficiency",
               "cells per rank", "peak MiB per rank"});
  const auto sumOf = [](const RunResult& r, const std::vector<std::string>& phases) {
    double s = 0.0;
    for (const std::string& phase : phases)
      if (r.phases.count(phase)) s += r.phases.at(phase);
    return s;
  };
  const auto serialOf = [&](const RunResult& r) { return sumOf(r, kSerialPhases); };
  const auto inputOf = [&](const RunResult& r) { return formatSeconds(sumOf(r, kInputPhases)); };
  const auto phase = [](const RunResult& r, const char* name) {
    return r.phases.count(name) ? formatSeconds(r.phases.at(name)) : std::string("-");
  };
  table.addRow(
      {"plain svo build", "-", formatSeconds(plain.wall.median), inputOf(plain), phase(plain, "voxelize"),
       formatSeconds(serialOf(plain)), "-", "-", "-",
       fmt::format("{:.0f}", double(plain.report.at("peakResidentBytes").get<std::uint64_t>()) / (1 << 20))});
  for (const auto& [threads, r] : threaded) {
    const double speedUp = base / r.wall.median;
    table.addRow(
        {fmt::format("plain, --threads {}", threads), "-", formatSeconds(r.wall.median), inputOf(r),
         phase(r, "voxelize"), formatSeconds(serialOf(r)), fmt::format("{:.2f}x", speedUp),
         fmt::format("{:.0f}%", 100.0 * speedUp / threads), "-",
         fmt::format("{:.0f}", double(r.report.at("peakResidentBytes").get<std::uint64_t>()) / (1 << 20))});
  }
  for (const auto& [ranks, r] : mpi) {
    std::string cells, peaks;
    for (const auto& rank : r.report.at("ranks")) {
      cells += (cells.empty() ? "" : "/") + std::to_string(rank.at("cells").get<std::size_t>());
      peaks += (peaks.empty() ? "" : "/") +
               fmt::format("{:.0f}", double(rank.at("peakResidentBytes").get<std::uint64_t>()) / (1 << 20));
    }
    const double speedUp = base / r.wall.median;
    table.addRow({"mpirun svo build", std::to_string(ranks), formatSeconds(r.wall.median), inputOf(r),
                  phase(r, "voxelize"), formatSeconds(serialOf(r)), fmt::format("{:.2f}x", speedUp),
                  fmt::format("{:.0f}%", 100.0 * speedUp / ranks), cells, peaks});
  }

  printTitle("Building over MPI: svo build as one process and under mpirun, one thread a rank");
  fmt::print("{}: {} triangles; {} levels, cells of level {}; median of {} runs\n", args.mesh,
             formatCount(plain.report.at("triangles").get<std::uint64_t>()), args.levels, args.cellLevel,
             args.runs);
  table.print();
  fmt::print(
      "wall: the whole command timed from outside (mpirun's start-up included, ranks not bound to a core each: "
      "mpirun --bind-to none); input: {}, the passes over the input, shared; voxelize: the cells' phase, "
      "shared out; serial: {}, on rank 0 alone.\n"
      "speed-up, efficiency: against the 1-rank job (else the plain build); efficiency = speed-up / ranks "
      "(or threads).\n",
      fmt::join(kInputPhases, " + "), fmt::join(kSerialPhases, " + "));
  if (one != mpi.end())
    fmt::print("MPI overhead, 1 rank against the plain build: {:+.1f}% wall time\n",
               100.0 * (one->second.wall.median / plain.wall.median - 1.0));
  for (const auto& [ranks, r] : mpi) {
    const auto same =
        std::find_if(threaded.begin(), threaded.end(), [&](const auto& t) { return t.first == ranks; });
    if (same == threaded.end()) continue;
    fmt::print(
        "{} ranks: {:.2f}x 1/{} of the 1-rank time, {:.2f}x the wall time of {} threads in one process\n",
        ranks, r.wall.median / (base / ranks), ranks, r.wall.median / same->second.wall.median, ranks);
  }
  const RunResult& ref = one != mpi.end() ? one->second : plain;
  const double serial = serialOf(ref), share = std::min(1.0, serial / ref.wall.median);
  std::string slowest;
  double slowestSeconds = -1.0;
  for (const std::string& p : kSerialPhases)
    if (ref.phases.count(p) && ref.phases.at(p) > slowestSeconds) slowest = p, slowestSeconds = ref.phases.at(p);
  fmt::print("serial part: {} of {} ({:.1f}%); the largest: {} ({}). Amdahl's bound:", formatSeconds(serial),
             formatSeconds(ref.wall.median), 100.0 * share, slowest, formatSeconds(slowestSeconds));
  for (const int n : kAmdahlRanks) fmt::print(" {:.1f}x at {} ranks", amdahl(share, n), n);
  fmt::print("\n");
}

}  // namespace svo::tools::bench
