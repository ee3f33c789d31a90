// Stores read from a real nginx and from svo serve by range requests (client/http_source.hpp,
// client/locator.hpp), against independent references: the local file's bytes, the local store's index and
// slices, and the frame a local pager converges to, bit for bit. Servers listen on 127.0.0.1 only and are
// stopped by the tests; retries and backoffs are kept tiny, and every wait is bounded in count.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <random>
#include <set>
#include <sstream>
#include <thread>

#include <nlohmann/json.hpp>

#include "link_delay.hpp"
#include "nginx_fixture.hpp"
#include "paging_helpers.hpp"
#include "reference.hpp"
#include "svo/builder/build.hpp"
#include "svo/client/http_source.hpp"
#include "svo/client/locator.hpp"
#include "svo/client/pager.hpp"
#include "svo/client/stream_source.hpp"
#include "svo/server/server.hpp"
#include "svo/store/store_reader.hpp"

namespace fs = std::filesystem;

namespace {

// The sphere and box store (many slices, so a pager makes many requests); `sliceBytes` changes the file
// without changing the scene.
fs::path writeStore(const fs::path& path, std::uint32_t sliceBytes = 4096) {
  svotest::writeSphereAndBoxStore(path, sliceBytes);
  return path;
}

std::vector<std::byte> fileBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::vector<char> chars((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<std::byte> out(chars.size());
  std::memcpy(out.data(), chars.data(), chars.size());
  return out;
}

std::string slurp(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

using svotest::cameraAt;
using svotest::converge;
using svotest::errorOf;
using svotest::everything;
using svotest::expectSameFrame;
using svotest::quickRetries;
using svotest::renderFinest;
using svotest::ServedFolder;
using svotest::sphereStore;

// A static server whose /private/ folder needs "Authorization: Bearer secret".
constexpr const char* kPrivateServerBlock =
    "server {\n listen 127.0.0.1:{port};\n root {root};\n"
    " location /private/ { if ($http_authorization != \"Bearer secret\") { return 401; } }\n}\n";

// The README's ```nginx block that holds `marker`, each `from` replaced by its `to`; empty, with a test
// failure saying what is missing, when the block or a `from` is not there.
std::string readmeNginxSnippet(const std::string& marker,
                               const std::vector<std::pair<std::string, std::string>>& replacements) {
  const std::string readme = slurp(fs::path(SVO_SOURCE_DIR) / "README.md");
  const std::size_t at = readme.find(marker);
  const std::size_t begin = at == std::string::npos ? at : readme.rfind("```nginx\n", at);
  if (begin == std::string::npos) {
    ADD_FAILURE() << "README.md has no nginx snippet holding \"" << marker << "\"";
    return "";
  }
  const std::size_t end = readme.find("```", at);
  std::string snippet = readme.substr(begin + 9, end - begin - 9);
  for (const auto& [from, to] : replacements) {
    const std::size_t found = snippet.find(from);
    if (found == std::string::npos) {
      ADD_FAILURE() << "the snippet has no \"" << from << "\":\n" << snippet;
      return "";
    }
    snippet.replace(found, from.size(), to);
  }
  return snippet;
}

// Streams the store at `url` into a pager, takes the server `down` mid-stream and brings it `up` again on
// the same port: the fetches that failed meanwhile are deferred, not failed, with one message for the outage,
// and the pager resumes with its pool and converges to the local pager's frame.
void expectResumesAcrossAnOutage(const std::string& url, const std::function<void()>& down,
                                 const std::function<void()>& up) {
  svo::PagerOptions options;
  options.fetchThreads = 4;
  options.sourceRetrySeconds = 0.02;
  options.sourceRetryMaxSeconds = 0.1;
  svo::Pager pager(svo::openSliceSource(url, quickRetries()), options);
  const svo::Camera camera = cameraAt({1.6, 2.4, 3.0}, {0, 0, 0}, 96);
  converge(pager, svo::viewOf(pager.transform(), camera, 16.0));  // the coarse levels
  const std::vector<std::uint32_t> before = pager.residentSlices();
  ASSERT_LT(before.size(), pager.index().slices().size());

  down();
  const svo::ViewQuery all = everything(pager, camera);
  std::uint32_t deferred = 0;
  for (int i = 0; i < 500 && deferred == 0; ++i) {
    deferred += pager.update(all).deferred;
    pager.waitForWork(0.02);
  }
  EXPECT_GT(deferred, 0u) << "no fetch failed while the server was down";
  EXPECT_FALSE(pager.converged());
  EXPECT_TRUE(pager.failedSlices().empty());
  EXPECT_FALSE(pager.deferredSlices().empty());
  const std::vector<std::string> errors = pager.takeErrors();
  ASSERT_EQ(errors.size(), 1u) << "one message for the outage";
  EXPECT_NE(errors[0].find("asking again later"), std::string::npos) << errors[0];

  up();
  converge(pager, all);
  EXPECT_TRUE(pager.failedSlices().empty());
  EXPECT_TRUE(pager.deferredSlices().empty());
  EXPECT_EQ(pager.residentSlices().size(), pager.index().slices().size());
  const std::vector<std::uint32_t> after = pager.residentSlices();
  EXPECT_TRUE(std::includes(after.begin(), after.end(), before.begin(), before.end())) << "the pool was kept";
  pager.checkInvariants();
  svo::Pager local(sphereStore(), options);
  converge(local, all);
  expectSameFrame(renderFinest(pager, camera), renderFinest(local, camera));
}

// The folder served by nginx.
class Http : public ServedFolder {
 protected:
  void SetUp() override {
    if (svotest::nginxBinary().empty())
      GTEST_SKIP() << "nginx is not installed (Debian: nginx-light): the HTTP range tests need a real server";
    ServedFolder::SetUp();
  }
  void stopServer() override { server_.reset(); }
  svotest::NginxServer& serve(svotest::NginxServer::Options options = {}) {
    server_ = std::make_unique<svotest::NginxServer>(root_, std::move(options));
    return *server_;
  }

  std::unique_ptr<svotest::NginxServer> server_;
};

}  // namespace

TEST_F(Http, EveryByteRangeEqualsTheFile) {
  // Random bytes, not a store: any file is served alike.
  std::vector<std::byte> bytes(300'001);
  std::mt19937 rng(7);
  for (std::byte& b : bytes) b = std::byte(rng() & 0xff);
  std::ofstream(root_ / "random.bin", std::ios::binary)
      .write(reinterpret_cast<const char*>(bytes.data()), std::streamsize(bytes.size()));
  svotest::NginxServer& server = serve();
  const svo::HttpByteSource source(server.url("random.bin"), quickRetries());
  EXPECT_EQ(source.name(), server.url("random.bin"));
  ASSERT_EQ(source.size(), bytes.size());
  EXPECT_FALSE(source.validator().empty());  // nginx sends an ETag for static files

  // Reads that need a request: those with bytes to give beyond the first ones the opening request kept.
  std::uint64_t requests = 1;
  const auto expectRead = [&](std::uint64_t offset, std::size_t length) {
    std::vector<std::byte> out(length, std::byte(0xee));
    const std::size_t got = source.read(offset, out);
    const std::size_t expected =
        offset >= bytes.size() ? 0 : std::min<std::size_t>(length, bytes.size() - offset);
    requests += expected > 0 && offset + expected > svo::kHttpPrefixBytes;
    ASSERT_EQ(got, expected) << "offset " << offset << " length " << length;
    EXPECT_EQ(std::memcmp(out.data(), bytes.data() + std::min<std::uint64_t>(offset, bytes.size()), got), 0)
        << "offset " << offset << " length " << length;
    for (std::size_t i = got; i < length; ++i) ASSERT_EQ(out[i], std::byte(0xee)) << "written past the end";
  };
  std::uniform_int_distribution<std::uint64_t> offsets(0, bytes.size() - 1);
  std::uniform_int_distribution<std::size_t> lengths(1, 70'000);
  for (int i = 0; i < 100; ++i) expectRead(offsets(rng), lengths(rng));
  expectRead(0, bytes.size());                   // the whole file
  expectRead(bytes.size() - 1, 1);               // its last byte
  expectRead(bytes.size() - 10, 100);            // across the end: the 10 there are
  expectRead(bytes.size(), 16);                  // at the end: nothing
  expectRead(bytes.size() + 1000, 16);           // past it
  expectRead(12345, 0);                          // nothing asked
  expectRead(0, 256);                            // among the first bytes: no request
  expectRead(svo::kHttpPrefixBytes - 100, 200);  // across their end
  const svo::HttpStats sequential = source.stats();
  EXPECT_EQ(sequential.requests, requests);
  EXPECT_EQ(sequential.retries, 0u);

  // Several threads at once, each on its own kept-alive connection.
  std::vector<std::thread> threads;
  std::atomic<int> wrong{0};
  for (int t = 0; t < 4; ++t)
    threads.emplace_back([&, t] {
      std::mt19937 local(100 + t);
      for (int i = 0; i < 50; ++i) {
        const std::uint64_t offset = offsets(local);
        std::vector<std::byte> out(lengths(local));
        const std::size_t got = source.read(offset, out);
        wrong += got != std::min<std::size_t>(out.size(), bytes.size() - offset) ||
                 std::memcmp(out.data(), bytes.data() + offset, got) != 0;
      }
    });
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(wrong.load(), 0);

  // Connections are kept alive: 305 requests came over at most one per thread that ever read. nginx logs a
  // request once its response is sent, so the last line may come a moment after the client has its bytes.
  const auto countLines = [](const std::string& text) {
    return std::size_t(std::count(text.begin(), text.end(), '\n'));
  };
  std::string accessLog = server.accessLog();
  for (int wait = 0; wait < 500 && countLines(accessLog) < source.stats().requests; ++wait) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    accessLog = server.accessLog();
  }
  std::set<std::string> connections;
  std::size_t lines = 0;
  std::istringstream log(accessLog);
  for (std::string line; std::getline(log, line); ++lines) {
    EXPECT_NE(line.find(" 206 "), std::string::npos) << line;
    connections.insert(line.substr(0, line.find(' ')));
  }
  EXPECT_EQ(lines, source.stats().requests);
  EXPECT_LE(connections.size(), 5u);
}

TEST_F(Http, StoreIndexAndSlicesEqualTheLocalOnes) {
  svotest::NginxServer& server = serve();
  const auto local = svo::openSliceSource(sphereStore().string());
  const auto remote = svo::openSliceSource(server.url("scene.svo"), quickRetries());
  const svo::StoreIndex &a = local->index(), &b = remote->index();
  EXPECT_EQ(b.name(), server.url("scene.svo"));
  EXPECT_EQ(a.header().fileBytes, b.header().fileBytes);
  EXPECT_EQ(a.header().directoryOffset, b.header().directoryOffset);
  EXPECT_EQ(a.header().directoryChecksum, b.header().directoryChecksum);
  EXPECT_EQ(a.header().parameters.levels, b.header().parameters.levels);
  ASSERT_EQ(a.slices().size(), b.slices().size());
  ASSERT_GT(a.slices().size(), 20u);
  svo::SliceBytes x, y;
  for (std::uint32_t s = 0; s < a.slices().size(); ++s) {
    EXPECT_EQ(a.slices()[s].offset, b.slices()[s].offset) << s;
    EXPECT_EQ(a.slices()[s].checksum, b.slices()[s].checksum) << s;
    EXPECT_EQ(a.slices()[s].parentSlice, b.slices()[s].parentSlice) << s;
    local->fetch(s, x);
    remote->fetch(s, y);
    ASSERT_EQ(x.size(), y.size()) << s;
    EXPECT_EQ(std::memcmp(x.data(), y.data(), x.size()), 0) << "slice " << s;
  }
  // Through the store reader too: every checksum and invariant holds over HTTP.
  const svo::StoreReader reader(svo::openByteSource(server.url("scene.svo"), quickRetries()));
  EXPECT_EQ(reader.verify(), svo::StoreReader(sphereStore()).verify());
}

TEST_F(Http, PagerOverHttpConvergesToTheLocalImage) {
  svotest::NginxServer& server = serve();
  const svo::Camera camera = cameraAt({1.6, 2.4, 3.0}, {0, 0, 0}, 96);
  for (const std::size_t budget : {std::size_t(256) << 20, std::size_t(512) << 10}) {
    svo::PagerOptions options;
    options.budgetBytes = budget;
    options.fetchThreads = 4;
    svo::Pager local(sphereStore(), options);
    const std::shared_ptr<svo::SliceSource> source =
        svo::openSliceSource(server.url("scene.svo"), quickRetries());
    svo::Pager remote(source, options);
    // The view's own frustum, finest detail: what a render command converges.
    const svo::ViewQuery view = svo::viewOf(local.transform(), camera, 0.0);
    converge(local, view);
    converge(remote, view);
    EXPECT_TRUE(remote.failedSlices().empty());
    EXPECT_EQ(remote.residentSlices(), local.residentSlices()) << "budget " << budget;
    // The tight budget holds part of what the view wants: which part is the scheduler's choice, the same
    // over either source.
    if (budget < (std::size_t(1) << 20))
      EXPECT_LT(remote.residentSlices().size(), remote.index().slices().size());
    EXPECT_GE(remote.bytesRead(), remote.index().slices()[remote.residentSlices().back()].compressedBytes);
    remote.checkInvariants();
    expectSameFrame(renderFinest(remote, camera), renderFinest(local, camera));
    // nginx has no view stream: the source learns so from its 404 and reads by range alone.
    const auto& stream = dynamic_cast<const svo::ViewStreamSource&>(*source);
    for (int i = 0; i < 200 && !stream.stats().declined; ++i)
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    EXPECT_TRUE(stream.stats().declined);
    EXPECT_EQ(stream.stats().pushed, 0u);
  }
}

TEST_F(Http, MissingStoresClosedPortsAndBadUrlsAreOneClearLine) {
  svotest::NginxServer& server = serve();
  const std::string missing = server.url("missing.svo");
  const std::string notFound = errorOf([&] { svo::openSliceSource(missing, quickRetries()); });
  EXPECT_NE(notFound.find(missing), std::string::npos) << notFound;
  EXPECT_NE(notFound.find("no such store"), std::string::npos) << notFound;
  EXPECT_NE(notFound.find("404"), std::string::npos) << notFound;
  EXPECT_EQ(server.accessLog().find("missing.svo"), server.accessLog().rfind("missing.svo"))
      << "a 404 is not retried:\n"
      << server.accessLog();

  // A port nothing listens on: the retries run out, and the error says the failure may pass.
  const std::string url = server.url("scene.svo");
  server.stop();
  try {
    svo::HttpByteSource source(url, quickRetries());
    ADD_FAILURE() << "opened a store on a stopped server";
  } catch (const svo::TransientSourceError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(url), std::string::npos) << what;
    EXPECT_NE(what.find("connect"), std::string::npos) << what;
    EXPECT_NE(what.find("gave up after 3 attempts"), std::string::npos) << what;
  }

  const std::string ftp = errorOf([] { svo::openSliceSource("ftp://127.0.0.1/scene.svo"); });
  EXPECT_NE(ftp.find("ftp://127.0.0.1/scene.svo"), std::string::npos) << ftp;
  EXPECT_NE(ftp.find("http://"), std::string::npos) << ftp;
  const std::string bad = errorOf([] { svo::openSliceSource("http://127.0.0.1:99999/scene.svo"); });
  EXPECT_NE(bad.find("not a valid URL"), std::string::npos) << bad;
  EXPECT_FALSE(svo::isUrl("scenes/a.svo"));
  EXPECT_FALSE(svo::isUrl("/abs/a:b.svo"));
  EXPECT_TRUE(svo::isUrl("HTTPS://host/a.svo"));
}

TEST_F(Http, ServerWithoutRangeRequestsIsRefused) {
  fs::create_directories(root_ / "norange");
  fs::copy_file(sphereStore(), root_ / "norange" / "scene.svo");
  svotest::NginxServer::Options options;
  options.serverBlock =
      "server {\n listen 127.0.0.1:{port};\n root {root};\n location /norange/ { max_ranges 0; }\n}\n";
  svotest::NginxServer& server = serve(options);
  const std::string what =
      errorOf([&] { svo::HttpByteSource(server.url("norange/scene.svo"), quickRetries()); });
  EXPECT_NE(what.find(server.url("norange/scene.svo")), std::string::npos) << what;
  EXPECT_NE(what.find("does not answer range requests"), std::string::npos) << what;
}

// The token check of the README's nginx snippet: no token is a 401 naming --token, a wrong one is refused,
// the right one reads the same bytes.
TEST_F(Http, BearerTokenIsSentAndItsAbsenceExplained) {
  fs::create_directories(root_ / "private");
  fs::copy_file(sphereStore(), root_ / "private" / "scene.svo");
  svotest::NginxServer& server = serve({kPrivateServerBlock});
  const std::string url = server.url("private/scene.svo");
  svo::RemoteOptions remote = quickRetries();
  const std::string none = errorOf([&] { svo::openSliceSource(url, remote); });
  EXPECT_NE(none.find(url), std::string::npos) << none;
  EXPECT_NE(none.find("needs a token (--token or SVO_TOKEN"), std::string::npos) << none;
  remote.token = "wrong";
  const std::string wrong = errorOf([&] { svo::openSliceSource(url, remote); });
  EXPECT_NE(wrong.find("token refused"), std::string::npos) << wrong;
  remote.token = "secret";
  const auto source = svo::openSliceSource(url, remote);
  const auto local = svo::openSliceSource(sphereStore().string());
  ASSERT_EQ(source->index().slices().size(), local->index().slices().size());
  svo::SliceBytes x, y;
  const std::uint32_t last = std::uint32_t(local->index().slices().size() - 1);
  source->fetch(last, x);
  local->fetch(last, y);
  EXPECT_TRUE(x == y);
}

TEST_F(Http, StoreReplacedOnTheServerMidStreamIsAClearError) {
  svotest::NginxServer& server = serve();
  const auto source = svo::openSliceSource(server.url("scene.svo"), quickRetries());
  const std::uint32_t last = std::uint32_t(source->index().slices().size() - 1);
  ASSERT_GT(source->index().slices()[last].offset, svo::kHttpPrefixBytes) << "a slice the opening read kept";
  svo::SliceBytes bytes;
  source->fetch(last - 1, bytes);
  // Another build of the scene, renamed over the served file as a deploy would: another size and time, so
  // another ETag.
  const fs::path next = root_ / "scene.svo.next";
  writeStore(next, 8192);
  fs::last_write_time(next, fs::last_write_time(root_ / "scene.svo") + std::chrono::seconds(10));
  fs::rename(next, root_ / "scene.svo");
  try {
    source->fetch(last, bytes);
    ADD_FAILURE() << "read a slice of a replaced store";
  } catch (const svo::SliceError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(server.url("scene.svo")), std::string::npos) << what;
    EXPECT_NE(what.find("changed on the server"), std::string::npos) << what;
    EXPECT_FALSE(e.transient) << what;
  }
  // Opened again, it is the new store.
  const auto reopened = svo::openSliceSource(server.url("scene.svo"), quickRetries());
  EXPECT_EQ(reopened->index().header().fileBytes, fs::file_size(root_ / "scene.svo"));
}

// nginx is killed mid-stream and restarted on the same port.
TEST_F(Http, PagerResumesAfterTheServerIsKilledAndRestarted) {
  svotest::NginxServer& server = serve();
  expectResumesAcrossAnOutage(
      server.url("scene.svo"), [&] { server.kill(); }, [&] { server.start(); });
}

// The README's nginx snippet, as printed there, serves stores to `svo`: public ones, and private ones with
// the token.
TEST_F(Http, ReadmeNginxSnippetServesStores) {
  // The snippet's port and folder, replaced by the test's.
  const std::string snippet = readmeNginxSnippet(
      "listen 8080;", {{"listen 8080;", "listen 127.0.0.1:{port};"}, {"/srv/scenes", "{root}"}});
  ASSERT_FALSE(snippet.empty());
  fs::create_directories(root_ / "private");
  fs::copy_file(sphereStore(), root_ / "private" / "scene.svo");
  svotest::NginxServer& server = serve({snippet});
  const auto open = svo::openSliceSource(server.url("scene.svo"), quickRetries());
  EXPECT_EQ(open->index().header().fileBytes, fs::file_size(sphereStore()));
  const std::string refused =
      errorOf([&] { svo::openSliceSource(server.url("private/scene.svo"), quickRetries()); });
  EXPECT_NE(refused.find("needs a token"), std::string::npos) << refused;
  svo::RemoteOptions remote = quickRetries();
  remote.token = "secret";  // the snippet's example token
  EXPECT_EQ(svo::openSliceSource(server.url("private/scene.svo"), remote)->index().slices().size(),
            open->index().slices().size());
}

// The README's TLS proxy in front of svo serve, with a certificate made here for 127.0.0.1: the pager
// converges over https:// to the local frame; a client that does not trust the certificate refuses the
// server.
TEST_F(Http, ReadmeTlsProxyServesSvoServeOverHttps) {
  if (std::system("openssl version > /dev/null 2>&1") != 0)
    GTEST_SKIP() << "openssl is not installed (Debian: openssl): the TLS test makes its certificate with it";
  const svotest::TempDir certs;
  const fs::path cert = certs.path() / "cert.pem", key = certs.path() / "key.pem";
  const std::string make =
      "openssl req -x509 -newkey rsa:2048 -nodes -days 1 -subj /CN=127.0.0.1 "
      "-addext subjectAltName=IP:127.0.0.1 -keyout " +
      key.string() + " -out " + cert.string() + " > /dev/null 2>&1";
  ASSERT_EQ(std::system(make.c_str()), 0) << make;
  const std::unique_ptr<svo::server::Server> backend = svotest::startServer(root_);
  const std::string snippet = readmeNginxSnippet(
      "listen 8443 ssl;", {{"listen 8443 ssl;", "listen 127.0.0.1:{port} ssl;"},
                           {"/etc/ssl/svo/cert.pem", cert.string()},
                           {"/etc/ssl/svo/key.pem", key.string()},
                           {"127.0.0.1:8080", "127.0.0.1:" + std::to_string(backend->port())}});
  ASSERT_FALSE(snippet.empty());
  svotest::NginxServer& server = serve({snippet});
  const std::string url = "https://127.0.0.1:" + std::to_string(server.port()) + "/scene";
  svo::RemoteOptions remote = quickRetries();
  const std::string untrusted = errorOf([&] { svo::openSliceSource(url, remote); });
  EXPECT_NE(untrusted.find("certificate"), std::string::npos) << untrusted;
  remote.caFile = cert.string();
  svo::PagerOptions pagerOptions;
  pagerOptions.fetchThreads = 4;
  svo::Pager local(sphereStore(), pagerOptions), served(svo::openSliceSource(url, remote), pagerOptions);
  const svo::Camera camera = cameraAt({1.6, 2.4, 3.0}, {0, 0, 0}, 96);
  const svo::ViewQuery view = svo::viewOf(local.transform(), camera, 0.0);
  converge(local, view);
  converge(served, view);
  EXPECT_TRUE(served.failedSlices().empty());
  EXPECT_EQ(served.residentSlices(), local.residentSlices());
  expectSameFrame(renderFinest(served, camera), renderFinest(local, camera));
}

// The commands take a URL wherever they take a store: the same images, byte for byte, as from the file.
TEST_F(Http, CommandsReadUrlsAsTheyReadFiles) {
  fs::create_directories(root_ / "private");
  fs::copy_file(sphereStore(), root_ / "private" / "scene.svo");
  svotest::NginxServer& server = serve({kPrivateServerBlock});
  const fs::path out = root_ / "out";
  fs::create_directories(out);
  const auto svo = [&](const std::string& args, const std::string& env = "") {
    const std::string command = env + " " + SVO_BINARY + " " + args + " >" + (out / "stdout").string() +
                                " 2>" + (out / "stderr").string();
    const int status = std::system(command.c_str());
    return std::make_pair(WIFEXITED(status) ? WEXITSTATUS(status) : 128, slurp(out / "stderr"));
  };
  const std::string local = sphereStore().string(), url = server.url("scene.svo");
  const std::string size = " --width 64 --height 64";
  for (const std::string& mode : {std::string(""), std::string(" --budget 1M")}) {
    ASSERT_EQ(svo("render " + local + " -o " + (out / "local.png").string() + size + mode).first, 0);
    const auto [code, err] = svo("render " + url + " -o " + (out / "http.png").string() + size + mode);
    ASSERT_EQ(code, 0) << err;
    EXPECT_EQ(slurp(out / "local.png"), slurp(out / "http.png")) << "render" << mode;
  }
  const auto [tokenCode, tokenErr] =
      svo("render " + server.url("private/scene.svo") + " -o " + (out / "private.png").string() + size,
          "SVO_TOKEN=secret");
  ASSERT_EQ(tokenCode, 0) << tokenErr;
  EXPECT_EQ(slurp(out / "local.png"), slurp(out / "private.png"));

  ASSERT_EQ(svo("inspect --json " + local).first, 0);
  nlohmann::json a = nlohmann::json::parse(slurp(out / "stdout"));
  ASSERT_EQ(svo("inspect --json " + url).first, 0);
  nlohmann::json b = nlohmann::json::parse(slurp(out / "stdout"));
  EXPECT_EQ(b["file"], url);
  a.erase("file"), b.erase("file");
  EXPECT_EQ(a, b);
  const auto [verifyCode, verifyErr] = svo("verify " + url);
  EXPECT_EQ(verifyCode, 0) << verifyErr;

  // One line naming the URL: a missing store, a missing token, an unsupported scheme.
  const std::vector<std::pair<std::string, std::string>> failures{
      {"render " + server.url("missing.svo") + " -o " + (out / "x.png").string(), "no such store"},
      {"render " + server.url("private/scene.svo") + " -o " + (out / "x.png").string(), "needs a token"},
      {"stress " + server.url("missing.svo"), "no such store"},
      {"verify ftp://127.0.0.1/scene.svo", "http:// or https://"}};
  for (const auto& [args, needle] : failures) {
    const auto [code, err] = svo(args);
    EXPECT_EQ(code, 1) << args << ": " << err;
    EXPECT_NE(err.find(needle), std::string::npos) << args << ": " << err;
    EXPECT_EQ(std::count(err.begin(), err.end(), '\n'), 1) << args << ": " << err;
  }
  EXPECT_FALSE(fs::exists(out / "x.png"));
}

// The benchmarks' link-delay relay passes every byte through intact, in both directions and over kept-alive
// connections, from several threads at once, also when its connections share a link of bounded rate.
TEST_F(Http, LinkDelayRelayPassesBytesIntact) {
  svotest::NginxServer& server = serve();
  for (const double bitsPerSecond : {0.0, 400e6}) {
    const svo::tools::bench::LinkDelay link("127.0.0.1", server.port(), 0.002, bitsPerSecond);
    const std::string url = "http://127.0.0.1:" + std::to_string(link.port()) + "/scene.svo";
    const auto remote = svo::openSliceSource(url, quickRetries());
    const auto local = svo::openSliceSource(sphereStore().string());
    const std::uint32_t count = std::uint32_t(local->index().slices().size());
    std::atomic<int> wrong{0};
    std::vector<std::thread> threads;
    for (std::uint32_t t = 0; t < 3; ++t)
      threads.emplace_back([&, t] {
        svo::SliceBytes x, y;
        for (std::uint32_t s = t; s < count; s += 3) {
          remote->fetch(s, x);
          local->fetch(s, y);
          wrong += !(x == y);
        }
      });
    for (std::thread& t : threads) t.join();
    EXPECT_EQ(wrong.load(), 0) << bitsPerSecond << " bits per second";
  }
  EXPECT_THROW(svo::tools::bench::LinkDelay("127.0.0.1", server.port(), 0.002, -1.0), std::runtime_error);
}

// ----- the same client against `svo serve` (svo::server::Server in process) --------------------------------

namespace {

// svo::server over a folder holding the sphere store as scene.svo, on a loopback port the first start picks
// and later starts reuse.
class ServeHttp : public ServedFolder {
 protected:
  void stopServer() override { server_.reset(); }
  void start(const std::string& token = "") {
    server_ = svotest::startServer(root_, port_, token);
    port_ = server_->port();
  }
  std::string url() const { return "http://127.0.0.1:" + std::to_string(port_) + "/scene"; }

