// A real nginx in the foreground on a free loopback port, serving a folder: the static HTTP server that the
// range-request tests read stores from, and the peer the server tests compare with. Its config, pid file,
// logs and every temp folder live in one temporary folder, removed with it; the process is stopped by the
// test (destructor, stop(), kill()).
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <string>

namespace svotest {

// The nginx binary: $SVO_NGINX if set, else `nginx` on PATH or in /usr/sbin; "" when there is none.
std::string nginxBinary();

class NginxServer {
 public:
  // `serverBlock`: the config's `server { ... }` text with `{port}` and `{root}` where the port and the
  // served folder go; empty for defaultServerBlock().
  struct Options {
    std::string serverBlock;
  };
  // A plain static server: `listen 127.0.0.1:{port}; root {root};` and nothing else.
  static std::string defaultServerBlock();

  // Starts nginx serving `root` on 127.0.0.1 at a free port and waits until it accepts connections. Throws
  // std::runtime_error with nginx's error log when it does not start (bounded wait).
  explicit NginxServer(std::filesystem::path root, Options options = {});
  ~NginxServer();
  NginxServer(const NginxServer&) = delete;
  NginxServer& operator=(const NginxServer&) = delete;

  // Stops it gracefully (SIGQUIT: open requests finish), or at once (SIGKILL: connections drop mid-answer, as
  // a crash or a pulled cable); both wait for the process to exit.
  void stop();
  void kill();
  // Starts it again on the same port (after stop() or kill()).
  void start();
  bool running() const { return pid_ > 0; }

  int port() const { return port_; }
  // http://127.0.0.1:PORT/PATH
  std::string url(const std::string& path) const;
  const std::filesystem::path& root() const { return root_; }
  // The access log so far: one line per request, "CONNECTION REQUESTS_ON_IT STATUS "REQUEST" "RANGE" BYTES".
  std::string accessLog() const;
  std::string errorLog() const;

 private:
  void writeConfig() const;
  void launch();
  void signalAndWait(int signal);

  std::filesystem::path root_, dir_;
  Options options_;
  int port_ = 0;
  pid_t pid_ = -1;
};

}  // namespace svotest
