// The paging server (server/) started in-process on a loopback port and spoken to over HTTP. References are
// independent of the server: the store files' own bytes (whole, ranges, the directory where the header's
// bytes say, slices where the directory's entries say, checked with XXH3 here), StoreReader's index for the
// metadata, and RFC 9110's rules for statuses and headers. Loops are bounded by count; nothing is timed.
#include <gtest/gtest.h>

#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <random>
#include <sstream>
#include <thread>

#include <xxhash.h>
#include <nlohmann/json.hpp>

#include "reference.hpp"
#include "server_client.hpp"
#include "server_fixture.hpp"
#include "svo/server/server.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;

namespace {

using svotest::httpGet;
using svotest::HttpReply;
using svotest::RunningServer;
using svotest::ServedStores;
using svotest::servedStores;
using svotest::slurp;

RunningServer start(svo::server::ServerOptions options = {}) {
  return svotest::startServer(std::move(options));
}
RunningServer& shared() {
  return svotest::sharedServer();
}

std::uint64_t u64At(const std::string& bytes, std::size_t offset) {
  std::uint64_t v = 0;
  std::memcpy(&v, bytes.data() + offset, sizeof v);
  return v;
}

TEST(Server, HealthScenesAndUnknownRoutes) {
  const std::uint16_t port = shared().port;
  const HttpReply health = httpGet(port, "/healthz");
  EXPECT_EQ(health.status, 200u);
  EXPECT_EQ(health.body, "ok\n");
  const HttpReply scenes = httpGet(port, "/scenes");
  ASSERT_EQ(scenes.status, 200u);
  EXPECT_EQ(scenes.header("content-type"), "application/json");
  const nlohmann::json list = nlohmann::json::parse(scenes.body);
  std::vector<std::string> names;
  for (const auto& s : list) names.push_back(s.at("name"));
  // Not the symlink leaving the root, not the hidden folder, not the linked folder (never followed).
  EXPECT_EQ(names, (std::vector<std::string>{"corrupt", "secret", "sphere", "sub/box"}));
  for (const auto& s : list) {
    const svo::StoreReader reader(servedStores().root / (s.at("name").get<std::string>() + ".svo"));
    EXPECT_EQ(s.at("fileBytes"), reader.header().fileBytes);
    EXPECT_EQ(s.at("levels"), reader.header().parameters.levels);
    EXPECT_EQ(s.at("slices"), reader.slices().size());
    EXPECT_EQ(s.at("protected"), s.at("name") == "secret");
  }
  EXPECT_EQ(httpGet(port, "/").status, 404u);
  EXPECT_EQ(httpGet(port, "/nosuchscene").status, 404u);
  EXPECT_EQ(httpGet(port, "/nosuchscene/slices/0").status, 404u);
  svotest::HttpClient client(port);
  const HttpReply post = client.request("POST", "/sphere.svo");
  EXPECT_EQ(post.status, 405u);
  EXPECT_EQ(post.header("allow"), "GET, HEAD");
  EXPECT_EQ(client.get("/healthz").status, 200u);  // the connection stays usable
}

TEST(Server, WholeFileIsTheFileWithRangesAndHead) {
  const std::uint16_t port = shared().port;
  const std::string file = slurp(servedStores().root / "sphere.svo");
  const std::size_t size = file.size();
  svotest::HttpClient client(port);
  for (const char* target : {"/sphere.svo", "/sphere", "/scenes/sphere"}) {
    const HttpReply whole = client.get(target);
    ASSERT_EQ(whole.status, 200u) << target;
    EXPECT_EQ(whole.body, file) << target;
    EXPECT_EQ(whole.header("accept-ranges"), "bytes");
    EXPECT_EQ(whole.header("content-type"), "application/octet-stream");
    EXPECT_TRUE(whole.keepAlive);
  }
  const HttpReply head = client.request("HEAD", "/sphere.svo");
  EXPECT_EQ(head.status, 200u);
  EXPECT_EQ(head.header("content-length"), std::to_string(size));
  EXPECT_TRUE(head.body.empty());
  struct Case {
    std::string range;
    std::size_t first, last;
  };
  const Case cases[] = {
      {"bytes=0-255", 0, 255},
      {"bytes=100-", 100, size - 1},
      {"bytes=-1000", size - 1000, size - 1},
      {"bytes=-" + std::to_string(size * 2), 0, size - 1},
      {"bytes=" + std::to_string(size - 10) + "-" + std::to_string(size + 50), size - 10, size - 1}};
  for (const Case& c : cases) {
    const HttpReply part = client.get("/sphere.svo", {{"Range", c.range}});
    ASSERT_EQ(part.status, 206u) << c.range;
    EXPECT_EQ(part.body, file.substr(c.first, c.last - c.first + 1)) << c.range;
    EXPECT_EQ(part.header("content-range"),
              "bytes " + std::to_string(c.first) + "-" + std::to_string(c.last) + "/" + std::to_string(size));
  }
  const HttpReply beyond = client.get("/sphere.svo", {{"Range", "bytes=" + std::to_string(size) + "-"}});
  EXPECT_EQ(beyond.status, 416u);
  EXPECT_EQ(beyond.header("content-range"), "bytes */" + std::to_string(size));
  for (const char* ignored : {"bytes=0-1,5-9", "bytes=9-5", "lines=1-2"}) {
    const HttpReply whole = client.get("/sphere.svo", {{"Range", ignored}});
    EXPECT_EQ(whole.status, 200u) << ignored;
    EXPECT_EQ(whole.body, file) << ignored;
  }
}

TEST(Server, EntityTagsAreStableAndRevalidate) {
  const std::uint16_t port = shared().port;
  const std::string file = slurp(servedStores().root / "sphere.svo");
  const std::string etag = httpGet(port, "/sphere.svo").header("etag");
  // Strong, and named by the file's size and the header's checksum (the header's last 8 bytes).
  char expected[64];
  std::snprintf(expected, sizeof expected, "\"%zx-%016llx\"", file.size(),
                static_cast<unsigned long long>(u64At(file, 248)));
  EXPECT_EQ(etag, expected);
  EXPECT_EQ(httpGet(port, "/sphere").header("etag"), etag);
  const HttpReply notModified = httpGet(port, "/sphere.svo", {{"If-None-Match", etag}});
  EXPECT_EQ(notModified.status, 304u);
  EXPECT_TRUE(notModified.body.empty());
  EXPECT_EQ(notModified.header("etag"), etag);
  EXPECT_EQ(httpGet(port, "/sphere.svo", {{"If-None-Match", "W/" + etag}}).status, 304u);
  EXPECT_EQ(httpGet(port, "/sphere.svo", {{"If-None-Match", "\"other\", " + etag}}).status, 304u);
  EXPECT_EQ(httpGet(port, "/sphere.svo", {{"If-None-Match", "\"other\""}}).status, 200u);
  // If-Range: the range only for the same version, else the whole file.
  EXPECT_EQ(httpGet(port, "/sphere.svo", {{"Range", "bytes=0-9"}, {"If-Range", etag}}).status, 206u);
  const HttpReply stale = httpGet(port, "/sphere.svo", {{"Range", "bytes=0-9"}, {"If-Range", "\"old\""}});
  EXPECT_EQ(stale.status, 200u);
  EXPECT_EQ(stale.body.size(), file.size());
  // Another store has another tag.
  EXPECT_NE(httpGet(port, "/sub/box.svo").header("etag"), etag);
}

TEST(Server, InfoAgreesWithTheStoreIndex) {
  const svo::StoreReader reader(servedStores().root / "sphere.svo");
  const svo::StoreHeader& h = reader.header();
  const HttpReply reply = httpGet(shared().port, "/sphere/info");
  ASSERT_EQ(reply.status, 200u);
  const nlohmann::json info = nlohmann::json::parse(reply.body);
  EXPECT_EQ(info.at("name"), "sphere");
  EXPECT_EQ(info.at("fileBytes"), h.fileBytes);
  EXPECT_EQ(info.at("levels"), h.parameters.levels);
  EXPECT_EQ(info.at("sliceBytes"), h.sliceBytes);
  EXPECT_EQ(info.at("sliceCount"), reader.slices().size());
  EXPECT_EQ(info.at("directory").at("offset"), h.directoryOffset);
  EXPECT_EQ(info.at("directory").at("bytes"), h.directoryBytes);
  EXPECT_EQ(info.at("transform").at("size"), h.transform.size);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(info.at("transform").at("origin")[i], h.transform.origin[i]);
    EXPECT_EQ(info.at("bounds").at("min")[i], h.transform.origin[i]);
    EXPECT_EQ(info.at("bounds").at("max")[i], h.transform.origin[i] + h.transform.size);
  }
  nlohmann::json attachments = nlohmann::json::array();
  if (h.hasColors) attachments.push_back("color");
  if (h.hasNormals) attachments.push_back("normal");
  EXPECT_TRUE(h.hasColors);
  EXPECT_EQ(info.at("attachments"), attachments);
  EXPECT_EQ(info.at("rootColor"), h.rootColor);
  std::vector<std::size_t> perLevel(std::size_t(h.parameters.levels), 0);
  std::uint64_t compressed = 0;
  for (const svo::SliceInfo& s : reader.slices())
    ++perLevel[std::size_t(s.voxelLevel - 1)], compressed += s.compressedBytes;
  EXPECT_EQ(info.at("slicesPerLevel").get<std::vector<std::size_t>>(), perLevel);
  EXPECT_EQ(info.at("compressedSliceBytes"), compressed);
  EXPECT_EQ(info.at("rootSlices"), nlohmann::json::array({0}));
  EXPECT_EQ(httpGet(shared().port, "/sub/box/info").status, 200u);
}

