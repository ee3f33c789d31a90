#include "remote.hpp"

#include <cstdlib>

#include "svo/client/locator.hpp"
#include "svo/client/pager.hpp"

namespace svo::tools {

void addTokenOption(CLI::App* command, std::string& token) {
  command->add_option("--token", token,
                      "for a store URL: bearer token sent to the server (default: the SVO_TOKEN environment "
                      "variable)");
}

void addRangeOnlyFlag(CLI::App* command, bool& rangeOnly) {
  command->add_flag("--range-only", rangeOnly,
                    "for a store URL: range requests only, without svo serve's view stream (as from a static "
                    "server)");
}

RemoteOptions remoteOptions(const std::string& token, bool rangeOnly) {
  RemoteOptions options;
  options.token = token;
  options.viewStream = !rangeOnly;
  if (const char* env = std::getenv("SVO_TOKEN"); options.token.empty() && env) options.token = env;
  // curl's own variable for the certificates an https:// server is checked against.
  if (const char* ca = std::getenv("CURL_CA_BUNDLE"); ca && *ca) options.caFile = ca;
  return options;
}

int fetchThreadsFor(const std::string& locator) {
  return isUrl(locator) ? kRemoteFetchThreads : PagerOptions{}.fetchThreads;
}

CLI::Validator storeLocator() {
  return CLI::Validator(
      [](std::string& locator) { return isUrl(locator) ? std::string() : CLI::ExistingFile(locator); },
      "FILE or URL");
}

}  // namespace svo::tools
