// libFuzzer target over the paging server's own parsers (server/include/svo/server/request.hpp): the
// target's path and route, Range, If-None-Match, If-Range, the bearer token and slice ids. Any bytes must
// give an answer that keeps the parsers' promises, never a crash, a hang or a sanitizer report. The input
// is split at its first two NUL bytes into a target, a header value and a size (decimal) for ranges.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include "svo/server/request.hpp"

namespace {

using namespace svo::server;

void check(bool promise) {
  if (!promise) std::abort();
}

void fuzzPath(std::string_view target) {
  const TargetPath path = parseTargetPath(target);
  check(path.error.empty() || path.segments.empty());
  for (const std::string& s : path.segments)
    check(!s.empty() && s.front() != '.' && s.find('/') == std::string::npos &&
          s.find('\\') == std::string::npos && s.find('\0') == std::string::npos);
  const Route route = parseRoute(path.segments);
  if (!route.scene.empty()) check(isSafeSceneName(route.scene));
  for (const Route& r : sceneRoutes(path.segments)) {
    check(isSafeSceneName(r.scene));
    if (r.kind == RouteKind::Slice) (void)parseSliceId(r.sliceId);
  }
}

void fuzzRange(std::string_view header, std::uint64_t size) {
  const RangeRequest r = parseRange(header, size);
  if (r.kind == RangeKind::Partial) check(r.range.first <= r.range.last && r.range.last < size);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view input(reinterpret_cast<const char*>(data), size);
  const std::size_t a = input.find('\0');
  const std::string_view target = input.substr(0, a);
  const std::string_view rest = a == std::string_view::npos ? std::string_view() : input.substr(a + 1);
  const std::size_t b = rest.find('\0');
  const std::string_view header = rest.substr(0, b);
  const std::string sizeText(b == std::string_view::npos ? std::string_view() : rest.substr(b + 1, 20));
  const std::uint64_t representation = std::strtoull(sizeText.c_str(), nullptr, 10);

  fuzzPath(target);
  fuzzRange(header, representation);
  fuzzRange(target, representation);
  const std::string etag = "\"" + std::string(target.substr(0, 16)) + "\"";
  (void)ifNoneMatchMatches(header, etag);
  (void)ifRangeMatches(header, etag);
  if (const auto token = bearerToken(header)) check(!token->empty() && constantTimeEquals(*token, *token));
  check(constantTimeEquals(target, header) == (target == header));
  if (const auto id = parseSliceId(target)) check(std::to_string(*id) == target);
  return 0;
}
