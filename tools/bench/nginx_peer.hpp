// The peers the benchmarks start on loopback beside svo serve: nginx (or any program) as a child process in a
// scratch folder, on a free port, waited for until it listens. `svo bench serve` measures svo serve against
// it; `svo bench quality --stream` streams a store from it by range requests.
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

namespace svo::tools::bench {

// A child process with stdout and stderr in `log`; stopped (SIGTERM, then SIGKILL) and reaped when it goes.
class Child {
 public:
  // Starts argv[0] (searched in PATH); throws std::runtime_error naming it when it cannot.
  Child(const std::vector<std::string>& argv, const std::filesystem::path& log);
  ~Child() { stop(); }
  Child(const Child&) = delete;
  Child& operator=(const Child&) = delete;
  pid_t pid() const { return pid_; }
  bool running();
  // What it wrote, for an error message.
  std::string log() const;
  void stop();

 private:
  pid_t pid_ = -1;
  std::filesystem::path log_;
};

// A loopback port free now (the kernel's pick for a socket bound to port 0).
std::uint16_t freePort();

// Waits (bounded) until `child` accepts connections on `port`; throws std::runtime_error naming it (`name`)
// with its log when it exits first, or when it does not listen in time.
void waitUntilListening(Child& child, std::uint16_t port, const std::string& name);

// A scratch folder with an empty root/ (the folder a peer serves), removed with the object.
struct ScratchFolder {
  std::filesystem::path path;
  explicit ScratchFolder(std::filesystem::path at);
  ~ScratchFolder();
  ScratchFolder(const ScratchFolder&) = delete;
  ScratchFolder& operator=(const ScratchFolder&) = delete;
  // `store` placed in root/ under its own name (hard-linked: a copy only across file systems); its path.
  std::filesystem::path serve(const std::filesystem::path& store) const;
};

// `name` as one URL path segment: unreserved bytes as they are, the others percent-encoded.
std::string urlSegment(const std::string& name);

// Whether `program` names an executable: a path, or a name found in PATH.
bool onPath(const std::string& program);

// Where nginx's workers cannot read `file`: started by root they run as an unprivileged user, who needs every
// folder above it open to others and the file readable by them. The first such path; empty when there is
// none, or when this process is not root.
std::string closedToNginxWorkers(const std::filesystem::path& file);

// nginx (the binary `nginx`) serving `root` on 127.0.0.1:`port` with `workers` worker processes, its config,
// pid file, logs and temp folders in `dir`; not yet listening when this returns (waitUntilListening).
std::unique_ptr<Child> startNginx(const std::string& nginx, const std::filesystem::path& dir,
                                  const std::filesystem::path& root, std::uint16_t port, int workers);

}  // namespace svo::tools::bench