TEST(Server, DirectoryAndSlicesAreTheStoredBytes) {
  const std::string file = slurp(servedStores().root / "sphere.svo");
  svotest::HttpClient client(shared().port);
  // The directory where the header's own bytes say (docs/format.md: offset at byte 88, size at 96).
  const HttpReply directory = client.get("/sphere/directory");
  ASSERT_EQ(directory.status, 200u);
  EXPECT_EQ(directory.body, file.substr(u64At(file, 88), u64At(file, 96)));
  const svo::StoreReader reader(servedStores().root / "sphere.svo");
  ASSERT_GT(reader.slices().size(), 10u);
  for (std::uint32_t id = 0; id < reader.slices().size(); ++id) {
    const svo::SliceInfo& s = reader.slices()[id];
    const HttpReply slice = client.get("/sphere/slices/" + std::to_string(id));
    ASSERT_EQ(slice.status, 200u) << id;
    EXPECT_EQ(slice.body, file.substr(s.offset, s.compressedBytes)) << id;
    EXPECT_EQ(XXH3_64bits(slice.body.data(), slice.body.size()), s.checksum) << id;
    char etag[32];
    std::snprintf(etag, sizeof etag, "\"%016llx\"", static_cast<unsigned long long>(s.checksum));
    EXPECT_EQ(slice.header("etag"), etag);
    EXPECT_EQ(slice.header("cache-control"), "public, max-age=31536000, immutable");
  }
  const svo::SliceInfo& last = reader.slices().back();
  const std::string lastTarget = "/sphere/slices/" + std::to_string(reader.slices().size() - 1);
  const HttpReply part = client.get(lastTarget, {{"Range", "bytes=3-9"}});
  EXPECT_EQ(part.status, 206u);
  EXPECT_EQ(part.body, file.substr(last.offset + 3, 7));
  EXPECT_EQ(client.get(lastTarget, {{"If-None-Match", part.header("etag")}}).status, 304u);
  EXPECT_EQ(client.get("/scenes/sphere/slices/0").body,
            file.substr(reader.slices()[0].offset, reader.slices()[0].compressedBytes));
}

