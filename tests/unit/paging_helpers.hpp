// Helpers of the tests that page stores from servers: the sphere store and a folder serving it, svo::server
// in process, quick retries, cameras, convergence bounded in count, bit-for-bit frame comparison.
#pragma once

#include <gtest/gtest.h>

#include <stdlib.h>

#include <cstring>
#include <exception>
#include <filesystem>
#include <memory>
#include <string>

#include "reference.hpp"
#include "svo/client/http_source.hpp"
#include "svo/client/pager.hpp"
#include "svo/server/server.hpp"

namespace svotest {

// The sphere and box store with 4 KiB slices (many slices, so a pager makes many requests), written once.
inline const std::filesystem::path& sphereStore() {
  static const TempFile file = [] {
    TempFile f("svo_paging_store", ".svo");
    writeSphereAndBoxStore(f.path, 4096);
    return f;
  }();
  return file.path;
}

// A folder to serve, holding the sphere store as scene.svo; the server stops and the folder goes after the
// test.
class ServedFolder : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern = (std::filesystem::temp_directory_path() / "svo_served_XXXXXX").string();
    ASSERT_NE(::mkdtemp(pattern.data()), nullptr);
    root_ = pattern;
    std::filesystem::copy_file(sphereStore(), root_ / "scene.svo");
  }
  void TearDown() override {
    stopServer();
    if (!root_.empty()) std::filesystem::remove_all(root_);
  }
  virtual void stopServer() = 0;

  std::filesystem::path root_;
};

// svo::server over `root` on 127.0.0.1 (`port` 0: a free one), quiet, started.
inline std::unique_ptr<svo::server::Server> startServer(
    const std::filesystem::path& root, std::uint16_t port = 0, const std::string& token = "",
    std::uint64_t streamWindowBytes = svo::server::kDefaultStreamWindowBytes) {
  svo::server::ServerOptions options;
  options.root = root;
  options.port = port;
  options.threads = 2;
  options.token = token;
  options.streamWindowBytes = streamWindowBytes;
  options.logSink = [](std::string_view) {};
  auto server = std::make_unique<svo::server::Server>(options);
  server->start();
  return server;
}

// Retries that end within a second: tests see the final error quickly.
inline svo::RemoteOptions quickRetries() {
  svo::RemoteOptions o;
  o.retries = 2;
  o.backoffBaseSeconds = 0.01;
  o.backoffMaxSeconds = 0.05;
  o.retryBudgetSeconds = 1.0;
  o.connectTimeoutSeconds = 2.0;
  o.requestTimeoutSeconds = 10.0;
  return o;
}

inline svo::Camera cameraAt(glm::dvec3 eye, glm::dvec3 target, int size) {
  svo::Camera c;
  c.eye = eye, c.target = target, c.fovYDegrees = 50.0, c.width = c.height = size;
  return c;
}

// Every slice of the store, whatever the camera sees.
inline svo::ViewQuery everything(const svo::Pager& pager, const svo::Camera& camera) {
  svo::ViewQuery view = svo::viewOf(pager.transform(), camera, 1e-9);
  view.frustum.clear();
  return view;
}

// Updates until the view has converged; bounded. Returns the slices deferred on the way.
inline std::uint32_t converge(svo::Pager& pager, const svo::ViewQuery& view) {
  std::uint32_t deferred = 0;
  for (int i = 0; i < 4000; ++i) {
    deferred += pager.update(view).deferred;
    if (pager.converged()) return deferred;
    pager.waitForWork(0.02);
  }
  ADD_FAILURE() << "the pager did not converge";
  return deferred;
}

// Both frames bit for bit: color and depth of every pixel.
inline void expectSameFrame(const svo::Frame& a, const svo::Frame& b) {
  ASSERT_EQ(a.color.size(), b.color.size());
  std::size_t hits = 0;
  for (const glm::vec4& c : b.color) hits += c.a > 0.0f;
  EXPECT_GT(hits, 0u);
  EXPECT_EQ(std::memcmp(a.color.data(), b.color.data(), a.color.size() * sizeof(glm::vec4)), 0);
  EXPECT_EQ(std::memcmp(a.depth.data(), b.depth.data(), a.depth.size() * sizeof(float)), 0);
}

inline svo::Frame renderFinest(const svo::Pager& pager, const svo::Camera& camera) {
  svo::RenderOptions options;
  options.lodPixels = 0.0f, options.threads = 1;
  return svo::render(pager.trunk(), pager.transform(), camera, options);
}

}  // namespace svotest
