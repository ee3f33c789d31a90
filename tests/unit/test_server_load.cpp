// The paging server under many clients, clients that go away, its metrics and log, its stop, and the `svo
// serve` command as a child process. References as in test_server.cpp: the store files' own bytes.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <random>
#include <regex>
#include <thread>

#include <nlohmann/json.hpp>

#include "server_client.hpp"
#include "server_fixture.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;

namespace {

using svotest::httpGet;
using svotest::HttpReply;
using svotest::RunningServer;
using svotest::servedStores;
using svotest::slurp;

// A metric's value in Prometheus text (`name` with its labels, as written), or -1 when absent.
double metric(const std::string& text, const std::string& name) {
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);)
    if (line.rfind(name + " ", 0) == 0) return std::stod(line.substr(name.size() + 1));
  return -1;
}

// A connection whose receive buffer holds a few KB, so that the server cannot write a store in one go.
int smallWindowConnection(std::uint16_t port) {
  return svotest::connectRaw(port, 10, 4096);
}

TEST(ServerLoad, ClientsVanishingMidBodyLeaveItServing) {
  RunningServer r = svotest::startServer();
  const std::string file = slurp(servedStores().root / "sphere.svo");
  for (int i = 0; i < 20; ++i) {
    const int fd = smallWindowConnection(r.port);
    ASSERT_TRUE(svotest::sendRaw(fd, "GET /sphere.svo HTTP/1.1\r\nHost: x\r\n\r\n"));
    char head[512];
    EXPECT_GT(::recv(fd, head, sizeof head, 0), 0);
    // Gone with most of the body unread: a reset rather than a close.
    const linger reset{1, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_LINGER, &reset, sizeof reset);
    ::close(fd);
  }
  svotest::HttpClient client(r.port);
  EXPECT_EQ(client.get("/sphere.svo").body, file);
  EXPECT_EQ(client.get("/healthz").status, 200u);
}

TEST(ServerLoad, ConcurrentClientsGetTheStoredBytes) {
  svo::server::ServerOptions options;
  options.cacheBytes = 64 * 1024;  // a fraction of the sphere's slices: entries come and go under load
  RunningServer r = svotest::startServer(options);
  const std::string file = slurp(servedStores().root / "sphere.svo");
  const svo::StoreReader reader(servedStores().root / "sphere.svo");
  const auto& slices = reader.slices();
  constexpr int kThreads = 16, kRequests = 60;
  std::atomic<int> wrong{0}, sliceRequests{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t)
    threads.emplace_back([&, t] {
      std::mt19937 random(std::uint32_t(t) + 1);
      svotest::HttpClient client(r.port);
      for (int i = 0; i < kRequests; ++i) {
        if (i % 3 != 2) {
          const std::uint32_t id = std::uint32_t(random() % slices.size());
          const HttpReply reply = client.get("/sphere/slices/" + std::to_string(id));
          ++sliceRequests;
          if (reply.status != 200 || reply.body != file.substr(slices[id].offset, slices[id].compressedBytes))
            ++wrong;
        } else {
          const std::size_t first = random() % file.size();
          const std::size_t last = std::min(file.size() - 1, first + random() % 100000);
          const HttpReply reply = client.get(
              "/sphere.svo", {{"Range", "bytes=" + std::to_string(first) + "-" + std::to_string(last)}});
          if (reply.status != 206 || reply.body != file.substr(first, last - first + 1)) ++wrong;
        }
      }
    });
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(wrong, 0);
  // A response is counted once written, which the client may see before the server does: the last ones
  // are waited for.
  std::string metrics = httpGet(r.port, "/metrics").body;
  for (int i = 0; i < 200 && metric(metrics, "svo_slices_sent_total") != double(sliceRequests); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    metrics = httpGet(r.port, "/metrics").body;
  }
  EXPECT_EQ(metric(metrics, "svo_slice_cache_hits_total") + metric(metrics, "svo_slice_cache_misses_total"),
            double(sliceRequests));
  EXPECT_EQ(metric(metrics, "svo_slices_sent_total"), double(sliceRequests));
  EXPECT_LE(metric(metrics, "svo_slice_cache_bytes"), double(options.cacheBytes));
}

