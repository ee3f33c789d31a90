// The HTTP paging service (docs/architecture.md): serves every .svo store under a folder to many
// clients over HTTP/1.1 keep-alive, as whole files with range requests (what a static server does, so a
// generic range client reads it like nginx) and by part (info, directory, slices as stored, checksums end
// to end), from a bounded cache of compressed slices shared by all connections. Routes:
//   GET /healthz, /metrics (Prometheus text), /scenes (JSON)
//   GET /NAME.svo and /NAME            the store file (Range, ETag, If-None-Match, HEAD)
//   GET /NAME/info                     JSON metadata
//   GET /NAME/directory                the directory's bytes as stored
//   GET /NAME/slices/ID                slice ID's compressed bytes as stored (immutable, ETag = checksum)
//   GET /NAME/stream (WebSocket)       the view stream: the client sends views, the server pushes the
//                                      slices each needs, most valuable first (svo/store/view_stream.hpp)
// NAME is a store's path under the folder without .svo. Its only state is the cache: many instances can
// stand behind a load balancer.
#pragma once

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

namespace svo::server {

// The slice cache's bound when none is given: room for a few hundred 1 MB slices (the store's default
// slice size), the hot set of a handful of viewers of one scene.
inline constexpr std::uint64_t kDefaultCacheBytes = std::uint64_t(256) << 20;
// How long a request may take to arrive, head and body, counted from the end of the last response: a
// client sending a byte a second is cut after it, and an idle keep-alive connection closed.
inline constexpr std::chrono::milliseconds kDefaultRequestReadTimeout{10'000};
// Bytes a view stream may have sent that its client has not acknowledged: twice a 100 Mbit/s, 100 ms
// link's 1.25 MB in flight, so the window does not idle such a link, while a superseded view wastes at most
// this much and one client's backlog stays bounded.
inline constexpr std::uint64_t kDefaultStreamWindowBytes = std::uint64_t(4) << 20;

enum class LogFormat { Text, Json };

struct ServerOptions {
  std::filesystem::path root;      // the folder of stores, searched recursively
  std::string bind = "127.0.0.1";  // address to listen on
  std::uint16_t port = 0;          // 0: a free port (port() says which)
  unsigned threads = 0;            // I/O threads; 0: one per hardware thread
  std::uint64_t cacheBytes = kDefaultCacheBytes;
  std::uint64_t streamWindowBytes = kDefaultStreamWindowBytes;
  std::string token;  // non-empty: "Authorization: Bearer TOKEN" on every route but /healthz
  LogFormat logFormat = LogFormat::Text;
  bool logRequests = true;  // one line per request (failures are always logged)
  std::chrono::milliseconds requestReadTimeout = kDefaultRequestReadTimeout;
  // Where log lines go (one call per line, no end of line); empty: stderr.
  std::function<void(std::string_view)> logSink;
};

class Server {
 public:
  // Checks the folder: throws std::runtime_error with one line when it does not exist or holds no store.
  explicit Server(ServerOptions options);
  ~Server();  // stop()
  Server(const Server&) = delete;
  Server& operator=(const Server&) = delete;

  // Listens and starts the I/O threads; throws std::runtime_error naming the address when it cannot.
  void start();
  std::uint16_t port() const;
  // "http://ADDRESS:PORT".
  std::string url() const;
  // The stores found when the server was made.
  std::size_t storeCount() const;
  // Stops accepting, lets responses in flight finish (for a bounded time), closes idle connections and
  // joins the threads. Idempotent.
  void stop();
  // Catches SIGINT and SIGTERM, starts, calls `listening` (to say where), blocks until one of the signals
  // arrives, then stops.
  void serveUntilSignal(const std::function<void(const Server&)>& listening);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace svo::server
