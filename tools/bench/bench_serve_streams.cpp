#include "bench_serve_streams.hpp"

#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>
#include <numbers>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <vector>

#include "measure.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/stream_source.hpp"
#include "svo/store/view_stream.hpp"

namespace svo::tools::bench {
namespace {

// Each viewer's image: a viewer window's size.
constexpr int kViewerPixels = 512;
// The views' LOD target: render's default.
constexpr double kViewerLodPixels = 1.0;
// Clients have this long to open their streams (loopback: milliseconds each).
constexpr std::chrono::seconds kConnectTimeout{30};

}  // namespace

std::vector<pid_t> processAndChildren(pid_t pid) {
  std::vector<pid_t> tree{pid};
  for (const auto& entry : std::filesystem::directory_iterator("/proc")) {
    const std::string name = entry.path().filename().string();
    if (name.find_first_not_of("0123456789") != std::string::npos) continue;
    std::ifstream in(entry.path() / "status");
    for (std::string line; std::getline(in, line);)
      if (line.rfind("PPid:", 0) == 0) {
        if (std::stoi(line.substr(5)) == pid) tree.push_back(std::stoi(name));
        break;
      }
  }
  return tree;
}

namespace {

// User + system CPU seconds of process `pid` and its children so far (/proc/PID/stat fields 14 and 15, in
// clock ticks); 0 for a process gone meanwhile.
double processCpuSeconds(pid_t pid) {
  double ticks = 0.0;
  for (const pid_t p : processAndChildren(pid)) {
    std::ifstream in("/proc/" + std::to_string(p) + "/stat");
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    const std::size_t close = text.rfind(')');  // the command name may hold spaces
    if (close == std::string::npos) continue;
    std::istringstream fields(text.substr(close + 2));
    std::string skip;
    for (int field = 3; field < 14; ++field) fields >> skip;
    double user = 0, system = 0;
    fields >> user >> system;
    ticks += user + system;
  }
  return ticks / double(::sysconf(_SC_CLK_TCK));
}

// Client `i` of `n`: the scene framed from its own direction, around the vertical and up and down.
ViewQuery viewerView(const SceneTransform& scene, int i, int n) {
  const double azimuth = 2.0 * std::numbers::pi * (i + 0.5) / n;
  const double elevation = 0.6 * std::sin(7.0 * azimuth);  // spread over heights, deterministic
  const glm::dvec3 direction{std::cos(azimuth), elevation, std::sin(azimuth)};
  return viewOf(scene, Camera::framing(scene, -direction, kViewerPixels, kViewerPixels), kViewerLodPixels);
}

}  // namespace

ManyViewers runManyViewers(const std::string& url, const StoreReader& reader, pid_t server, int clients,
                           std::uint64_t budgetBytes, bool viewStream) {
  RemoteOptions remote;
  remote.viewStream = viewStream;
  std::vector<std::shared_ptr<SliceSource>> sources;
  for (int i = 0; i < clients; ++i) sources.push_back(openSliceSource(url, remote));
  if (viewStream) {
    const auto deadline = std::chrono::steady_clock::now() + kConnectTimeout;
    for (const auto& s : sources)
      while (!static_cast<const ViewStreamSource&>(*s).streaming()) {
        if (std::chrono::steady_clock::now() > deadline)
          throw std::runtime_error(url + ": the view streams did not open within 30 s");
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      }
  }
  std::vector<ViewQuery> views;
  std::vector<std::vector<std::uint32_t>> plans;
  for (int i = 0; i < clients; ++i) {
    views.push_back(viewerView(reader.header().transform, i, clients));
    plans.push_back(stream::planSlices(reader.index(), views.back(), budgetBytes));
  }

  ManyViewers r;
  r.clients = clients;
  std::vector<double> done(clients, 0.0);
  std::atomic<int> converged{0};
  std::atomic<std::uint64_t> bytes{0};
  const double cpuBefore = processCpuSeconds(server);
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::thread> threads;
  for (int i = 0; i < clients; ++i)
    threads.emplace_back([&, i] {
      bool ok = true;
      try {
        sources[i]->follow(views[i], budgetBytes);
        SliceBytes slice;
        for (const std::uint32_t id : plans[i]) {
          sources[i]->fetch(id, slice);
          checkSlice(reader.index(), id, slice);
          bytes += slice.size();
        }
      } catch (const std::exception&) {
        ok = false;
      }
      done[i] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      converged += ok;
    });
  for (std::thread& t : threads) t.join();
  r.serverCpuSeconds = processCpuSeconds(server) - cpuBefore;
  r.converged = converged;
  r.bytes = bytes;
  r.seconds = *std::max_element(done.begin(), done.end());
  r.medianSeconds = percentile(done, 0.5);
  for (const auto& s : sources)
    if (const auto* stream = dynamic_cast<const ViewStreamSource*>(s.get()))
      r.pulled += stream->stats().pulled;
  return r;
}

ManyViewers medianRun(std::vector<ManyViewers> runs) {
  std::sort(runs.begin(), runs.end(),
            [](const ManyViewers& a, const ManyViewers& b) { return a.seconds < b.seconds; });
  return runs[runs.size() / 2];
}

}  // namespace svo::tools::bench
