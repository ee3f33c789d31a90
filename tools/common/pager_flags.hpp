// The pager's threads as command-line flags, for every command that streams.
#pragma once

#include <string>

#include "svo/client/pager.hpp"

namespace CLI {
class App;
}

namespace svo::tools {

// Adds --fetch-threads, --decode-threads, --worker-nice and --decoders-during-frames to `cmd`, bound to
// `options` (whose values are the defaults shown). Fetch threads start at 0, resolved by
// resolvedFetchThreads once the store is known.
void addPagerThreadFlags(CLI::App& cmd, PagerOptions& options);
// `flag` when the command line set it, else fetchThreadsFor(locator): more for a URL than for a file.
int resolvedFetchThreads(int flag, const std::string& locator);
// Adds --attributes raw|compressed: how the octree's blocks (the pool's, or the one block of a store read
// whole) hold colors and normals.
void addAttributeLayoutFlag(CLI::App& cmd, AttributeLayout& layout);

}  // namespace svo::tools