TEST(ServerLoad, MetricsCountWhatWasServed) {
  RunningServer r = svotest::startServer();
  const svo::SliceInfo s = svo::StoreReader(servedStores().root / "sphere.svo").slices()[0];
  // One connection: the server counts a response once written, before it reads the connection's next
  // request, so /metrics on it sees every request before it.
  svotest::HttpClient client(r.port);
  for (int i = 0; i < 3; ++i) EXPECT_EQ(client.get("/sphere/slices/0").status, 200u);
  EXPECT_EQ(client.get("/nosuch").status, 404u);
  EXPECT_EQ(client.request("HEAD", "/sphere/slices/0").status, 200u);
  const HttpReply reply = client.get("/metrics");
  EXPECT_EQ(reply.header("content-type"), "text/plain; version=0.0.4; charset=utf-8");
  const std::string& m = reply.body;
  EXPECT_EQ(metric(m, "svo_slice_cache_misses_total"), 1);
  EXPECT_EQ(metric(m, "svo_slice_cache_hits_total"), 3);
  EXPECT_EQ(metric(m, "svo_slice_cache_hit_ratio"), 0.75);
  EXPECT_EQ(metric(m, "svo_slices_sent_total"), 3);  // HEAD sends no slice
  EXPECT_EQ(metric(m, "svo_slice_cache_bytes"), double(s.compressedBytes + 192));
  EXPECT_EQ(metric(m, "svo_http_requests_total{route=\"slice\",status=\"200\"}"), 4);
  EXPECT_EQ(metric(m, "svo_http_requests_total{route=\"scene\",status=\"404\"}"), 1);
  EXPECT_EQ(metric(m, "svo_http_request_duration_seconds_count"), 5);
  EXPECT_GE(metric(m, "svo_http_sent_bytes_total"), 3.0 * s.compressedBytes);
  EXPECT_EQ(metric(m, "svo_http_open_connections"), 1);  // this one
  {
    std::vector<std::unique_ptr<svotest::HttpClient>> more;
    for (int i = 0; i < 3; ++i) {
      more.push_back(std::make_unique<svotest::HttpClient>(r.port));
      EXPECT_EQ(more.back()->get("/healthz").status, 200u);  // accepted and served: counted as open
    }
    EXPECT_EQ(metric(client.get("/metrics").body, "svo_http_open_connections"), 4);
  }
  // Closed by the clients; the server notices each as it reads the end of its stream.
  double open = 4;
  for (int i = 0; i < 200 && open != 1; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    open = metric(client.get("/metrics").body, "svo_http_open_connections");
  }
  EXPECT_EQ(open, 1);
}

TEST(ServerLoad, JsonLogHasOneObjectPerRequest) {
  svo::server::ServerOptions options;
  options.logFormat = svo::server::LogFormat::Json;
  RunningServer r = svotest::startServer(options);
  EXPECT_EQ(httpGet(r.port, "/healthz").status, 200u);
  EXPECT_EQ(httpGet(r.port, "/sphere/slices/999999").status, 404u);
  r.server->stop();  // every line written
  int requests = 0;
  for (const std::string& line : r.log->copy()) {
    const nlohmann::json j = nlohmann::json::parse(line);  // throws, failing the test, if not one object
    EXPECT_TRUE(j.contains("time") && j.contains("level")) << line;
    if (!j.contains("target")) continue;
    ++requests;
    EXPECT_EQ(j.at("method"), "GET");
    EXPECT_GT(j.at("bytes").get<std::uint64_t>(), 0u);
    EXPECT_GE(j.at("us").get<std::int64_t>(), 0);
    EXPECT_EQ(j.at("peer").get<std::string>().rfind("127.0.0.1:", 0), 0u);
    EXPECT_EQ(j.at("status"), j.at("target") == "/healthz" ? 200 : 404) << line;
  }
  EXPECT_EQ(requests, 2);
}

