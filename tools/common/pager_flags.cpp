#include "pager_flags.hpp"

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include <string>
#include <utility>
#include <vector>

#include "number_checks.hpp"
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
                 "when streaming: decode threads that go on while a frame of a still view renders (the "
                 "others wait for it to end)")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
  cmd.add_option("--decoders-during-moving-frames", options.decodersDuringMovingFrames,
                 "when streaming: the same while the camera moves (the view differs from the frame before)")
      ->check(CLI::Range(0, 64))
      ->capture_default_str();
}

namespace {

// An enum option given by name. Bound to the enum itself, CLI11 would print an 8-bit enum's values as
// characters in the help and in its error message.
template <class Enum>
void addNamedOption(CLI::App& cmd, const std::string& flag, Enum& value,
                    const std::vector<std::pair<std::string, Enum>>& names, const std::string& description) {
  std::vector<std::string> keys;
  std::string current;
  for (const auto& [name, v] : names) {
    keys.push_back(name);
    if (v == value) current = name;
  }
  cmd.add_option_function<std::string>(
         flag,
         [&value, names](const std::string& given) {
           for (const auto& [name, v] : names)
             if (CLI::detail::to_lower(name) == CLI::detail::to_lower(given)) value = v;
         },
         description)
      ->check(CLI::IsMember(keys, CLI::ignore_case))
      ->default_str(current);
}

}  // namespace

void addAttributeLayoutFlag(CLI::App& cmd, AttributeOptions& attributes) {
  addNamedOption(
      cmd, "--attributes", attributes.layout,
      {{nameOf(AttributeLayout::Raw), AttributeLayout::Raw},
       {nameOf(AttributeLayout::Compressed), AttributeLayout::Compressed}},
      "colors and normals in memory: raw (32-bit values, children inherit equal ones; sec. 5.4) or "
      "compressed (units of 16 child slots, about a byte per color and two per normal; sec. 5.5)");
  cmd.add_option("--exact-normals", attributes.exactNormalUnitDegrees,
                 "with --attributes compressed: a unit of normals that no grid fits within this many degrees "
                 "(root mean square) keeps its normals' 32-bit values instead (0 = none: every unit a grid)")
      ->check(finiteRange(0.0, kMaxExactNormalUnitDegrees))
      ->capture_default_str();
}

void addPoolLayoutFlag(CLI::App& cmd, PoolLayout& layout) {
  addNamedOption(
      cmd, "--pool", layout,
      {{nameOf(PoolLayout::Blocks), PoolLayout::Blocks}, {nameOf(PoolLayout::Levels), PoolLayout::Levels}},
      "how the pool holds the resident octree: blocks (laid out again by every load; packets, beams, "
      "GPU) or levels (arrays per level that a load appends to; raw attributes, beams, one ray at a time)");
}

void addPacketSimdFlag(CLI::App& cmd, PacketSimd& simd) {
  addNamedOption(
      cmd, "--simd", simd,
      {{nameOf(PacketSimd::Widest), PacketSimd::Widest},
       {nameOf(PacketSimd::Avx512), PacketSimd::Avx512},
       {nameOf(PacketSimd::Avx2), PacketSimd::Avx2},
       {nameOf(PacketSimd::None), PacketSimd::None}},
      "the CPU ray caster's packet loop: widest (what this CPU has), avx512 (16 rays), avx2 (8 rays), "
      "none (one ray at a time); a loop the CPU lacks falls back to the next narrower one");
}

int resolvedFetchThreads(int flag, const std::string& locator) {
  return flag > 0 ? flag : fetchThreadsFor(locator);
}

}  // namespace svo::tools
