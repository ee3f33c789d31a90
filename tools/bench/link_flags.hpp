// --link-delay and --link-rate, for the benchmarks that read a store over HTTP: the flags, and the relay
// (link_delay.hpp) they put in front of an http:// URL.
#pragma once

#include <memory>
#include <string>
#include <utility>

#include <CLI/CLI.hpp>

#include "link_delay.hpp"

namespace svo::tools::bench {

// Adds --link-delay (milliseconds each way) and --link-rate (bits per second, 100M style) to `cmd`, their
// help starting with `scope` ("for an http:// URL"); returns the two options.
std::pair<CLI::Option*, CLI::Option*> addLinkFlags(CLI::App& cmd, double& delayMs, double& bitsPerSecond,
                                                   const std::string& scope);

// With a delay or a rate: a relay in front of the server `url` names, and `url` rewritten to go through it;
// else nullptr and `url` as it is. Throws UsageError when `url` is not http://.
std::unique_ptr<LinkDelay> delayLink(std::string& url, double delayMs, double bitsPerSecond);

// "a relay adding 10 ms each way at 100 Mbit/s", for titles.
std::string linkDescription(double delayMs, double bitsPerSecond);

}  // namespace svo::tools::bench
