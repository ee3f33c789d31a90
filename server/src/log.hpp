// The server's log: one line per request and per failure, as text or as one JSON object per line.
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <string_view>

#include "svo/server/server.hpp"

namespace spdlog {
class logger;
}

namespace svo::server {

struct RequestRecord {
  std::string_view method, target, peer;
  unsigned status = 0;
  std::uint64_t bytes = 0;  // written, head and body
  std::int64_t microseconds = 0;
  std::string_view failure;  // what went wrong (a refusal, a corrupt slice, a client gone), or empty
};

class Log {
 public:
  // Lines go to `sink` when given, else to stderr. `requests` false leaves out the lines of requests that
  // went well; a request's failure is always one line, at error level.
  Log(LogFormat format, bool requests, std::function<void(std::string_view)> sink);
  ~Log();
  void request(const RequestRecord& r);
  void info(std::string_view what);
  void error(std::string_view what);

 private:
  void message(bool isError, std::string_view what);
  LogFormat format_;
  bool requests_;
  std::shared_ptr<spdlog::logger> logger_;
};

}  // namespace svo::server
