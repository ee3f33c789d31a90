// What the paging server's tests serve: a folder of small stores built once per test run (a colored sphere
// in 4 KB slices, a box in a sub-folder, a copy guarded by a token file, a copy with one corrupt slice, a
// symlink and a linked folder leading out of the folder, a hidden folder), and servers started on it on a
// free loopback port, their log lines kept for the test to read.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "svo/server/server.hpp"

namespace svotest {

struct ServedStores {
  ServedStores();
  ~ServedStores();
  std::filesystem::path root;      // served
  std::filesystem::path outside;   // beside it, reachable only through symlinks
  std::uint32_t corruptSlice = 0;  // corrupt.svo's slice whose bytes were changed
};
const ServedStores& servedStores();

std::string slurp(const std::filesystem::path& path);

struct LogLines {
  std::mutex mutex;
  std::vector<std::string> lines;
  bool contains(const std::string& text);
  std::vector<std::string> copy();
};

struct RunningServer {
  std::unique_ptr<svo::server::Server> server;
  std::shared_ptr<LogLines> log = std::make_shared<LogLines>();
  std::uint16_t port = 0;
};
// A started server with `options`: over servedStores() unless a root is given, 4 threads unless given, its
// log kept.
RunningServer startServer(svo::server::ServerOptions options = {});
// One started server shared by the tests that need no options of their own.
RunningServer& sharedServer();

}  // namespace svotest
