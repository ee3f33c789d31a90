#include "nginx_peer.hpp"

#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <thread>

#include <fmt/format.h>

extern char** environ;

namespace svo::tools::bench {
namespace fs = std::filesystem;
namespace {

// A peer has this long to start listening (polled every 50 ms).
constexpr std::chrono::seconds kStartTimeout{10};
// A peer has this long to exit after SIGTERM before it is killed.
constexpr std::chrono::seconds kStopTimeout{5};

bool accepts(std::uint16_t port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  const bool ok = fd >= 0 && ::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) == 0;
  if (fd >= 0) ::close(fd);
  return ok;
}

// nginx's config: sendfile without tcp_nopush, its fastest here on loopback (120 KB ranges, 64 connections,
// 2 workers: sendfile 18-27k requests/s, without sendfile 14-20k, sendfile with tcp_nopush 2.3k).
std::string nginxConfig(const fs::path& dir, const fs::path& root, std::uint16_t port, int workers) {
  const std::string d = dir.string();
  return fmt::format(R"(daemon off;
master_process on;
worker_processes {workers};
pid {d}/nginx.pid;
error_log {d}/nginx-error.log;
events {{ worker_connections 1024; }}
http {{
  access_log off;
  client_body_temp_path {d}/body;
  proxy_temp_path {d}/proxy;
  fastcgi_temp_path {d}/fastcgi;
  uwsgi_temp_path {d}/uwsgi;
  scgi_temp_path {d}/scgi;
  default_type application/octet-stream;
  sendfile on;
  keepalive_requests 1000000;
  open_file_cache max=64;
  server {{
    listen 127.0.0.1:{port};
    root {root};
  }}
}}
)",
                     fmt::arg("workers", workers), fmt::arg("d", d), fmt::arg("port", port),
                     fmt::arg("root", root.string()));
}

}  // namespace

Child::Child(const std::vector<std::string>& argv, const fs::path& log) : log_(log) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  std::vector<std::string> arguments = argv;
  std::vector<char*> argp;
  for (std::string& a : arguments) argp.push_back(a.data());
  argp.push_back(nullptr);
  const int spawned = ::posix_spawnp(&pid_, argp[0], &actions, nullptr, argp.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (spawned != 0) throw std::runtime_error(argv[0] + ": cannot start it (" + std::strerror(spawned) + ")");
}

bool Child::running() {
  if (pid_ <= 0) return false;
  int status = 0;
  if (::waitpid(pid_, &status, WNOHANG) != pid_) return true;
  pid_ = -1;
  return false;
}

std::string Child::log() const {
  std::ifstream in(log_);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

void Child::stop() {
  if (pid_ <= 0) return;
  ::kill(pid_, SIGTERM);
  const auto deadline = std::chrono::steady_clock::now() + kStopTimeout;
  while (running() && std::chrono::steady_clock::now() < deadline)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  if (pid_ > 0) {
    ::kill(pid_, SIGKILL);
    ::waitpid(pid_, nullptr, 0);
    pid_ = -1;
  }
}

std::uint16_t freePort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t length = sizeof addr;
  if (fd < 0 || ::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &length) != 0)
    throw std::runtime_error("cannot find a free loopback port");
  ::close(fd);
  return ntohs(addr.sin_port);
}

void waitUntilListening(Child& child, std::uint16_t port, const std::string& name) {
  const auto deadline = std::chrono::steady_clock::now() + kStartTimeout;
  while (!accepts(port)) {
    if (!child.running()) throw std::runtime_error(name + " exited at start: " + child.log());
    if (std::chrono::steady_clock::now() > deadline)
      throw std::runtime_error(
          name + fmt::format(" does not listen on port {} after {} s", port, kStartTimeout.count()));
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

ScratchFolder::ScratchFolder(fs::path at) : path(std::move(at)) {
  fs::remove_all(path);
  fs::create_directories(path / "root");
}

ScratchFolder::~ScratchFolder() {
  std::error_code ec;
  fs::remove_all(path, ec);
}

fs::path ScratchFolder::serve(const fs::path& store) const {
  const fs::path served = path / "root" / (store.stem().string() + ".svo");
  std::error_code ec;
  fs::create_hard_link(store, served, ec);  // a copy only across file systems
  if (ec) fs::copy_file(store, served);
  return served;
}

std::string urlSegment(const std::string& name) {
  std::string out;
  for (const unsigned char c : name)
    out += std::isalnum(c) || c == '-' || c == '_' || c == '.' || c == '~' ? std::string(1, char(c))
                                                                           : fmt::format("%{:02X}", c);
  return out;
}

bool onPath(const std::string& program) {
  if (program.find('/') != std::string::npos) return ::access(program.c_str(), X_OK) == 0;
  const char* path = std::getenv("PATH");
  std::stringstream dirs(path ? path : "");
  for (std::string dir; std::getline(dirs, dir, ':');)
    if (!dir.empty() && ::access((fs::path(dir) / program).c_str(), X_OK) == 0) return true;
  return false;
}

std::string closedToNginxWorkers(const fs::path& file) {
  if (::geteuid() != 0) return "";
  const fs::path path = fs::absolute(file);
  std::error_code ec;
  if ((fs::status(path, ec).permissions() & fs::perms::others_read) == fs::perms::none) return path.string();
  for (fs::path dir = path.parent_path();; dir = dir.parent_path()) {
    if ((fs::status(dir, ec).permissions() & fs::perms::others_exec) == fs::perms::none) return dir.string();
    if (dir == dir.parent_path()) return "";
  }
}

std::unique_ptr<Child> startNginx(const std::string& nginx, const fs::path& dir, const fs::path& root,
                                  std::uint16_t port, int workers) {
  const fs::path config = dir / "nginx.conf";
  std::ofstream(config) << nginxConfig(dir, root, port, workers);
  return std::make_unique<Child>(
      std::vector<std::string>{nginx, "-c", config.string(), "-p", dir.string() + "/", "-e",
                               (dir / "nginx-start.log").string()},
      dir / "nginx.log");
}

}  // namespace svo::tools::bench