TEST(Server, BadSliceIdsAreRefused) {
  svotest::HttpClient client(shared().port);
  const std::size_t count = svo::StoreReader(servedStores().root / "sphere.svo").slices().size();
  for (const char* bad : {"abc", "-1", "01", "1x", "99999999999"}) {
    const HttpReply r = client.get(std::string("/sphere/slices/") + bad);
    EXPECT_EQ(r.status, 400u) << bad;
    EXPECT_NE(r.body.find("not a slice id"), std::string::npos) << r.body;
  }
  const HttpReply unknown = client.get("/sphere/slices/" + std::to_string(count));
  EXPECT_EQ(unknown.status, 404u);
  EXPECT_EQ(unknown.body,
            "sphere has no slice " + std::to_string(count) + " (it has " + std::to_string(count) + ")\n");
}

TEST(Server, TraversalAndEscapesAreRefused) {
  const std::uint16_t port = shared().port;
  // Raw request lines: no client library normalizes these targets on the way.
  for (const char* target :
       {"/../x", "/%2e%2e/x", "/%2E%2E%2Fetc/passwd", "/sub/../sphere.svo", "/sub/%2e%2e/sphere.svo",
        "/escape.svo", "/escape", "/linkdir/x.svo", "/.hidden/h.svo", "//etc/passwd", "/sphere%00.svo",
        "/sub%5Cbox.svo", "/..%2Foutside%2Fx.svo", "/secret.svo.token"}) {
    const int fd = svotest::connectRaw(port);
    ASSERT_TRUE(svotest::sendRaw(
        fd, std::string("GET ") + target + " HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"));
    const std::string raw = svotest::receiveAll(fd);
    ::close(fd);
    const unsigned status = svotest::statusOf(raw);
    EXPECT_TRUE(status == 400 || status == 404) << target << ": " << raw.substr(0, 80);
  }
  EXPECT_EQ(httpGet(port, "/sub/box.svo").status, 200u);  // a real sub-folder store still serves
}

