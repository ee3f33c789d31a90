// `svo bench serve STORE`: raw slice GETs on loopback, `svo serve` against nginx serving the same file by
// byte ranges, measured in the same run with wrk (64 keep-alive connections by default). Each peer runs as
// its own process from a scratch folder holding the store; wrk cycles through every slice (GET
// /NAME/slices/ID for svo serve; GET /NAME.svo with Range: bytes=OFFSET-END for nginx: the same bytes),
// then fetches the whole store (GET /NAME.svo from both). Runs alternate between the peers and the two
// loads after one warm-up each; medians of requests/s, MB/s, p50 and p99 latency (wrk's), and each peer's
// resident set when listening and at its peak (svo serve's process; nginx's master and workers). Then
// --viewers clients, each with its own view, fetch what their views plan at once: from svo serve's view
// stream and from nginx by range requests (bench_serve_streams.hpp).
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstring>
#include <fstream>
#include <memory>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <fmt/format.h>

#include "bench_common.hpp"
#include "bench_serve_streams.hpp"
#include "measure.hpp"
#include "nginx_peer.hpp"
#include "number_checks.hpp"
#include "process.hpp"
#include "svo/store/store_reader.hpp"

extern char** environ;

namespace svo::tools::bench {
namespace fs = std::filesystem;
namespace {

// The load the service is sized for: many viewers' pagers, a few connections each.
constexpr int kDefaultConnections = 64;
// Short runs, several of them: the default bench stays under half a minute.
constexpr double kDefaultSeconds = 2.0;
constexpr int kDefaultRuns = 3;
constexpr int kWarmupSeconds = 1;
// wrk's own threads: on a small machine the load generator shares the cores with the peer it measures.
constexpr int kDefaultWrkThreads = 2;
// Requests in the wrk script: every slice of a store up to this many, else this many spread evenly.
constexpr std::size_t kMaxTargets = 4096;
// Viewers streaming their own views at once in the many-viewers run, and each one's pool.
constexpr int kDefaultViewers = 64;
constexpr std::uint64_t kDefaultViewerBudget = std::uint64_t(64) << 20;

struct ServeArgs {
  std::string store;
  int connections = kDefaultConnections;
  double seconds = kDefaultSeconds;
  int runs = kDefaultRuns;
  int threads = 0;
  int wrkThreads = kDefaultWrkThreads;
  int viewers = kDefaultViewers;
  std::uint64_t viewerBudget = kDefaultViewerBudget;
  std::string nginx = "nginx";
};

// A process's resident set field ("VmHWM", "VmRSS") in bytes, 0 when unknown.
std::uint64_t statusBytes(pid_t pid, const std::string& field) {
  std::ifstream in(fmt::format("/proc/{}/status", pid));
  for (std::string line; std::getline(in, line);)
    if (line.rfind(field + ":", 0) == 0) return std::stoull(line.substr(field.size() + 1)) * 1024;
  return 0;
}

// A resident set field of `pid` and of its children (nginx's workers), summed.
std::uint64_t residentBytes(pid_t pid, const std::string& field) {
  std::uint64_t total = 0;
  for (const pid_t p : processAndChildren(pid)) total += statusBytes(p, field);
  return total;
}

// One request of the load: a path and, for a byte range, its Range value.
struct Target {
  std::string path, range;
};

// The wrk script cycling through `targets`, each thread from its own place, printing its summary as one
// line wrk's own output cannot be confused with.
std::string wrkScript(const std::vector<Target>& targets) {
  std::string s = "local targets = {\n";
  for (const Target& t : targets)
    s += t.range.empty() ? fmt::format("  {{\"{}\"}},\n", t.path)
                         : fmt::format("  {{\"{}\", \"{}\"}},\n", t.path, t.range);
  s += R"(}
local counter = 0
function setup(thread)
  thread:set("id", counter)
  counter = counter + 1
end
function init(args)
  prepared = {}
  for k, t in ipairs(targets) do
    local headers = {}
    if t[2] then headers["Range"] = t[2] end
    prepared[k] = wrk.format("GET", t[1], headers)
  end
  i = (id or 0) * 7919 % #prepared
end
function request()
  i = i % #prepared + 1
  return prepared[i]
end
function done(summary, latency, requests)
  local e = summary.errors
  io.write(string.format("SVO-BENCH %d %d %d %d %.1f %.1f\n", summary.requests, summary.bytes,
    summary.duration, e.connect + e.read + e.write + e.status + e.timeout, latency:percentile(50),
    latency:percentile(99)))
end
)";
  return s;
}

struct Load {
  double requestsPerSecond = 0, megabytesPerSecond = 0, p50Seconds = 0, p99Seconds = 0;
  std::uint64_t errors = 0;
};

Load runWrk(const ServeArgs& args, std::uint16_t port, const fs::path& script, double seconds) {
  const std::vector<std::string> argv = {"wrk",
                                         "-t",
                                         std::to_string(args.wrkThreads),
                                         "-c",
                                         std::to_string(args.connections),
                                         "-d",
                                         fmt::format("{}s", std::max(1, int(seconds + 0.5))),
                                         "-s",
                                         script.string(),
                                         fmt::format("http://127.0.0.1:{}/", port)};
  const std::optional<ProcessResult> r = runProcess(argv, {{}, true});
  if (!r) throw std::runtime_error("wrk: cannot start it (is the wrk package installed?)");
  const std::size_t at = r->output.find("SVO-BENCH ");
  if (!r->succeeded() || at == std::string::npos) throw std::runtime_error("wrk failed: " + r->output);
  std::istringstream in(r->output.substr(at + 10));
  double requests = 0, bytes = 0, micros = 0, errors = 0, p50 = 0, p99 = 0;
  in >> requests >> bytes >> micros >> errors >> p50 >> p99;
  const double duration = std::max(micros, 1.0) * 1e-6;
  return {requests / duration, bytes / duration / 1e6, p50 * 1e-6, p99 * 1e-6, std::uint64_t(errors)};
}

std::string ratio(double a, double b) {
  return b > 0 ? fmt::format("{:.2f}", a / b) : "-";
}
std::string micros(double seconds) {
  return fmt::format("{:.0f} us", seconds * 1e6);
}

}  // namespace

