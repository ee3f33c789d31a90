// The benchmarks' peers (tools/bench/nginx_peer.hpp): nginx started in a scratch folder serves the store
// placed there, byte for byte by range requests, until its Child goes; the scratch folder goes with its
// object.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <vector>

#include "nginx_fixture.hpp"
#include "nginx_peer.hpp"
#include "svo/client/locator.hpp"

namespace fs = std::filesystem;
using namespace svo::tools::bench;

namespace {

std::string slurp(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

}  // namespace

TEST(NginxPeer, ServesTheScratchFoldersStoreByRanges) {
  const std::string nginx = svotest::nginxBinary();
  if (nginx.empty()) GTEST_SKIP() << "nginx is not installed";
  const fs::path store = fs::path(SVO_TEST_DATA) / "fixtures" / "sphere-v4.svo";
  const std::string bytes = slurp(store);
  fs::path folder;
  {
    const ScratchFolder scratch(fs::temp_directory_path() / ("svo_nginx_peer_" + std::to_string(::getpid())));
    folder = scratch.path;
    const fs::path served = scratch.serve(store);
    EXPECT_EQ(served, scratch.path / "root" / "sphere-v4.svo");
    const std::uint16_t port = freePort();
    std::unique_ptr<Child> child = startNginx(nginx, scratch.path, scratch.path / "root", port, 1);
    waitUntilListening(*child, port, "nginx");
    const auto source =
        svo::openByteSource("http://127.0.0.1:" + std::to_string(port) + "/" + urlSegment("sphere-v4.svo"));
    ASSERT_EQ(source->size(), bytes.size());
    std::vector<std::byte> tail(100);
    ASSERT_EQ(source->read(bytes.size() - tail.size(), tail), tail.size());
    EXPECT_EQ(std::string(reinterpret_cast<const char*>(tail.data()), tail.size()),
              bytes.substr(bytes.size() - 100));
    child->stop();
    EXPECT_FALSE(child->running());
  }
  EXPECT_FALSE(fs::exists(folder));
}

TEST(NginxPeer, NamesAndPaths) {
  EXPECT_EQ(urlSegment("a b/c~d.svo"), "a%20b%2Fc~d.svo");
  EXPECT_TRUE(onPath("sh"));
  EXPECT_TRUE(onPath("/bin/sh"));
  EXPECT_FALSE(onPath("svo-no-such-program"));
  // Open to others: nothing to say; a folder closed to others is named, but only where nginx's workers would
  // run as another user (this process is root).
  const fs::path folder = fs::temp_directory_path() / ("svo_nginx_closed_" + std::to_string(::getpid()));
  fs::create_directories(folder);
  std::ofstream(folder / "store.svo") << "x";
  fs::permissions(
      folder, fs::perms::owner_all | fs::perms::group_all | fs::perms::others_read | fs::perms::others_exec);
  fs::permissions(folder / "store.svo", fs::perms::owner_read | fs::perms::others_read);
  EXPECT_EQ(closedToNginxWorkers(folder / "store.svo"), "");
  fs::permissions(folder, fs::perms::others_exec, fs::perm_options::remove);
  EXPECT_EQ(closedToNginxWorkers(folder / "store.svo"), ::geteuid() == 0 ? folder.string() : "");
  fs::remove_all(folder);
}
