#include "machine.hpp"

#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <fstream>
#include <stdexcept>
#include <string>

#include <CLI/CLI.hpp>

namespace svo::tools {
namespace {

// Share of the machine's memory a command takes when the user sets no bound: half leaves room for the page
// cache, the desktop and one more command of the same size.
constexpr double kDefaultMemoryShare = 0.5;

// A /proc/meminfo field in bytes, or 0 when absent.
std::uint64_t meminfoBytes(const std::string& field) {
  std::ifstream in("/proc/meminfo");
  std::string name;
  std::uint64_t kib = 0;
  std::string unit;
  while (in >> name >> kib >> unit)
    if (name == field + ":") return kib * 1024;
  return 0;
}

}  // namespace

MachineMemory machineMemory() {
  if (const char* forced = std::getenv("SVO_MACHINE_MEMORY")) {
    std::uint64_t bytes = 0;
    // CLI11's size parser: the same "64M" / "1G" forms as --budget and --memory.
    std::string text = forced;
    bool parsed = false;
    try {
      parsed = CLI::AsSizeValue(false)(text).empty() && CLI::detail::lexical_cast(text, bytes) && bytes > 0;
    } catch (const CLI::Error&) {
    }
    if (!parsed) throw std::runtime_error(std::string("SVO_MACHINE_MEMORY: not a size (") + forced + ")");
    return {bytes, bytes};
  }
  MachineMemory m;
  m.physical = meminfoBytes("MemTotal");
  if (m.physical == 0)
    m.physical = std::uint64_t(::sysconf(_SC_PHYS_PAGES)) * std::uint64_t(::sysconf(_SC_PAGESIZE));
  m.available = meminfoBytes("MemAvailable");
  if (m.available == 0) m.available = m.physical;
  return m;
}

std::uint64_t defaultMemoryShare(const MachineMemory& memory) {
  return std::uint64_t(kDefaultMemoryShare * double(std::min(memory.physical, memory.available)));
}

std::uint64_t residentBytes() {
  std::ifstream in("/proc/self/statm");
  std::uint64_t sizePages = 0, residentPages = 0;
  in >> sizePages >> residentPages;
  return residentPages * std::uint64_t(::sysconf(_SC_PAGESIZE));
}

std::uint64_t peakResidentBytes() {
  rusage usage{};
  ::getrusage(RUSAGE_SELF, &usage);
  return std::uint64_t(usage.ru_maxrss) * 1024;  // KiB on Linux
}

}  // namespace svo::tools