namespace {

struct Peer {
  std::unique_ptr<Child> process;
  std::uint16_t port = 0;
  std::uint64_t startResident = 0, peakResident = 0;
};

// One kind of request, measured on both peers: the wrk script of each and their runs.
struct Workload {
  std::string title, nginxColumn;
  fs::path scripts[2];  // svo serve's, nginx's
  std::vector<Load> runs[2];
};

double median(const std::vector<Load>& runs, double Load::*field) {
  std::vector<double> v;
  for (const Load& l : runs) v.push_back(l.*field);
  return summarize(v).median;
}

void printWorkload(const Workload& w) {
  printTitle(w.title);
  Table table({"", "svo serve", w.nginxColumn, "svo / nginx"});
  const auto row = [&](const std::string& what, double Load::*field, auto format) {
    const double a = median(w.runs[0], field), b = median(w.runs[1], field);
    table.addRow({what, format(a), format(b), ratio(a, b)});
  };
  row("requests/s", &Load::requestsPerSecond, [](double v) { return formatCount(std::uint64_t(v)); });
  row("MB/s (heads and bodies)", &Load::megabytesPerSecond,
      [](double v) { return fmt::format("{:.0f}", v); });
  row("p50 latency", &Load::p50Seconds, micros);
  row("p99 latency", &Load::p99Seconds, micros);
  std::uint64_t errors[2] = {0, 0};
  for (int p = 0; p < 2; ++p)
    for (const Load& l : w.runs[p]) errors[p] += l.errors;
  table.addRow({"errors (status >= 400, socket)", formatCount(errors[0]), formatCount(errors[1]), ""});
  table.print();
}

void printResults(const ServeArgs& args, const StoreReader& reader, int threads,
                  const std::vector<Workload>& workloads, const Peer& svo, const Peer& nginx) {
  std::uint64_t compressed = 0;
  for (const SliceInfo& s : reader.slices()) compressed += s.compressedBytes;
  std::printf("%s: %s, %s slices (mean %.1f KB compressed)\n", args.store.c_str(),
              formatBytes(reader.header().fileBytes).c_str(), formatCount(reader.slices().size()).c_str(),
              double(compressed) / double(reader.slices().size()) / 1e3);
  std::printf(
      "loopback, %d keep-alive connections, wrk %d threads; %d svo serve threads / nginx workers; "
      "median of %d runs of %g s after a warm-up\n",
      args.connections, args.wrkThreads, threads, args.runs, args.seconds);
  for (const Workload& w : workloads) printWorkload(w);
  printTitle("Memory (nginx: master + workers)");
  Table memory({"", "svo serve", "nginx", "svo / nginx"});
  memory.addRow({"RSS when listening", formatBytes(svo.startResident), formatBytes(nginx.startResident),
                 ratio(double(svo.startResident), double(nginx.startResident))});
  memory.addRow({"peak RSS", formatBytes(svo.peakResident), formatBytes(nginx.peakResident),
                 ratio(double(svo.peakResident), double(nginx.peakResident))});
  memory.print();
  std::printf(
      "\nsvo serve sends slices from its cache (checked once against their checksums) and whole files by\n"
      "pread in 256 KiB chunks; nginx sends from the page cache with sendfile. svo serve's resident set\n"
      "starts with the whole svo binary's libraries. Ratios above 1: svo serve higher (better for\n"
      "requests/s and MB/s, worse for latency and memory).\n");
}

void printManyViewers(const ServeArgs& args, const ManyViewers& svo, const ManyViewers& nginx) {
  printTitle(fmt::format("{} viewers at once, each its own view (512 px, a {} pool): svo serve's view stream vs "
                         "nginx by range requests",
                         args.viewers, formatBytes(args.viewerBudget)));
  Table table({"", "svo serve (stream)", "nginx (ranges)", "svo / nginx"});
  const auto mbps = [](const ManyViewers& v) { return double(v.bytes) / 1e6 / std::max(1e-9, v.seconds); };
  const auto cpuPerMb = [](const ManyViewers& v) {
    return 1e6 * v.serverCpuSeconds / std::max(1e-9, double(v.bytes) / 1e6);
  };
  table.addRow({"viewers converged", fmt::format("{} of {}", svo.converged, svo.clients),
                fmt::format("{} of {}", nginx.converged, nginx.clients), ""});
  table.addRow({"until the last converged", formatSeconds(svo.seconds), formatSeconds(nginx.seconds),
                ratio(svo.seconds, nginx.seconds)});
  table.addRow({"until the median one did", formatSeconds(svo.medianSeconds), formatSeconds(nginx.medianSeconds),
                ratio(svo.medianSeconds, nginx.medianSeconds)});
  table.addRow({"aggregate MB/s", fmt::format("{:.0f}", mbps(svo)), fmt::format("{:.0f}", mbps(nginx)),
                ratio(mbps(svo), mbps(nginx))});
  table.addRow({"server CPU per MB", fmt::format("{:.0f} us", cpuPerMb(svo)), fmt::format("{:.0f} us", cpuPerMb(nginx)),
                ratio(cpuPerMb(svo), cpuPerMb(nginx))});
  table.addRow({"slices read by range (stream fallback)", std::to_string(svo.pulled), "all", ""});
  table.print();
  std::printf("the run of median time of %d per peer (alternating); ", args.runs);
  std::printf("a viewer has converged when every slice its view plans (the scheduler within its pool) arrived and "
              "passed the store's check; nginx: a slice per request, one connection per viewer\n");
}

// The peer `which` (0: svo serve, 1: nginx) started over `root`, listening.
Peer startPeer(int which, const ServeArgs& args, const fs::path& scratch, const fs::path& root, int threads) {
  Peer p;
  p.port = freePort();
  if (which == 0) {
    p.process = std::make_unique<Child>(
        std::vector<std::string>{fs::read_symlink("/proc/self/exe").string(), "serve", root.string(),
                                 "--port", std::to_string(p.port), "--threads", std::to_string(threads),
                                 "--no-request-log"},
        scratch / "svo-serve.log");
  } else {
    p.process = startNginx(args.nginx, scratch, root, p.port, threads);
  }
  waitUntilListening(*p.process, p.port, which == 0 ? "svo serve" : "nginx");
  p.startResident = residentBytes(p.process->pid(), "VmRSS");
  return p;
}

void runServeBench(const ServeArgs& args) {
  requireRuns(args.runs);
  if (args.connections < args.wrkThreads)
    throw UsageError("--connections must be at least --wrk-threads (wrk gives each thread a connection)");
  const StoreReader reader(args.store);  // a bad store fails here, with one line naming it
  const int threads =
      args.threads > 0 ? args.threads : int(std::max(1u, std::thread::hardware_concurrency()));
  ScratchFolder scratch(fs::temp_directory_path() / fmt::format("svo-bench-serve-{}", ::getpid()));
  const std::string name = fs::path(args.store).stem().string();
  const fs::path root = scratch.path / "root";
  scratch.serve(args.store);

  const std::vector<SliceInfo>& slices = reader.slices();
  const std::size_t count = std::min(slices.size(), kMaxTargets);
  std::vector<Target> bySlice, byRange;
  const std::string file = "/" + urlSegment(name + ".svo");
  for (std::size_t k = 0; k < count; ++k) {
    const std::size_t id = k * slices.size() / count;
    const SliceInfo& s = slices[id];
    bySlice.push_back({fmt::format("/{}/slices/{}", urlSegment(name), id), ""});
    byRange.push_back({file, fmt::format("bytes={}-{}", s.offset, s.offset + s.compressedBytes - 1)});
  }
  std::vector<Workload> workloads(2);
  workloads[0].title = "Slice GETs (every slice in turn)";
  workloads[0].nginxColumn = "nginx (byte ranges)";
  workloads[0].scripts[0] = scratch.path / "slices.lua";
  workloads[0].scripts[1] = scratch.path / "ranges.lua";
  std::ofstream(workloads[0].scripts[0]) << wrkScript(bySlice);
  std::ofstream(workloads[0].scripts[1]) << wrkScript(byRange);
  workloads[1].title = "Whole-store GETs";
  workloads[1].nginxColumn = "nginx";
  workloads[1].scripts[0] = workloads[1].scripts[1] = scratch.path / "file.lua";
  std::ofstream(workloads[1].scripts[0]) << wrkScript({{file, ""}});

  Peer peers[2] = {startPeer(0, args, scratch.path, root, threads),
                   startPeer(1, args, scratch.path, root, threads)};
  for (Workload& w : workloads)
    for (int p = 0; p < 2; ++p) runWrk(args, peers[p].port, w.scripts[p], kWarmupSeconds);
  for (int run = 0; run < args.runs; ++run)
    for (Workload& w : workloads)
      for (int p = 0; p < 2; ++p)
        w.runs[p].push_back(runWrk(args, peers[p].port, w.scripts[p], args.seconds));
  for (Peer& p : peers) p.peakResident = residentBytes(p.process->pid(), "VmHWM");
  printResults(args, reader, threads, workloads, peers[0], peers[1]);
  if (args.viewers > 0) {
    const std::string base = "http://127.0.0.1:";
    std::vector<ManyViewers> runs[2];
    for (int run = 0; run < args.runs; ++run) {
      runs[0].push_back(runManyViewers(base + std::to_string(peers[0].port) + "/" + urlSegment(name), reader,
                                       peers[0].process->pid(), args.viewers, args.viewerBudget, true));
      runs[1].push_back(runManyViewers(base + std::to_string(peers[1].port) + file, reader,
                                       peers[1].process->pid(), args.viewers, args.viewerBudget, false));
    }
    const ManyViewers viewers[2] = {medianRun(runs[0]), medianRun(runs[1])};
    printManyViewers(args, viewers[0], viewers[1]);
  }
}

}  // namespace

