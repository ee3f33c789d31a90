#include "nginx_fixture.hpp"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <vector>

extern char** environ;

namespace svotest {
namespace {

namespace fs = std::filesystem;

// Polls for nginx to accept connections every kPollMicros, at most kStartPolls times (5 s): it starts in
// milliseconds on an idle machine, and much later only when something is wrong.
constexpr int kPollMicros = 10'000;
constexpr int kStartPolls = 500;
// A graceful stop waits this many polls (5 s) for the process to exit before it is killed.
constexpr int kStopPolls = 500;
// Binding a fresh port can race with another program taking it between our probe and nginx's bind.
constexpr int kPortAttempts = 5;

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// A port on 127.0.0.1 that nothing listens on now (the kernel's choice for port 0).
int freeLoopbackPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) throw std::runtime_error(std::string("socket: ") + std::strerror(errno));
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = 0;
  socklen_t len = sizeof a;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
    ::close(fd);
    throw std::runtime_error(std::string("cannot find a free loopback port: ") + std::strerror(errno));
  }
  ::close(fd);
  return ntohs(a.sin_port);
}

bool accepts(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  a.sin_port = htons(std::uint16_t(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0;
  ::close(fd);
  return ok;
}

void replaceAll(std::string& text, const std::string& from, const std::string& to) {
  for (std::size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
    text.replace(at, from.size(), to);
}

}  // namespace

std::string nginxBinary() {
  if (const char* set = std::getenv("SVO_NGINX"); set && *set) return ::access(set, X_OK) == 0 ? set : "";
  std::vector<std::string> dirs;
  if (const char* path = std::getenv("PATH")) {
    std::stringstream s(path);
    for (std::string dir; std::getline(s, dir, ':');) dirs.push_back(dir);
  }
  dirs.insert(dirs.end(), {"/usr/sbin", "/usr/local/sbin"});  // root's folders, often not on a user's PATH
  for (const std::string& dir : dirs)
    if (const fs::path p = fs::path(dir) / "nginx"; !dir.empty() && ::access(p.c_str(), X_OK) == 0) return p;
  return "";
}

std::string NginxServer::defaultServerBlock() {
  return "server {\n  listen 127.0.0.1:{port};\n  root {root};\n}\n";
}

NginxServer::NginxServer(fs::path root, Options options)
    : root_(fs::absolute(root)), options_(std::move(options)) {
  if (options_.serverBlock.empty()) options_.serverBlock = defaultServerBlock();
  if (nginxBinary().empty()) throw std::runtime_error("nginx is not installed");
  std::string pattern = (fs::temp_directory_path() / "svo_nginx_XXXXXX").string();
  if (!::mkdtemp(pattern.data())) throw std::runtime_error("cannot make a temp folder for nginx");
  dir_ = pattern;
  for (int attempt = 1;; ++attempt) {
    port_ = freeLoopbackPort();
    try {
      writeConfig();
      launch();
      return;
    } catch (const std::exception&) {
      // Another program took the port between the probe and nginx's bind: try another one.
      const bool portTaken = errorLog().find("Address already in use") != std::string::npos;
      if (!portTaken || attempt == kPortAttempts) {
        fs::remove_all(dir_);
        throw;
      }
    }
  }
}

NginxServer::~NginxServer() {
  if (pid_ > 0) signalAndWait(SIGKILL);
  std::error_code ec;
  fs::remove_all(dir_, ec);
}

void NginxServer::writeConfig() const {
  const std::string d = dir_.string();
  std::string server = options_.serverBlock;
  replaceAll(server, "{port}", std::to_string(port_));
  replaceAll(server, "{root}", root_.string());
  std::ofstream conf(dir_ / "nginx.conf");
  // One process (no master, so no switch to another user that could not read the test's folders); every
  // path nginx would write under its install prefix is moved into the temp folder.
  conf << "daemon off;\nmaster_process off;\nworker_processes 1;\n"
       << "pid " << d << "/nginx.pid;\nerror_log " << d << "/error.log warn;\n"
       << "events { worker_connections 256; }\n"
       << "http {\n"
       << "  client_body_temp_path " << d << "/client_body;\n  proxy_temp_path " << d << "/proxy;\n"
       << "  fastcgi_temp_path " << d << "/fastcgi;\n  uwsgi_temp_path " << d << "/uwsgi;\n"
       << "  scgi_temp_path " << d << "/scgi;\n"
       << "  default_type application/octet-stream;\n"
       << "  log_format svo '$connection $connection_requests $status \"$request\" \"$http_range\" "
          "$body_bytes_sent';\n"
       << "  access_log " << d << "/access.log svo;\n"
       << server << "}\n";
  if (!conf) throw std::runtime_error("cannot write " + (dir_ / "nginx.conf").string());
}

void NginxServer::launch() {
  const std::string binary = nginxBinary(), prefix = dir_.string() + "/",
                    conf = (dir_ / "nginx.conf").string(), log = (dir_ / "error.log").string(),
                    out = (dir_ / "stdout.log").string();
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, out.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  std::vector<std::string> args{binary, "-p", prefix, "-c", conf, "-e", log};
  std::vector<char*> argv;
  for (std::string& a : args) argv.push_back(a.data());
  argv.push_back(nullptr);
  const int rc = ::posix_spawn(&pid_, binary.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    pid_ = -1;
    throw std::runtime_error("cannot start " + binary + ": " + std::strerror(rc));
  }
  for (int i = 0; i < kStartPolls; ++i) {
    int status = 0;
    if (::waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      throw std::runtime_error("nginx exited at start: " + errorLog() + slurp(out));
    }
    if (accepts(port_)) return;
    ::usleep(kPollMicros);
  }
  signalAndWait(SIGKILL);
  throw std::runtime_error("nginx did not accept connections on port " + std::to_string(port_) +
                           " within 5 s: " + errorLog());
}

void NginxServer::signalAndWait(int signal) {
  if (pid_ <= 0) return;
  ::kill(pid_, signal);
  for (int i = 0; signal != SIGKILL && i < kStopPolls; ++i) {
    if (::waitpid(pid_, nullptr, WNOHANG) == pid_) {
      pid_ = -1;
      return;
    }
    ::usleep(kPollMicros);
  }
  if (signal != SIGKILL) ::kill(pid_, SIGKILL);
  ::waitpid(pid_, nullptr, 0);
  pid_ = -1;
}

void NginxServer::stop() {
  signalAndWait(SIGQUIT);
}

void NginxServer::kill() {
  signalAndWait(SIGKILL);
}

void NginxServer::start() {
  if (pid_ > 0) throw std::logic_error("nginx is already running");
  launch();
}

std::string NginxServer::url(const std::string& path) const {
  return "http://127.0.0.1:" + std::to_string(port_) + "/" + path;
}

std::string NginxServer::accessLog() const {
  return slurp(dir_ / "access.log");
}

std::string NginxServer::errorLog() const {
  return slurp(dir_ / "error.log");
}

}  // namespace svotest
