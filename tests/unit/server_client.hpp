// Test clients for the paging server: a small synchronous Beast client (one keep-alive connection) and raw
// sockets for what no HTTP client sends. Loopback only; every read is bounded by a receive timeout.
#pragma once

#include <cstdint>
#include <map>
#include <string>

namespace svotest {

struct HttpReply {
  unsigned status = 0;
  std::map<std::string, std::string> headers;  // names in lower case
  std::string body;
  bool keepAlive = false;
  std::string header(const std::string& name) const {
    const auto it = headers.find(name);
    return it == headers.end() ? std::string() : it->second;
  }
};

// One connection to 127.0.0.1:port, kept alive between requests. Throws on any transport error.
class HttpClient {
 public:
  explicit HttpClient(std::uint16_t port);
  ~HttpClient();
  HttpClient(const HttpClient&) = delete;
  HttpClient& operator=(const HttpClient&) = delete;
  HttpReply request(const std::string& method, const std::string& target,
                    const std::map<std::string, std::string>& headers = {});
  HttpReply get(const std::string& target, const std::map<std::string, std::string>& headers = {}) {
    return request("GET", target, headers);
  }

 private:
  struct Impl;
  Impl* impl_;
};

// One request on a fresh connection.
HttpReply httpGet(std::uint16_t port, const std::string& target,
                  const std::map<std::string, std::string>& headers = {});

// A raw TCP connection to 127.0.0.1:port with a receive timeout of `timeoutSeconds`; a non-zero
// `receiveWindow` caps its receive buffer (bytes), so that a server cannot write much ahead of the reader.
int connectRaw(std::uint16_t port, int timeoutSeconds = 10, int receiveWindow = 0);
// Sends `bytes` (as much as the peer takes; false when it refused some), never raising SIGPIPE.
bool sendRaw(int fd, const std::string& bytes);
// Everything received until the peer closes, an error or the receive timeout.
std::string receiveAll(int fd);
// The status of the first response in `raw` ("HTTP/1.1 400 ..."), 0 when there is none.
unsigned statusOf(const std::string& raw);
// The status the server answers to `request` sent raw on a fresh connection, read to its end.
unsigned rawStatus(std::uint16_t port, const std::string& request);

}  // namespace svotest