TEST(Server, TokensGuardEveryRouteButHealth) {
  svo::server::ServerOptions options;
  options.token = "t0k";
  RunningServer r = start(options);
  const auto bearer = [](const std::string& t) {
    return std::map<std::string, std::string>{{"Authorization", "Bearer " + t}};
  };
  EXPECT_EQ(httpGet(r.port, "/healthz").status, 200u);
  for (const char* target :
       {"/scenes", "/metrics", "/sphere.svo", "/sphere/info", "/sphere/slices/0", "/nosuch"}) {
    const HttpReply missing = httpGet(r.port, target);
    EXPECT_EQ(missing.status, 401u) << target;
    EXPECT_EQ(missing.header("www-authenticate").rfind("Bearer", 0), 0u) << target;
    EXPECT_EQ(httpGet(r.port, target, bearer("wrong")).status, 403u) << target;
    EXPECT_EQ(httpGet(r.port, target, {{"Authorization", "Basic dDBrOg=="}}).status, 401u) << target;
    const unsigned expected = std::string(target) == "/nosuch" ? 404u : 200u;
    EXPECT_EQ(httpGet(r.port, target, bearer("t0k")).status, expected) << target;
  }
  // A scene with a token file takes its own token, not the server's.
  EXPECT_EQ(httpGet(r.port, "/secret/info", bearer("t0k")).status, 403u);
  EXPECT_EQ(httpGet(r.port, "/secret/info", bearer("s3cret")).status, 200u);
  // Without a server token, the scene's token still guards it, and only it.
  const std::uint16_t open = shared().port;
  EXPECT_EQ(httpGet(open, "/secret/slices/0").status, 401u);
  EXPECT_EQ(httpGet(open, "/secret/slices/0", bearer("s3cre")).status, 403u);
  EXPECT_EQ(httpGet(open, "/secret/slices/0", bearer("s3cret")).status, 200u);
  EXPECT_EQ(httpGet(open, "/sphere/slices/0").status, 200u);
}

TEST(Server, MalformedAndOversizedRequestsAreRefused) {
  RunningServer r = start();
  EXPECT_EQ(svotest::rawStatus(r.port, "GARBAGE\r\n\r\n"), 400u);
  EXPECT_EQ(svotest::rawStatus(r.port, "GET /healthz HTTP/9.9\r\n\r\n"), 400u);
  EXPECT_EQ(svotest::rawStatus(r.port, "GET /healthz HTTP/1.1\r\nBad Header\r\n\r\n"), 400u);
  EXPECT_EQ(svotest::rawStatus(r.port, "GET /healthz HTTP/1.1\r\nContent-Length: x\r\n\r\n"), 400u);
  EXPECT_EQ(svotest::rawStatus(r.port, "BREW /pot HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"), 405u);
  EXPECT_EQ(
      svotest::rawStatus(r.port, "GET /healthz HTTP/1.1\r\nX-Big: " + std::string(40000, 'a') + "\r\n\r\n"),
      431u);
  EXPECT_EQ(svotest::rawStatus(
                r.port, "GET /healthz HTTP/1.1\r\nContent-Length: 200000\r\n\r\n" + std::string(200000, 'b')),
            413u);
  // A small body is read and ignored; the connection goes on.
  svotest::HttpClient client(r.port);
  EXPECT_EQ(svotest::rawStatus(r.port,
                               "GET /healthz HTTP/1.1\r\nContent-Length: 3\r\nConnection: close\r\n\r\nabc"),
            200u);
  EXPECT_EQ(client.get("/healthz").body, "ok\n");
  // Each refusal is one line, naming why (every line is written once stopped).
  r.server->stop();
  const std::vector<std::string> lines = r.log->copy();
  EXPECT_EQ(std::count_if(lines.begin(), lines.end(),
                          [](const std::string& l) { return l.find(": refused: ") != std::string::npos; }),
            6);
  EXPECT_TRUE(r.log->contains("header limit exceeded"));
}

