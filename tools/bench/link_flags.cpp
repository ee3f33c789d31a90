#include "link_flags.hpp"

#include <cstdlib>
#include <map>

#include <fmt/format.h>

#include "number_checks.hpp"
#include "usage.hpp"

namespace svo::tools::bench {

std::pair<CLI::Option*, CLI::Option*> addLinkFlags(CLI::App& cmd, double& delayMs, double& bitsPerSecond,
                                                   const std::string& scope) {
  CLI::Option* delay =
      cmd.add_option("--link-delay", delayMs,
                     scope +
                         ": milliseconds a loopback relay adds to each direction (a link of twice that round "
                         "trip)")
          ->check(finiteRange(0.0, 10000.0));
  CLI::Option* rate =
      cmd.add_option("--link-rate", bitsPerSecond,
                     scope +
                         ": bits per second the relay's link carries in each direction, shared by every "
                         "connection (100M: a 100 Mbit/s link; default unbounded)")
          ->transform(CLI::AsNumberWithUnit(std::map<std::string, double>{{"k", 1e3}, {"M", 1e6}, {"G", 1e9}},
                                            CLI::AsNumberWithUnit::CASE_SENSITIVE))
          ->check(finiteNonNegative());
  return {delay, rate};
}

std::unique_ptr<LinkDelay> delayLink(std::string& url, double delayMs, double bitsPerSecond) {
  if (delayMs <= 0.0 && bitsPerSecond <= 0.0) return nullptr;
  const std::string scheme = "http://";
  if (url.rfind(scheme, 0) != 0) throw UsageError("--link-delay and --link-rate need an http:// store URL");
  const std::size_t slash = url.find('/', scheme.size());
  const std::string authority = url.substr(scheme.size(), slash - scheme.size());
  const std::size_t colon = authority.rfind(':');
  const bool hasPort = colon != std::string::npos && authority.find(']', colon) == std::string::npos;
  const std::string host = authority.substr(0, hasPort ? colon : authority.size());
  const int port = hasPort ? std::atoi(authority.c_str() + colon + 1) : 80;
  auto link = std::make_unique<LinkDelay>(host.starts_with('[') ? host.substr(1, host.size() - 2) : host,
                                          port, delayMs * 1e-3, bitsPerSecond);
  url = scheme + "127.0.0.1:" + std::to_string(link->port()) +
        (slash == std::string::npos ? "/" : url.substr(slash));
  return link;
}

std::string linkDescription(double delayMs, double bitsPerSecond) {
  return fmt::format("a relay adding {:g} ms each way{}", delayMs,
                     bitsPerSecond > 0.0 ? fmt::format(" at {:g} Mbit/s", bitsPerSecond * 1e-6) : "");
}

}  // namespace svo::tools::bench