void addServeBench(CLI::App& bench) {
  auto args = std::make_shared<ServeArgs>();
  CLI::App* cmd = bench.add_subcommand("serve",
                                       "slice and whole-store GETs from `svo serve` vs nginx serving the "
                                       "same file by byte ranges (wrk, loopback)");
  cmd->add_option("store", args->store, "a .svo store")->required()->check(CLI::ExistingFile);
  cmd->add_option("--connections", args->connections, "concurrent keep-alive connections")
      ->check(CLI::Range(1, 10000))
      ->capture_default_str();
  cmd->add_option("--seconds", args->seconds, "length of each timed run")
      ->check(finiteRange(1.0, 600.0))
      ->capture_default_str();
  cmd->add_option("--runs", args->runs, "timed runs per peer (alternating); the median is reported")
      ->capture_default_str();
  cmd->add_option("--threads", args->threads, "svo serve's threads and nginx's workers (0: one per core)")
      ->check(CLI::Range(0, 256))
      ->capture_default_str();
  cmd->add_option("--wrk-threads", args->wrkThreads, "wrk's threads")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd->add_option("--nginx", args->nginx, "the nginx binary")->capture_default_str();
  cmd->add_option("--viewers", args->viewers,
                  "clients streaming their own views at once after the GET loads (0: none)")
      ->check(CLI::Range(0, 1000))
      ->capture_default_str();
  cmd->add_option("--viewer-budget", args->viewerBudget, "each viewer's pool (bytes; 64M)")
      ->transform(CLI::AsSizeValue(false))
      ->capture_default_str();
  cmd->callback([args] { runServeBench(*args); });
}

}  // namespace svo::tools::bench
