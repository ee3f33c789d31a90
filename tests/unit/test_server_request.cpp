// The paging server's pure parsers (server/include/svo/server/request.hpp) against hand-worked answers from
// RFC 9110's examples and rules: ranges, conditional requests, paths, routes, tokens, slice ids.
#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "svo/server/request.hpp"

namespace {

using namespace svo::server;

struct RangeCase {
  const char* header;
  std::uint64_t size;
  RangeKind kind;
  std::uint64_t first, last;
};

TEST(ServerRequest, RangeFollowsRfc9110) {
  const RangeCase cases[] = {
      // RFC 9110 sec. 14.1.2's examples on a 10000-byte representation.
      {"bytes=0-499", 10000, RangeKind::Partial, 0, 499},
      {"bytes=500-999", 10000, RangeKind::Partial, 500, 999},
      {"bytes=-500", 10000, RangeKind::Partial, 9500, 9999},
      {"bytes=9500-", 10000, RangeKind::Partial, 9500, 9999},
      {"bytes=0-0", 10000, RangeKind::Partial, 0, 0},
      {"bytes=-1", 10000, RangeKind::Partial, 9999, 9999},
      // A last position past the end is the end; a suffix longer than the whole is the whole.
      {"bytes=9000-20000", 10000, RangeKind::Partial, 9000, 9999},
      {"bytes=-20000", 10000, RangeKind::Partial, 0, 9999},
      {"bytes=0-18446744073709551615", 10, RangeKind::Partial, 0, 9},
      {"bytes=0-99999999999999999999999", 10, RangeKind::Partial, 0, 9},
      // Unit and spaces are forgiven as RFC 9110 allows (case-insensitive unit, optional white space).
      {"  Bytes = 1-2 ", 10, RangeKind::Partial, 1, 2},
      // Unsatisfiable: starts at or past the end, an empty suffix, anything of an empty representation.
      {"bytes=10000-", 10000, RangeKind::Unsatisfiable, 0, 0},
      {"bytes=10000-10001", 10000, RangeKind::Unsatisfiable, 0, 0},
      {"bytes=-0", 10000, RangeKind::Unsatisfiable, 0, 0},
      {"bytes=0-", 0, RangeKind::Unsatisfiable, 0, 0},
      {"bytes=-5", 0, RangeKind::Unsatisfiable, 0, 0},
      {"bytes=99999999999999999999999-", 10, RangeKind::Unsatisfiable, 0, 0},
      // Ignored (the whole representation): absent, invalid, other units, several ranges.
      {"", 100, RangeKind::Whole, 0, 0},
      {"bytes=5-4", 100, RangeKind::Whole, 0, 0},
      {"bytes=abc", 100, RangeKind::Whole, 0, 0},
      {"bytes=-", 100, RangeKind::Whole, 0, 0},
      {"bytes=1-2x", 100, RangeKind::Whole, 0, 0},
      {"bytes=+1-2", 100, RangeKind::Whole, 0, 0},
      {"items=0-1", 100, RangeKind::Whole, 0, 0},
      {"bytes 0-1", 100, RangeKind::Whole, 0, 0},
      {"bytes=0-1,5-6", 100, RangeKind::Whole, 0, 0},
  };
  for (const RangeCase& c : cases) {
    const RangeRequest r = parseRange(c.header, c.size);
    EXPECT_EQ(r.kind, c.kind) << c.header << " of " << c.size;
    if (r.kind == RangeKind::Partial && c.kind == RangeKind::Partial) {
      EXPECT_EQ(r.range.first, c.first) << c.header;
      EXPECT_EQ(r.range.last, c.last) << c.header;
      EXPECT_EQ(r.range.length(), c.last - c.first + 1) << c.header;
    }
  }
}

TEST(ServerRequest, PathsDecodeAndRefuseTraversal) {
  EXPECT_EQ(parseTargetPath("/a/b.svo").segments, (std::vector<std::string>{"a", "b.svo"}));
  EXPECT_EQ(parseTargetPath("/a%20b/c?x=../..").segments, (std::vector<std::string>{"a b", "c"}));
  EXPECT_EQ(parseTargetPath("/x%2Fy").segments, (std::vector<std::string>{"x", "y"}));
  EXPECT_TRUE(parseTargetPath("/").segments.empty());
  EXPECT_TRUE(parseTargetPath("/").error.empty());
  for (const char* bad :
       {"", "a/b", "/../x", "/a/../b", "/%2e%2e/x", "/%2E%2E%2Fetc/passwd", "/a/%2e", "/.hidden",
        "//etc/passwd", "/a//b", "/a/", "/a%00.svo", "/a%5Cb", "/a\\b", "/a%1", "/a%zz", "/a%", "/a\x01"}) {
    const TargetPath p = parseTargetPath(bad);
    EXPECT_FALSE(p.error.empty()) << bad;
    EXPECT_TRUE(p.segments.empty()) << bad;
  }
  EXPECT_TRUE(isSafeSceneName("a/b c/d"));
  for (const char* bad : {"", "/a", "a/", "a//b", "../a", "a/..", ".a", "a\\b"})
    EXPECT_FALSE(isSafeSceneName(bad)) << bad;
  EXPECT_FALSE(isSafeSceneName(std::string("a\0b", 3)));
}

TEST(ServerRequest, RoutesNameScenesAndTheirParts) {
  using S = std::vector<std::string>;
  const auto expect = [](const S& segments, RouteKind kind, const std::string& scene, const std::string& id) {
    const Route r = parseRoute(segments);
    EXPECT_EQ(r.kind, kind) << ::testing::PrintToString(segments);
    EXPECT_EQ(r.scene, scene) << ::testing::PrintToString(segments);
    EXPECT_EQ(r.sliceId, id) << ::testing::PrintToString(segments);
  };
  expect({}, RouteKind::NotFound, "", "");
  expect({"healthz"}, RouteKind::Health, "", "");
  expect({"metrics"}, RouteKind::Metrics, "", "");
  expect({"scenes"}, RouteKind::Scenes, "", "");
  expect({"bunny.svo"}, RouteKind::File, "bunny", "");
  expect({"bunny"}, RouteKind::File, "bunny", "");
  expect({"a", "b.svo"}, RouteKind::File, "a/b", "");
  expect({"a", "b", "info"}, RouteKind::Info, "a/b", "");
  expect({"a", "directory"}, RouteKind::Directory, "a", "");
  expect({"a", "b", "slices", "17"}, RouteKind::Slice, "a/b", "17");
  expect({"info"}, RouteKind::File, "info", "");
  expect({"slices", "3"}, RouteKind::File, "slices/3", "");
  expect({"healthz.svo"}, RouteKind::File, "healthz", "");
  // /scenes/NAME/... reads as NAME too, after the literal readings.
  const std::vector<Route> routes = sceneRoutes({"scenes", "a", "info"});
  ASSERT_EQ(routes.size(), 4u);
  EXPECT_EQ(routes[0].kind, RouteKind::Info);
  EXPECT_EQ(routes[0].scene, "scenes/a");
  EXPECT_EQ(routes[1].kind, RouteKind::File);
  EXPECT_EQ(routes[1].scene, "scenes/a/info");
  EXPECT_EQ(routes[2].kind, RouteKind::Info);
  EXPECT_EQ(routes[2].scene, "a");
  EXPECT_EQ(routes[3].kind, RouteKind::File);
  EXPECT_EQ(routes[3].scene, "a/info");
  EXPECT_TRUE(sceneRoutes({"healthz"}).empty());
}

TEST(ServerRequest, SliceIdsAreCanonicalDecimals) {
  EXPECT_EQ(parseSliceId("0"), 0u);
  EXPECT_EQ(parseSliceId("42"), 42u);
  EXPECT_EQ(parseSliceId("4294967295"), 4294967295u);
  for (const char* bad : {"", "-1", "+1", "01", "4294967296", "99999999999", "1a", " 1", "0x10"})
    EXPECT_FALSE(parseSliceId(bad).has_value()) << bad;
}

TEST(ServerRequest, ConditionalsCompareEntityTags) {
  const std::string etag = "\"abc\"";
  EXPECT_TRUE(ifNoneMatchMatches("\"abc\"", etag));
  EXPECT_TRUE(ifNoneMatchMatches("W/\"abc\"", etag));  // weak comparison
  EXPECT_TRUE(ifNoneMatchMatches("\"x\", W/\"abc\"", etag));
  EXPECT_TRUE(ifNoneMatchMatches(" * ", etag));
  EXPECT_FALSE(ifNoneMatchMatches("\"abcd\"", etag));
  EXPECT_FALSE(ifNoneMatchMatches("abc", etag));
  EXPECT_FALSE(ifNoneMatchMatches("\"abc", etag));
  EXPECT_TRUE(ifRangeMatches("\"abc\"", etag));
  EXPECT_FALSE(ifRangeMatches("W/\"abc\"", etag));  // strong comparison
  EXPECT_FALSE(ifRangeMatches("Wed, 21 Oct 2015 07:28:00 GMT", etag));
  EXPECT_FALSE(ifRangeMatches("\"abc\", \"abc\"", etag));
}

TEST(ServerRequest, BearerTokensCompareWhole) {
  EXPECT_EQ(bearerToken("Bearer abc.DEF-1"), "abc.DEF-1");
  EXPECT_EQ(bearerToken("bearer   tok  "), "tok");
  EXPECT_FALSE(bearerToken("Basic dXNlcjpwYXNz").has_value());
  EXPECT_FALSE(bearerToken("Bearer").has_value());
  EXPECT_FALSE(bearerToken("Bearer   ").has_value());
  EXPECT_FALSE(bearerToken("").has_value());
  EXPECT_TRUE(constantTimeEquals("secret", "secret"));
  EXPECT_TRUE(constantTimeEquals("", ""));
  EXPECT_FALSE(constantTimeEquals("secret", "secreT"));
  EXPECT_FALSE(constantTimeEquals("secret", "secret2"));
  EXPECT_FALSE(constantTimeEquals("", "x"));
  EXPECT_FALSE(constantTimeEquals(std::string("a\0", 2), "a"));
}

}  // namespace
