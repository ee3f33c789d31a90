#include "svo/server/request.hpp"

#include <algorithm>
#include <limits>

namespace svo::server {
namespace {

constexpr std::uint64_t kSaturated = std::numeric_limits<std::uint64_t>::max();
// A slice id is a directory index: at most 10 decimal digits for a 32-bit count.
constexpr std::size_t kMaxSliceIdDigits = 10;

bool isSpace(char c) {
  return c == ' ' || c == '\t';
}

std::string_view trim(std::string_view s) {
  while (!s.empty() && isSpace(s.front())) s.remove_prefix(1);
  while (!s.empty() && isSpace(s.back())) s.remove_suffix(1);
  return s;
}

bool isDigit(char c) {
  return c >= '0' && c <= '9';
}

char lower(char c) {
  return c >= 'A' && c <= 'Z' ? char(c - 'A' + 'a') : c;
}

bool equalsIgnoringCase(std::string_view a, std::string_view b) {
  return a.size() == b.size() &&
         std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) { return lower(x) == lower(y); });
}

// Leading decimal digits of `s` (consumed), saturating at 2^64 - 1; nothing when there are none.
std::optional<std::uint64_t> takeNumber(std::string_view& s) {
  if (s.empty() || !isDigit(s.front())) return std::nullopt;
  std::uint64_t value = 0;
  while (!s.empty() && isDigit(s.front())) {
    const std::uint64_t digit = std::uint64_t(s.front() - '0');
    value = value > (kSaturated - digit) / 10 ? kSaturated : value * 10 + digit;
    s.remove_prefix(1);
  }
  return value;
}

int hexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

std::string join(const std::vector<std::string>& segments, std::size_t count) {
  std::string out;
  for (std::size_t i = 0; i < count; ++i) {
    if (i) out += '/';
    out += segments[i];
  }
  return out;
}

// The next entity tag of a list (RFC 9110 sec. 8.8.3): consumes it and returns its opaque tag (quotes
// included) and whether it is weak; nothing on a malformed list.
std::optional<std::string_view> takeEntityTag(std::string_view& s, bool& weak) {
  weak = s.size() >= 2 && s[0] == 'W' && s[1] == '/';
  if (weak) s.remove_prefix(2);
  if (s.empty() || s.front() != '"') return std::nullopt;
  const std::size_t close = s.find('"', 1);
  if (close == std::string_view::npos) return std::nullopt;
  const std::string_view tag = s.substr(0, close + 1);
  for (const char c : tag.substr(1, tag.size() - 2))
    if (static_cast<unsigned char>(c) < 0x21 || c == 0x7f) return std::nullopt;
  s.remove_prefix(close + 1);
  return tag;
}

}  // namespace

RangeRequest parseRange(std::string_view header, std::uint64_t size) {
  const RangeRequest whole;
  std::string_view s = trim(header);
  const std::size_t eq = s.find('=');
  if (eq == std::string_view::npos || !equalsIgnoringCase(trim(s.substr(0, eq)), "bytes")) return whole;
  s = trim(s.substr(eq + 1));
  if (s.find(',') != std::string_view::npos) return whole;  // several ranges: the whole body is allowed
  RangeRequest out{RangeKind::Partial, {}};
  if (!s.empty() && s.front() == '-') {  // the last n bytes
    s.remove_prefix(1);
    const std::optional<std::uint64_t> n = takeNumber(s);
    if (!n || !s.empty()) return whole;
    if (*n == 0 || size == 0) return {RangeKind::Unsatisfiable, {}};
    out.range = {size > *n ? size - *n : 0, size - 1};
    return out;
  }
  const std::optional<std::uint64_t> first = takeNumber(s);
  if (!first || s.empty() || s.front() != '-') return whole;
  s.remove_prefix(1);
  std::optional<std::uint64_t> last;
  if (!s.empty()) {
    last = takeNumber(s);
    if (!last || !s.empty()) return whole;
    if (*last < *first) return whole;  // an invalid range-spec: ignored, as a header that is not one
  }
  if (*first >= size) return {RangeKind::Unsatisfiable, {}};
  out.range = {*first, std::min(last.value_or(size - 1), size - 1)};
  return out;
}

TargetPath parseTargetPath(std::string_view target) {
  TargetPath out;
  if (target.empty() || target.front() != '/') {
    out.error = "the target must be a path starting with '/'";
    return out;
  }
  target = target.substr(0, target.find('?'));
  std::string decoded;
  decoded.reserve(target.size());
  for (std::size_t i = 0; i < target.size(); ++i) {
    char c = target[i];
    if (c == '%') {
      const int hi = i + 2 < target.size() ? hexValue(target[i + 1]) : -1;
      const int lo = i + 2 < target.size() ? hexValue(target[i + 2]) : -1;
      if (hi < 0 || lo < 0) {
        out.error = "bad percent escape in the path";
        return out;
      }
      c = char(hi * 16 + lo);
      i += 2;
    }
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) {
      out.error = "control character in the path";
      return out;
    }
    if (c == '\\') {
      out.error = "backslash in the path";
      return out;
    }
    decoded += c;
  }
  if (decoded == "/") return out;
  std::string_view rest = std::string_view(decoded).substr(1);
  while (true) {
    const std::size_t slash = rest.find('/');
    const std::string_view segment = rest.substr(0, slash);
    if (segment.empty()) {
      out.error = "empty segment in the path";
      break;
    }
    if (segment.front() == '.') {
      out.error = "a path segment starts with '.'";
      break;
    }
    out.segments.emplace_back(segment);
    if (slash == std::string_view::npos) break;
    rest.remove_prefix(slash + 1);
  }
  if (!out.error.empty()) out.segments.clear();
  return out;
}

