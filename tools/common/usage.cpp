#include "usage.hpp"

#include <unistd.h>

namespace svo::tools {

void checkWritableOutput(const std::filesystem::path& out) {
  const std::filesystem::path dir = out.has_parent_path() ? out.parent_path() : ".";
  if (!std::filesystem::is_directory(dir))
    throw UsageError(out.string() + ": folder " + dir.string() + " does not exist");
  if (::access(dir.c_str(), W_OK) != 0)
    throw UsageError(out.string() + ": folder " + dir.string() + " is not writable");
  if (std::filesystem::is_directory(out)) throw UsageError(out.string() + ": is a folder");
}

}  // namespace svo::tools
