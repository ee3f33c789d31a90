#include "pager_flags.hpp"

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include <map>
#include <string>

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

void addAttributeLayoutFlag(CLI::App& cmd, AttributeLayout& layout) {
  const std::map<std::string, AttributeLayout> names{
      {nameOf(AttributeLayout::Raw), AttributeLayout::Raw},
      {nameOf(AttributeLayout::Compressed), AttributeLayout::Compressed}};
  cmd.add_option(
         "--attributes", layout,
         "colors and normals in memory: raw (32-bit values, children inherit equal ones; sec. 5.4) or "
         "compressed (units of 16 child slots, about a byte per color and two per normal; sec. 5.5)")
      ->transform(CLI::CheckedTransformer(names, CLI::ignore_case))
      ->default_str(nameOf(layout));
}

int resolvedFetchThreads(int flag, const std::string& locator) {
  return flag > 0 ? flag : fetchThreadsFor(locator);
}

}  // namespace svo::tools