Route parseRoute(const std::vector<std::string>& segments) {
  const std::size_t n = segments.size();
  if (n == 0) return {};
  const std::string& last = segments.back();
  if (n == 1 && last == "healthz") return {RouteKind::Health, {}, {}};
  if (n == 1 && last == "metrics") return {RouteKind::Metrics, {}, {}};
  if (n == 1 && last == "scenes") return {RouteKind::Scenes, {}, {}};
  constexpr std::string_view kExtension = ".svo";
  if (last.size() > kExtension.size() && last.ends_with(kExtension)) {
    std::string scene = join(segments, n - 1);
    if (n > 1) scene += '/';
    scene += last.substr(0, last.size() - kExtension.size());
    return {RouteKind::File, std::move(scene), {}};
  }
  if (n >= 2 && last == "info") return {RouteKind::Info, join(segments, n - 1), {}};
  if (n >= 2 && last == "directory") return {RouteKind::Directory, join(segments, n - 1), {}};
  if (n >= 2 && last == "stream") return {RouteKind::Stream, join(segments, n - 1), {}};
  if (n >= 3 && segments[n - 2] == "slices") return {RouteKind::Slice, join(segments, n - 2), last};
  return {RouteKind::File, join(segments, n), {}};
}

std::vector<Route> sceneRoutes(const std::vector<std::string>& segments) {
  std::vector<Route> out;
  const auto add = [&](const std::vector<std::string>& s) {
    const Route route = parseRoute(s);
    if (route.scene.empty()) return;  // not a scene's route
    out.push_back(route);
    if (route.kind != RouteKind::File) out.push_back({RouteKind::File, join(s, s.size()), {}});
  };
  add(segments);
  if (segments.size() > 1 && segments.front() == "scenes")
    add(std::vector<std::string>(segments.begin() + 1, segments.end()));
  return out;
}

bool isSafeSceneName(std::string_view name) {
  if (name.empty()) return false;
  bool segmentStart = true;
  for (const char c : name) {
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f || c == '\\') return false;
    if (segmentStart && (c == '/' || c == '.')) return false;
    segmentStart = c == '/';
  }
  return !segmentStart;
}

std::optional<std::uint32_t> parseSliceId(std::string_view text) {
  if (text.empty() || text.size() > kMaxSliceIdDigits) return std::nullopt;
  if (text.size() > 1 && text.front() == '0') return std::nullopt;  // one URL per slice
  std::string_view rest = text;
  const std::optional<std::uint64_t> value = takeNumber(rest);
  if (!value || !rest.empty() || *value > std::numeric_limits<std::uint32_t>::max()) return std::nullopt;
  return std::uint32_t(*value);
}

bool ifNoneMatchMatches(std::string_view header, std::string_view etag) {
  std::string_view s = trim(header);
  if (s == "*") return true;
  const std::string_view opaque = etag.starts_with("W/") ? etag.substr(2) : etag;
  while (true) {
    while (!s.empty() && (isSpace(s.front()) || s.front() == ',')) s.remove_prefix(1);
    if (s.empty()) return false;
    bool weak = false;
    const std::optional<std::string_view> tag = takeEntityTag(s, weak);
    if (!tag) return false;
    if (*tag == opaque) return true;
  }
}

bool ifRangeMatches(std::string_view header, std::string_view etag) {
  std::string_view s = trim(header);
  bool weak = false;
  const std::optional<std::string_view> tag = takeEntityTag(s, weak);
  return tag && !weak && s.empty() && !etag.starts_with("W/") && *tag == etag;
}

std::optional<std::string_view> bearerToken(std::string_view authorization) {
  std::string_view s = trim(authorization);
  const std::size_t space = s.find_first_of(" \t");
  if (space == std::string_view::npos || !equalsIgnoringCase(s.substr(0, space), "bearer"))
    return std::nullopt;
  const std::string_view token = trim(s.substr(space));
  if (token.empty()) return std::nullopt;
  return token;
}

bool constantTimeEquals(std::string_view a, std::string_view b) {
  std::size_t diff = a.size() ^ b.size();
  const std::size_t n = std::max(a.size(), b.size());
  for (std::size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff |= std::size_t(x ^ y);
  }
  return diff == 0;
}

}  // namespace svo::server
