// The out-of-core build over MPI (mpi_build.hpp): the checks every rank takes part in, the ranks' cell
// loop, and rank 0's build with its cells shared out (mpi_dispatch.cpp).
#include "svo/builder/mpi_build.hpp"

#include <sched.h>
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <random>
#include <thread>

#include <tbb/info.h>
#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "cell_spill.hpp"
#include "mpi_dispatch.hpp"
#include "out_of_core.hpp"

namespace svo {
namespace mpi {

// How long a waiting rank sleeps between polls for a message: MPI's blocking waits spin a core that the
// ranks building cells on the same host need; a cell takes far longer than this to build.
constexpr auto kPollInterval = std::chrono::milliseconds(1);

void send(int to, Tag tag, const std::vector<char>& message) {
  MPI_Send(message.data(), int(message.size()), MPI_BYTE, to, tag, MPI_COMM_WORLD);
}

bool tryReceive(int from, Tag tag, std::vector<char>& message, int& sender) {
  int arrived = 0;
  MPI_Status status;
  MPI_Iprobe(from, tag, MPI_COMM_WORLD, &arrived, &status);
  if (!arrived) return false;
  int bytes = 0;
  MPI_Get_count(&status, MPI_BYTE, &bytes);
  message.resize(std::size_t(bytes));
  MPI_Recv(message.data(), bytes, MPI_BYTE, status.MPI_SOURCE, tag, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  sender = status.MPI_SOURCE;
  return true;
}

std::vector<char> receive(int from, Tag tag, int* sender) {
  std::vector<char> message;
  int who = 0;
  while (!tryReceive(from, tag, message, who)) pause();
  if (sender) *sender = who;
  return message;
}

void pause() { std::this_thread::sleep_for(kPollInterval); }

std::uint64_t peakResidentBytes() {
  rusage usage{};
  ::getrusage(RUSAGE_SELF, &usage);
  return std::uint64_t(usage.ru_maxrss) * 1024;  // Linux reports KiB
}

}  // namespace mpi

namespace {

using namespace mpi;

// The file rank 0 leaves in the work folder for every rank to read back: the folder is shared when all do.
constexpr char kSharedCheckFile[] = "shared-folder-check";

// What every rank must agree on: the input as it read it, and every option that shapes the cells or the
// store; or why it could not open the input. Not the memory bound: each rank's own (rank 0 picks the cells).
nlohmann::json agreementOf(const TriangleSource* source, const std::string& openError,
                           const BuildOptions& options, const StoreWriteOptions& write,
                           const OutOfCoreOptions& ooc, const std::filesystem::path& store) {
  if (!source) return {{"error", openError}};
  return {{"input",
           {{"fingerprint", std::to_string(source->fingerprint())}, {"triangles", source->triangleCount()}}},
          {"options",
           {{"levels", options.levels},
            {"contours", options.contours},
            {"leaf contour reduction", options.leafContourMinReduction},
            {"inner contour reduction", options.innerContourMinReduction},
            {"geometry error", options.geometryError},
            {"color error", options.colorError},
            {"normal error", options.normalError},
            {"slice size", write.sliceBytes},
            {"cell level", ooc.cellLevel},
            {"resume", ooc.resume},
            {"output", std::filesystem::absolute(store).string()},
            {"work folder", std::filesystem::absolute(workFolderOf(ooc, store)).string()}}}};
}

// Every rank's string, by rank, at rank 0 (empty elsewhere).
std::vector<std::string> gather(const std::string& mine, int rank, int size) {
  int length = int(mine.size());
  std::vector<int> lengths(static_cast<std::size_t>(size)), offsets(static_cast<std::size_t>(size));
  MPI_Gather(&length, 1, MPI_INT, lengths.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  int total = 0;
  for (int r = 0; r < size; ++r) offsets[std::size_t(r)] = total, total += lengths[std::size_t(r)];
  std::vector<char> all(std::size_t(std::max(total, 1)));
  MPI_Gatherv(mine.data(), length, MPI_CHAR, all.data(), lengths.data(), offsets.data(), MPI_CHAR, 0,
              MPI_COMM_WORLD);
  std::vector<std::string> out;
  if (rank != 0) return out;
  for (int r = 0; r < size; ++r)
    out.emplace_back(all.data() + offsets[std::size_t(r)], std::size_t(lengths[std::size_t(r)]));
  return out;
}

// Rank 0's verdict to all: nothing when `problem` (rank 0's) is empty, else the job ends here.
void settle(const std::string& problem, int rank) {
  int failed = problem.empty() ? 0 : 1;
  MPI_Bcast(&failed, 1, MPI_INT, 0, MPI_COMM_WORLD);
  if (!failed) return;
  if (rank == 0) throw std::runtime_error(problem);
  throw MpiJobFailed();
}

// The first rank that cannot build or disagrees with rank 0, and how; empty when all agree.
std::string disagreement(const std::vector<std::string>& agreements, const std::vector<std::string>& hosts) {
  const auto where = [&](std::size_t r) { return "rank " + std::to_string(r) + " on " + hosts[r]; };
  std::vector<nlohmann::json> all;
  for (const std::string& a : agreements) all.push_back(nlohmann::json::parse(a));
  for (std::size_t r = 0; r < all.size(); ++r)
    if (all[r].contains("error")) return where(r) + ": " + all[r]["error"].get<std::string>();
  for (std::size_t r = 1; r < all.size(); ++r) {
    const auto input = [&](std::size_t k) {
      return all[k]["input"]["triangles"].dump() + " triangles, fingerprint " +
             all[k]["input"]["fingerprint"].get<std::string>();
    };
    if (all[r]["input"] != all[0]["input"])
      return where(r) + " reads another input than rank 0 (" + input(r) + " against " + input(0) +
             "): every rank must read the same file";
    for (const auto& [key, value] : all[0]["options"].items())
      if (all[r]["options"][key] != value)
        return where(r) + " was started with another " + key + " (" + all[r]["options"][key].dump() +
               ") than rank 0 (" + value.dump() + "): every rank must get the same options";
  }
  return {};
}

// Whether every rank sees the file rank 0 writes into the work folder; the first that does not, or empty.
std::string unsharedFolder(const std::filesystem::path& work, int rank, const std::vector<std::string>& hosts) {
  const std::filesystem::path check = work / kSharedCheckFile;
  std::uint64_t nonce = 0;
  bool created = false;
  std::string problem;
  if (rank == 0) {
    std::error_code ec;
    created = std::filesystem::create_directories(work, ec);
    nonce = (std::uint64_t(std::random_device()()) << 32) ^ std::random_device()();
    std::ofstream out(check);
    if (ec || !(out << nonce).flush()) problem = work.string() + ": cannot write the work folder";
  }
  MPI_Bcast(&nonce, 1, MPI_UINT64_T, 0, MPI_COMM_WORLD);
  std::uint64_t seen = 0;
  int sees = std::ifstream(check) >> seen && seen == nonce ? 1 : 0;
  std::vector<int> all(hosts.empty() ? 1 : hosts.size());
  MPI_Gather(&sees, 1, MPI_INT, all.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  if (rank != 0) return {};
  std::error_code ignored;
  std::filesystem::remove(check, ignored);
  if (!problem.empty()) return problem;
  for (std::size_t r = 1; r < all.size(); ++r) {
    if (all[r]) continue;
    if (created) std::filesystem::remove_all(work, ignored);
    return "the work folder " + work.string() + " is not shared with rank " + std::to_string(r) + " on " +
           hosts[r] + ": every rank must see it (put the output on a file system all hosts mount)";
  }
  return {};
}

// The CPUs this process may run on (mpirun binds a rank to a core or a socket by default).
int coresAvailable() {
  cpu_set_t set;
  CPU_ZERO(&set);
  return sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 0;
}

// One line when ranks may run on fewer cores than their --threads (`cores`: each rank's, at rank 0): their
// builders would share them, and rank 0 writes the store on its own.
void warnOfFewCores(const std::vector<int>& cores, const std::vector<std::string>& hosts, int threads) {
  std::size_t fewer = 0, fewest = 0;
  for (std::size_t r = 0; r < cores.size(); ++r) {
    if (cores[r] <= 0 || cores[r] >= threads) continue;
    if (fewer++ == 0 || cores[r] < cores[fewest]) fewest = r;
  }
  if (fewer == 0) return;
  spdlog::warn(
      "{} of {} ranks may run on fewer cores than --threads {} (rank {} on {}: {} {}); mpirun binds each rank to "
      "a core or a socket by default: give each its cores with mpirun --map-by slot:PE={} (or --bind-to none; "
      "under Slurm, --cpus-per-task={})",
      fewer, cores.size(), threads, fewest, hosts[fewest], cores[fewest], cores[fewest] == 1 ? "core" : "cores",
      threads, threads);
}

// Every rank's message, at every rank, by rank; waits without spinning a core (ranks still binning on the
// same host need it).
std::vector<std::string> allGather(const std::string& mine, int size) {
  const auto wait = [](MPI_Request& request) {
    for (int done = 0; MPI_Test(&request, &done, MPI_STATUS_IGNORE), !done;) pause();
  };
  int length = int(mine.size());
  std::vector<int> lengths(static_cast<std::size_t>(size)), offsets(static_cast<std::size_t>(size));
  MPI_Request request;
  MPI_Iallgather(&length, 1, MPI_INT, lengths.data(), 1, MPI_INT, MPI_COMM_WORLD, &request);
  wait(request);
  int total = 0;
  for (int r = 0; r < size; ++r) offsets[std::size_t(r)] = total, total += lengths[std::size_t(r)];
  std::vector<char> all(std::size_t(std::max(total, 1)));
  MPI_Iallgatherv(mine.data(), length, MPI_CHAR, all.data(), lengths.data(), offsets.data(), MPI_CHAR,
                  MPI_COMM_WORLD, &request);
  wait(request);
  std::vector<std::string> out;
  for (int r = 0; r < size; ++r)
    out.emplace_back(all.data() + offsets[std::size_t(r)], std::size_t(lengths[std::size_t(r)]));
  return out;
}

// A rank other than 0: builds the cells rank 0 hands it until told to stop. Throws MpiJobFailed when the
// job failed (this rank's own failure is reported to rank 0, which reports it).
void buildHandedCells(const TriangleSource& source, const BuildOptions& options, const std::filesystem::path& work,
                      int ranks) {
  const SceneTransform transform = fitSceneCube(source.lower(), source.upper());
  const BinnedTriangles binned(scratchOf(work), ranks, source);
  Report report;
  std::string error;
  for (;;) {
    report.totals.peakResidentBytes = peakResidentBytes();
    send(0, kReportTag, pack(report, error));
    std::vector<char> rest;
    const Assignment a = front<Assignment>(receive(0, kAssignTag), &rest);
    if (a.kind == Assignment::kStop) return;
    if (a.kind != Assignment::kTask) throw MpiJobFailed();
    const CellTask task = unpackTask(a, rest);
    const auto start = std::chrono::steady_clock::now();
    try {
      CellRoot root;
      const VoxelTree tree = buildCell(source, transform, options, a.cellLevel, binned, task, root);
      writeCell(cellPath(work, task.coord), tree, root);
      report.kind = Report::kBuilt;
      report.task = a.task;
      report.root = root.record;
      report.weight = root.sums.weight;
      for (int k = 0; k < 4; ++k) report.color[k] = root.sums.color[k];
      for (int k = 0; k < 3; ++k) report.normal[k] = root.sums.normal[k];
      report.voxels = tree.voxels.size();
      ++report.totals.cells;
    } catch (const std::bad_alloc&) {
      report.kind = Report::kFailed;
      error = "out of memory building a cell (--memory bounds each rank; give it what one rank may use)";
    } catch (const std::exception& e) {
      report.kind = Report::kFailed;
      error = e.what();
    }
    report.totals.buildSeconds +=
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
}

}  // namespace

MpiJob::MpiJob() {
  int provided = 0;
  MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided);
  MPI_Comm_rank(MPI_COMM_WORLD, &rank_);
  MPI_Comm_size(MPI_COMM_WORLD, &size_);
  char name[MPI_MAX_PROCESSOR_NAME] = {};
  int length = 0;
  MPI_Get_processor_name(name, &length);
  host_.assign(name, std::size_t(length));
}

MpiJob::~MpiJob() {
  int finalized = 0;
  MPI_Finalized(&finalized);
  if (!finalized) MPI_Finalize();
}

void MpiJob::abort(const std::string& message) const {
  std::fprintf(stderr, "svo: %s\n", message.c_str());
  std::fflush(stderr);
  MPI_Abort(MPI_COMM_WORLD, 1);
  std::_Exit(1);
}

std::optional<MpiBuildReport> MpiJob::build(const TriangleSource* source, const std::string& openError,
                                            const BuildOptions& options, const StoreWriteOptions& write,
                                            const OutOfCoreOptions& ooc, const std::filesystem::path& store) {
  const std::vector<std::string> hosts = gather(host_, rank_, size_);
  const int mine = coresAvailable();
  std::vector<int> cores(static_cast<std::size_t>(size_));
  MPI_Gather(&mine, 1, MPI_INT, cores.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  if (rank_ == 0) warnOfFewCores(cores, hosts, ooc.threads);
  const std::vector<std::string> agreements =
      gather(agreementOf(source, openError, options, write, ooc, store).dump(), rank_, size_);
  settle(rank_ == 0 ? disagreement(agreements, hosts) : std::string(), rank_);
  const std::filesystem::path work = workFolderOf(ooc, store);
  settle(unsharedFolder(work, rank_, hosts), rank_);
  TopSharing sharing;
  sharing.rank = rank_, sharing.ranks = size_;
  sharing.exchange = [&](const std::string& mine) { return allGather(mine, size_); };
  if (rank_ != 0) {
    // Rank 0 settles the cell level (and the work folder), then every rank bins its share of the input.
    const Start start = front<Start>(receive(0, kStartTag));
    if (start.cellLevel == 0) throw MpiJobFailed();
    const SceneTransform transform = fitSceneCube(source->lower(), source->upper());
    // When the job failed there, rank 0 stops this rank at its first report.
    shareTopLevels(*source, transform, options, start.cellLevel, scratchOf(work), sharing);
    buildHandedCells(*source, options, work, size_);
    return std::nullopt;
  }
  bool started = false;
  sharing.start = [&](int cellLevel) {
    for (int r = 1; r < size_; ++r) send(r, kStartTag, pack(Start{cellLevel}));
    started = true;
  };
  sharing.describe = [&](int r) { return "rank " + std::to_string(r) + " on " + hosts[std::size_t(r)]; };
  Dispatcher dispatcher(hosts, ooc.threads);
  OutOfCoreOptions writing = ooc;
  const auto ranksHere = std::count(hosts.begin(), hosts.end(), host_);
  writing.writeThreads = std::min(ooc.threads * int(ranksHere), tbb::info::default_concurrency());
  MpiBuildReport report;
  try {
    report.build = buildStore(
        *source, options, write, writing, store, [&](const CellJobs& jobs) { return dispatcher.run(jobs); },
        sharing);
  } catch (...) {
    if (started)
      dispatcher.releaseAfterFailure();
    else
      for (int r = 1; r < size_; ++r) send(r, kStartTag, pack(Start{0}));
    throw;
  }
  for (int r = 0; r < size_; ++r) {
    const Totals& t = dispatcher.totals()[std::size_t(r)];
    report.ranks.push_back({r, hosts[std::size_t(r)], std::size_t(t.cells),
                            r == 0 ? peakResidentBytes() : t.peakResidentBytes, t.buildSeconds});
  }
  return report;
}

}  // namespace svo