TEST(ServerLoad, StopLetsTheResponseInFlightFinish) {
  RunningServer r = svotest::startServer();
  const std::string file = slurp(servedStores().root / "sphere.svo");
  const int fd = smallWindowConnection(r.port);
  ASSERT_TRUE(svotest::sendRaw(fd, "GET /sphere.svo HTTP/1.1\r\nHost: x\r\n\r\n"));
  char first[64];
  ASSERT_GT(::recv(fd, first, sizeof first, 0), 0);
  std::thread stopper([&] { r.server->stop(); });
  const std::string raw = std::string(first, sizeof first) + svotest::receiveAll(fd);
  ::close(fd);
  stopper.join();
  const std::size_t body = raw.find("\r\n\r\n");
  ASSERT_NE(body, std::string::npos);
  EXPECT_EQ(raw.substr(body + 4), file);
  EXPECT_THROW(httpGet(r.port, "/healthz"), std::exception);  // no longer listening
}

TEST(ServerLoad, RefusesMissingAndStorelessFolders) {
  svo::server::ServerOptions options;
  options.root = servedStores().root / "no such folder";
  EXPECT_THROW(svo::server::Server{options}, std::runtime_error);
  const fs::path empty = fs::temp_directory_path() / ("svo_serve_empty_" + std::to_string(::getpid()));
  fs::create_directories(empty / "sub");
  options.root = empty;
  try {
    svo::server::Server server(options);
    ADD_FAILURE() << "a folder without stores was accepted";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("no .svo store"), std::string::npos) << e.what();
  }
  fs::remove_all(empty);
}

TEST(ServerLoad, ReplacedStoreIsServedAnew) {
  const fs::path root = fs::temp_directory_path() / ("svo_serve_replace_" + std::to_string(::getpid()));
  fs::create_directories(root);
  fs::copy_file(servedStores().root / "sub" / "box.svo", root / "a.svo");
  svo::server::ServerOptions options;
  options.root = root;
  RunningServer r = svotest::startServer(options);
  const std::string box = slurp(root / "a.svo");
  EXPECT_EQ(httpGet(r.port, "/a.svo").body, box);
  // Replaced the way the store writer finishes a file: written beside it, renamed over it.
  fs::copy_file(servedStores().root / "sphere.svo", root / "a.svo.tmp");
  fs::rename(root / "a.svo.tmp", root / "a.svo");
  const std::string sphere = slurp(root / "a.svo");
  std::string served = box;
  for (int i = 0; i < 100 && served != sphere; ++i) {  // the catalog looks again after a second
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    served = httpGet(r.port, "/a.svo").body;
  }
  EXPECT_EQ(served, sphere);
  const svo::StoreReader reader(root / "a.svo");
  EXPECT_EQ(nlohmann::json::parse(httpGet(r.port, "/a/info").body).at("sliceCount"), reader.slices().size());
  const HttpReply slice = httpGet(r.port, "/a/slices/1");
  EXPECT_EQ(slice.body, sphere.substr(reader.slices()[1].offset, reader.slices()[1].compressedBytes));
  r.server->stop();
  fs::remove_all(root);
}

// `svo serve` as a child process, its stdout on a pipe.
struct Child {
  pid_t pid = -1;
  int out = -1;
};

Child spawn(const std::vector<std::string>& args) {
  int pipeFds[2];
  EXPECT_EQ(::pipe(pipeFds), 0);
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(pipeFds[1], 1);
    ::close(pipeFds[0]);
    std::vector<char*> argv;
    for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    ::execv(argv[0], argv.data());
    ::_exit(127);
  }
  ::close(pipeFds[1]);
  return {pid, pipeFds[0]};
}

// The first line the child prints, waiting at most ~20 s.
std::string firstLine(int fd) {
  std::string line;
  for (int i = 0; i < 200 && line.find('\n') == std::string::npos; ++i) {
    pollfd p{fd, POLLIN, 0};
    if (::poll(&p, 1, 100) <= 0) continue;
    char buffer[256];
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n <= 0) break;
    line.append(buffer, std::size_t(n));
  }
  return line.substr(0, line.find('\n'));
}

