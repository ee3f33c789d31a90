// What this machine has, for defaults sized from it: memory, and how much of it a command may take.
#pragma once

#include <cstdint>

namespace svo::tools {

struct MachineMemory {
  std::uint64_t physical = 0;   // MemTotal
  std::uint64_t available = 0;  // MemAvailable: what can be allocated without swapping or evicting others
};
// From /proc/meminfo. The environment variable SVO_MACHINE_MEMORY (e.g. "64M") stands in for both, so tests
// can run a command as if on a small machine; a value that does not parse is an error naming it.
MachineMemory machineMemory();

// The memory a command may take by default: this share of what is available, never above that share of
// the physical memory (other programs, the page cache and a second command keep the rest).
std::uint64_t defaultMemoryShare(const MachineMemory& memory);

// This process's resident set now (/proc/self/statm) and at its peak so far (getrusage).
std::uint64_t residentBytes();
std::uint64_t peakResidentBytes();

}  // namespace svo::tools
