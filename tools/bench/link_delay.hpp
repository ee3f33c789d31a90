// A TCP relay on loopback that holds every byte for a fixed one-way time in each direction, optionally at a
// bounded rate: a link of that round trip and bandwidth between a client and a server on this machine, for
// benchmarks where tc netem is not available (loopback only).
#pragma once

#include <memory>
#include <string>

namespace svo::tools::bench {

class LinkDelay {
 public:
  // Listens on 127.0.0.1 at a free port and relays each connection to `host`:`port`, delivering each
  // direction's bytes `oneWaySeconds` after they arrived, in order; a new connection's first bytes also wait
  // for the round trip its TCP handshake would take. With `bitsPerSecond` > 0, every connection shares one
  // link of that rate in each direction: bytes also wait for the link to carry the bytes before them (0:
  // unbounded). Throws std::runtime_error when it cannot listen or resolve `host`.
  LinkDelay(const std::string& host, int port, double oneWaySeconds, double bitsPerSecond = 0.0);
  ~LinkDelay();  // stops relaying: open connections are closed
  LinkDelay(const LinkDelay&) = delete;
  LinkDelay& operator=(const LinkDelay&) = delete;
  int port() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace svo::tools::bench
