// `svo bench serve`'s many-viewers part: N clients, each with its own view of the store (the whole scene
// framed from N directions around it), fetch the slices their view plans (planSlices: the scheduler within
// the budget) at once. From svo serve through its view stream (ViewStreamSource: the server pushes each
// client's plan); from nginx by range requests, a slice per request, as a static server is read. A client
// has converged when every planned slice arrived and passed the store's check. Reported: clients
// converged, the time until the last one did (and the median client's), aggregate MB/s, and the server's
// CPU time per MB sent (its process's user + system time, /proc).
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <string>
#include <vector>

#include "svo/store/store_reader.hpp"

namespace svo::tools::bench {

struct ManyViewers {
  int clients = 0, converged = 0;
  std::uint64_t bytes = 0;     // slice bytes received, all clients
  std::uint64_t pulled = 0;    // slices read by range request (the stream's fallback)
  double seconds = 0.0;        // until the last client converged
  double medianSeconds = 0.0;  // until the median client converged
  double serverCpuSeconds = 0.0;
};

// `pid` and its children (nginx's workers).
std::vector<pid_t> processAndChildren(pid_t pid);

// `clients` clients of the store at `url` (served by process `server`), each with a pool of
// `budgetBytes`: through the view stream when `viewStream`, else by range requests.
ManyViewers runManyViewers(const std::string& url, const StoreReader& reader, pid_t server, int clients,
                           std::uint64_t budgetBytes, bool viewStream);

// Of several runs, the one whose last viewer converged at the median time.
ManyViewers medianRun(std::vector<ManyViewers> runs);

}  // namespace svo::tools::bench