TEST(Server, SlowClientIsCutWhileOthersAreServed) {
  svo::server::ServerOptions options;
  options.requestReadTimeout = std::chrono::milliseconds(300);
  RunningServer r = start(options);
  const int idle = svotest::connectRaw(r.port);  // sends nothing: closed quietly, not logged as a failure
  std::atomic<bool> cut{false};
  std::thread slow([&] {
    const int fd = svotest::connectRaw(r.port);
    svotest::sendRaw(fd, "GET /healthz HTTP/1.1\r\nX-Slow: ");
    // A byte each 50 ms for at most 20 s: far past the 300 ms the server allows a request.
    for (int i = 0; i < 400 && !cut; ++i) {
      char c;
      const ssize_t n = ::recv(fd, &c, 1, MSG_DONTWAIT);
      if (n == 0 || !svotest::sendRaw(fd, "a")) cut = true;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    ::close(fd);
  });
  const std::string file = slurp(servedStores().root / "sphere.svo");
  const svo::SliceInfo s = svo::StoreReader(servedStores().root / "sphere.svo").slices()[1];
  for (int i = 0; i < 10; ++i) {
    const HttpReply reply = httpGet(r.port, "/sphere/slices/1");
    EXPECT_EQ(reply.status, 200u);
    EXPECT_EQ(reply.body, file.substr(s.offset, s.compressedBytes));
  }
  slow.join();
  EXPECT_TRUE(cut);
  char c;
  EXPECT_EQ(::recv(idle, &c, 1, 0), 0);  // closed by the server (the receive timeout is 10 s)
  ::close(idle);
  EXPECT_EQ(httpGet(r.port, "/healthz").status, 200u);
  r.server->stop();
  const std::vector<std::string> lines = r.log->copy();
  EXPECT_EQ(std::count_if(
                lines.begin(), lines.end(),
                [](const std::string& l) { return l.find("no complete request within 300 ms") != l.npos; }),
            1);
}

TEST(Server, CorruptSliceAnswers500NamingIt) {
  const ServedStores& stores = servedStores();
  RunningServer r = start();
  const std::string target = "/corrupt/slices/" + std::to_string(stores.corruptSlice);
  for (int attempt = 0; attempt < 2; ++attempt) {  // never cached: the second read fails the same way
    const HttpReply bad = httpGet(r.port, target);
    EXPECT_EQ(bad.status, 500u);
    // Named by scene and slice, not by the server's path to the file.
    EXPECT_EQ(bad.body.rfind("corrupt: slice " + std::to_string(stores.corruptSlice) + " (", 0), 0u)
        << bad.body;
    EXPECT_NE(bad.body.find("checksum mismatch"), std::string::npos) << bad.body;
    EXPECT_EQ(bad.body.find(stores.root.string()), std::string::npos) << bad.body;
  }
  // A client holding the slice's version is told so without the slice being read.
  char etag[32];
  std::snprintf(etag, sizeof etag, "\"%016llx\"",
                static_cast<unsigned long long>(
                    svo::StoreReader(stores.root / "corrupt.svo").slices()[stores.corruptSlice].checksum));
  EXPECT_EQ(httpGet(r.port, target, {{"If-None-Match", etag}}).status, 304u);
  const std::string file = slurp(stores.root / "corrupt.svo");
  const svo::StoreReader reader(stores.root / "corrupt.svo");
  for (std::uint32_t id = 0; id < 5; ++id) {
    const HttpReply good = httpGet(r.port, "/corrupt/slices/" + std::to_string(id));
    EXPECT_EQ(good.status, 200u);
    EXPECT_EQ(good.body, file.substr(reader.slices()[id].offset, reader.slices()[id].compressedBytes));
  }
  const std::string metrics = httpGet(r.port, "/metrics").body;
  EXPECT_NE(metrics.find("svo_corrupt_slices_total 2"), std::string::npos) << metrics;
  // One line per failed request, naming the file and the slice (every line is written once stopped).
  r.server->stop();
  const std::vector<std::string> lines = r.log->copy();
  EXPECT_EQ(std::count_if(lines.begin(), lines.end(),
                          [&](const std::string& l) {
                            return l.find("corrupt.svo: slice " + std::to_string(stores.corruptSlice)) !=
                                   std::string::npos;
                          }),
            2);
}

}  // namespace
