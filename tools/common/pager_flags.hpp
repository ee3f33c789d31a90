// The pager's threads and the octree's in-memory choices as command-line flags, for every command that
// streams or casts rays.
#pragma once

#include <string>

#include "svo/client/pager.hpp"
#include "svo/client/raycast.hpp"

namespace CLI {
class App;
}

namespace svo::tools {

// Adds --fetch-threads, --decode-threads, --worker-nice and --decoders-during-(moving-)frames to `cmd`, bound
// to `options` (whose values are the defaults shown). Fetch threads start at 0, resolved by
// resolvedFetchThreads once the store is known.
void addPagerThreadFlags(CLI::App& cmd, PagerOptions& options);
// `flag` when the command line set it, else fetchThreadsFor(locator): more for a URL than for a file.
int resolvedFetchThreads(int flag, const std::string& locator);
// Adds --attributes raw|compressed and --exact-normals DEGREES: how the octree's blocks (the pool's, or the
// one block of a store read whole) hold colors and normals.
void addAttributeLayoutFlag(CLI::App& cmd, AttributeOptions& attributes);
// Adds --pool blocks|levels: how the pager's pool holds the resident octree (PoolLayout).
void addPoolLayoutFlag(CLI::App& cmd, PoolLayout& layout);
// Adds --simd widest|avx512|avx2|none: the ray caster's packet loop (CastOptions::simd).
void addPacketSimdFlag(CLI::App& cmd, PacketSimd& simd);

}  // namespace svo::tools
