// Stores named by URL on the command line: --token (or SVO_TOKEN) and a check that lets URLs through where a
// command checks that its store file exists.
#pragma once

#include <string>

#include <CLI/CLI.hpp>

#include "svo/client/http_source.hpp"

namespace svo::tools {

// Adds --token to a command that takes a store URL.
void addTokenOption(CLI::App* command, std::string& token);
// Adds --range-only to a command that streams a store URL through the pager.
void addRangeOnlyFlag(CLI::App* command, bool& rangeOnly);
// The remote options of a command: its --token, else the SVO_TOKEN environment variable (which keeps the
// token out of the process list and the shell history); with `rangeOnly`, no view stream. CURL_CA_BUNDLE, as
// for curl, names the certificates an https:// server is checked against when not the system's.
RemoteOptions remoteOptions(const std::string& token, bool rangeOnly = false);
// A store argument: an existing file, or a URL (checked when the store is opened).
CLI::Validator storeLocator();

// Fetch threads for a store read over HTTP: each waits a round trip per request, so a link needs more of them
// waiting at once than a local disk does (PagerOptions::fetchThreads); `svo bench stream URL --link-delay 10
// --fetch-threads N` finds 2 leave a 20 ms link idle and 4 to 16 converge alike.
inline constexpr int kRemoteFetchThreads = 8;
// The pager's fetch threads for the store at `locator`: PagerOptions' default for a file, kRemoteFetchThreads
// for a URL.
int fetchThreadsFor(const std::string& locator);

}  // namespace svo::tools
