// What the paging server reads from a request besides what Beast parses: the target's path and route, the
// Range, If-None-Match and If-Range headers, the bearer token. Pure functions over strings, no I/O and no
// Beast, so the fuzz target (tests/fuzz/fuzz_request.cpp) runs them on any bytes.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace svo::server {

// Bytes first..last of a representation, both included (RFC 9110 sec. 14.1.2).
struct ByteRange {
  std::uint64_t first = 0, last = 0;
  std::uint64_t length() const { return last - first + 1; }
};

enum class RangeKind {
  Whole,          // send the whole representation (200)
  Partial,        // send `range` (206)
  Unsatisfiable,  // no byte of it exists (416)
};
struct RangeRequest {
  RangeKind kind = RangeKind::Whole;
  ByteRange range;
};
// The Range field's value `header` (empty when absent) against a representation of `size` bytes. One byte
// range (a-b, a-, -n) is Partial or Unsatisfiable; anything else (another unit, several ranges, bad syntax)
// is Whole, which RFC 9110 allows: a server may ignore Range and send the whole representation.
RangeRequest parseRange(std::string_view header, std::uint64_t size);

// A request target's path as segments under the served folder, or why it names nothing there.
struct TargetPath {
  std::vector<std::string> segments;  // percent-decoded
  std::string error;                  // non-empty: the target is refused (400), one line
};
// Splits `target` (origin form: "/a/b?query"; the query is ignored) into percent-decoded segments. Refuses
// targets that do not start with '/', bad escapes, control bytes (NUL included), backslashes, empty
// segments (so no absolute path after the first '/'), and segments that start with '.' ("..", ".", hidden
// files). A slash decoded from %2F splits segments like a raw one, so "%2E%2E%2F" is a ".." segment.
TargetPath parseTargetPath(std::string_view target);

enum class RouteKind { NotFound, Health, Metrics, Scenes, File, Info, Directory, Slice, Stream };
struct Route {
  RouteKind kind = RouteKind::NotFound;
  std::string scene;    // File, Info, Directory, Slice: the scene's name (relative path without .svo)
  std::string sliceId;  // Slice: the id as written (parseSliceId checks it)
};
// The route of a path's segments. /NAME.svo and /NAME are the whole file; /NAME/info, /NAME/directory and
// /NAME/slices/ID the scene's parts, /NAME/stream its view stream (NAME may hold slashes: a store in a
// sub-folder). healthz, metrics and scenes at the top are the service's own.
Route parseRoute(const std::vector<std::string>& segments);
// The readings of a scene route's segments, in the order the server tries them against its stores:
// parseRoute's; the whole file (/a/b/info when there is no scene a/b but a/b/info.svo); and both again
// without a leading "scenes" segment (/scenes/NAME/..., as a viewer may name a scene's URL).
std::vector<Route> sceneRoutes(const std::vector<std::string>& segments);

// Whether `name` is a scene name parseTargetPath could give: '/'-separated segments, none empty, none
// starting with '.', no backslash or control byte. The catalog checks names again before touching files.
bool isSafeSceneName(std::string_view name);

// A slice id: decimal digits only, below 2^32, no leading zero (one URL per slice).
std::optional<std::uint32_t> parseSliceId(std::string_view text);

// Whether If-None-Match `header` ("*" or a list of entity tags) matches `etag` by the weak comparison
// (RFC 9110 sec. 13.1.2: W/"x" matches "x").
bool ifNoneMatchMatches(std::string_view header, std::string_view etag);
// Whether If-Range `header` lets a Range apply: an entity tag strongly equal to `etag`. A date (or a weak
// tag) never does, so the whole representation is sent, which is always correct.
bool ifRangeMatches(std::string_view header, std::string_view etag);

// The token of an Authorization field "Bearer TOKEN" (scheme in any case), or nothing.
std::optional<std::string_view> bearerToken(std::string_view authorization);
// Compares in time that depends on the lengths only, never on where the strings differ.
bool constantTimeEquals(std::string_view a, std::string_view b);

}  // namespace svo::server
