#include "pager_flags.hpp"

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include "remote.hpp"

namespace svo::tools {

void addPagerThreadFlags(CLI::App& cmd, PagerOptions& options) {
  options.fetchThreads = 0;
  cmd.add_option(
         "--fetch-threads", options.fetchThreads,
         fmt::format("when streaming: threads that fetch slices from the store (default: {} for a file, {} "
                     "for a URL, whose round trips want more waiting at once)",
                     PagerOptions{}.fetchThreads, kRemoteFetchThreads))
      ->check(CLI::Range(1, 256));
  cmd.add_option("--decode-threads", options.decodeThreads,
                 "when streaming: threads that decode slices and lay out blocks")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  cmd.add_option("--worker-nice", options.workerNice,
                 "when streaming: nice value of those threads; higher gives frames more of the CPU, lower "
                 "streams faster while the camera moves")
      ->check(CLI::Range(0, 19))
      ->capture_default_str();
  cmd.add_option("--decoders-during-frames", options.decodersDuringFrames,
                 "when streaming: decode threads that go on while a frame renders (the others wait for it to "
                 "end)")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
}

int resolvedFetchThreads(int flag, const std::string& locator) {
  return flag > 0 ? flag : fetchThreadsFor(locator);
}

}  // namespace svo::tools