// The child's exit status once it has ended (waiting at most ~20 s, then killing it): -1 if killed.
int exitStatus(pid_t pid) {
  int status = 0;
  for (int i = 0; i < 200; ++i) {
    if (::waitpid(pid, &status, WNOHANG) == pid) return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ::kill(pid, SIGKILL);
  ::waitpid(pid, &status, 0);
  return -1;
}

// The command under test: the AddressSanitizer build when tools/scripts/test.sh made one.
std::string svoBinary() {
  const char* asan = std::getenv("SVO_ASAN_BINARY");
  return asan && *asan ? asan : SVO_BINARY;
}

TEST(ServeCommand, ServesUntilSigterm) {
  const Child child =
      spawn({svoBinary(), "serve", servedStores().root.string(), "--port", "0", "--threads", "2"});
  const std::string line = firstLine(child.out);
  std::smatch match;
  ASSERT_TRUE(std::regex_search(line, match, std::regex("http://127\\.0\\.0\\.1:([0-9]+)/"))) << line;
  const auto port = std::uint16_t(std::stoi(match[1]));
  EXPECT_NE(line.find("4 stores"), std::string::npos) << line;
  EXPECT_EQ(httpGet(port, "/healthz").body, "ok\n");
  const std::string file = slurp(servedStores().root / "sub" / "box.svo");
  EXPECT_EQ(httpGet(port, "/sub/box.svo").body, file);
  // A little of every path through the command's server (under AddressSanitizer in tools/scripts/test.sh).
  const svo::StoreReader reader(servedStores().root / "sub" / "box.svo");
  const svo::SliceInfo& s = reader.slices().back();
  svotest::HttpClient client(port);
  EXPECT_EQ(client.get("/scenes/sub/box/slices/" + std::to_string(reader.slices().size() - 1)).body,
            file.substr(s.offset, s.compressedBytes));
  EXPECT_EQ(client.get("/sub/box", {{"Range", "bytes=-100"}}).body, file.substr(file.size() - 100));
  EXPECT_EQ(client.get("/sub/box/info").status, 200u);
  EXPECT_EQ(client.get("/%2E%2E/x.svo").status, 400u);
  EXPECT_EQ(client.get("/corrupt/slices/" + std::to_string(servedStores().corruptSlice)).status, 500u);
  EXPECT_EQ(client.get("/metrics").status, 200u);
  EXPECT_EQ(svotest::rawStatus(port, "GARBAGE\r\n\r\n"), 400u);
  ::kill(child.pid, SIGTERM);
  EXPECT_EQ(exitStatus(child.pid), 0);
  ::close(child.out);
}

TEST(ServeCommand, RefusesAFolderWithoutStores) {
  const fs::path empty = fs::temp_directory_path() / ("svo_serve_none_" + std::to_string(::getpid()));
  fs::create_directories(empty);
  const Child child = spawn({svoBinary(), "serve", empty.string(), "--port", "0"});
  EXPECT_EQ(firstLine(child.out), "");  // nothing on stdout: the error is one line on stderr
  EXPECT_EQ(exitStatus(child.pid), 1);
  ::close(child.out);
  fs::remove_all(empty);
}

TEST(ServeCommand, BenchServeMeasuresBothPeers) {
  if (std::system("command -v wrk >/dev/null && command -v nginx >/dev/null") != 0)
    GTEST_SKIP() << "wrk or nginx is not installed (tools/scripts/install-deps.sh installs them)";
  const fs::path out = fs::temp_directory_path() / ("svo_bench_serve_" + std::to_string(::getpid()) + ".txt");
  const std::string command = std::string(SVO_BINARY) + " bench serve " +
                              (servedStores().root / "sphere.svo").string() +
                              " --seconds 1 --runs 1 --connections 8 --threads 1 >" + out.string() + " 2>&1";
  ASSERT_EQ(std::system(command.c_str()), 0) << slurp(out);
  const std::string text = slurp(out);
  fs::remove(out);
  // Both peers served every request: some requests each, and no error on either side.
  std::smatch m;
  ASSERT_TRUE(std::regex_search(text, m, std::regex(R"(requests/s +([0-9,]+) +([0-9,]+) +[0-9.]+)"))) << text;
  EXPECT_NE(m[1].str(), "0") << text;
  EXPECT_NE(m[2].str(), "0") << text;
  EXPECT_TRUE(std::regex_search(text, std::regex(R"(errors \(status >= 400, socket\) +0 +0)"))) << text;
}

}  // namespace
