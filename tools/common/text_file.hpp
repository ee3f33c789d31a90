// Text outputs (reports, CSV, scripts) written whole or not at all.
#pragma once

#include <filesystem>
#include <string_view>

namespace svo::tools {

// Writes `text` to `path` through a temporary name beside it, renamed when complete: a reader never sees a
// half-written file. Throws std::runtime_error naming the path when it cannot.
void writeTextFile(const std::filesystem::path& path, std::string_view text);

}  // namespace svo::tools