  std::uint16_t port_ = 0;
  std::unique_ptr<svo::server::Server> server_;
};

}  // namespace

// `svo serve`'s /NAME is the store file with range requests, as nginx serves it: the pager converges to the
// local frame through it, with and without a token.
TEST_F(ServeHttp, PagerOverSvoServeConvergesToTheLocalImage) {
  start("secret");
  svo::RemoteOptions remote = quickRetries();
  EXPECT_NE(errorOf([&] { svo::openSliceSource(url(), remote); }).find("needs a token"), std::string::npos);
  remote.token = "secret";
  const svo::Camera camera = cameraAt({1.6, 2.4, 3.0}, {0, 0, 0}, 96);
  svo::PagerOptions options;
  options.fetchThreads = 4;
  svo::Pager local(sphereStore(), options);
  const svo::ViewQuery view = svo::viewOf(local.transform(), camera, 0.0);
  converge(local, view);
  for (const bool viewStream : {false, true}) {  // by range alone, and beside the view stream
    remote.viewStream = viewStream;
    svo::Pager served(svo::openSliceSource(url(), remote), options);
    converge(served, view);
    EXPECT_TRUE(served.failedSlices().empty());
    EXPECT_EQ(served.residentSlices(), local.residentSlices());
    served.checkInvariants();
    expectSameFrame(renderFinest(served, camera), renderFinest(local, camera));
  }
}

// svo serve stops mid-stream and starts again on the same port.
TEST_F(ServeHttp, PagerResumesAfterSvoServeStopsAndStartsAgain) {
  start();
  expectResumesAcrossAnOutage(
      url(), [&] { stopServer(); }, [&] { start(); });
}
