// The pager's threads as command-line flags, for every command that streams.
#pragma once

#include "svo/client/pager.hpp"

namespace CLI {
class App;
}

namespace svo::tools {

// Adds --fetch-threads, --decode-threads, --worker-nice and --decoders-during-frames to `cmd`, bound to
// `options` (whose values are the defaults shown).
void addPagerThreadFlags(CLI::App& cmd, PagerOptions& options);

}  // namespace svo::tools
