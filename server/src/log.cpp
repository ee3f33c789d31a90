#include "log.hpp"

#include <mutex>
#include <string>

#include <fmt/format.h>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>
#include <nlohmann/json.hpp>

namespace svo::server {
namespace {

// Hands each formatted line (without its end of line) to a function: tests read the log this way.
class FunctionSink final : public spdlog::sinks::base_sink<std::mutex> {
 public:
  explicit FunctionSink(std::function<void(std::string_view)> f) : f_(std::move(f)) {}

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    spdlog::memory_buf_t line;
    formatter_->format(msg, line);
    std::string_view text(line.data(), line.size());
    while (!text.empty() && (text.back() == '\n' || text.back() == '\r')) text.remove_suffix(1);
    f_(text);
  }
  void flush_() override {}

 private:
  std::function<void(std::string_view)> f_;
};

// JSON lines: the pattern writes the time and level, the message the remaining members (",\"k\":v...").
constexpr const char* kJsonPattern = R"({"time":"%Y-%m-%dT%H:%M:%S.%fZ","level":"%l"%v})";
constexpr const char* kTextPattern = "%Y-%m-%d %H:%M:%S.%e %l %v";

// An object's members as the JSON pattern's %v wants them: a leading comma, no braces.
std::string members(const nlohmann::json& object) {
  std::string text = object.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  text.front() = ',';
  text.pop_back();
  return text;
}

}  // namespace

Log::Log(LogFormat format, bool requests, std::function<void(std::string_view)> sink)
    : format_(format), requests_(requests) {
  spdlog::sink_ptr s;
  if (sink)
    s = std::make_shared<FunctionSink>(std::move(sink));
  else
    s = std::make_shared<spdlog::sinks::stderr_sink_mt>();
  // Not registered with spdlog: several servers (tests) each keep their own.
  logger_ = std::make_shared<spdlog::logger>("svo-serve", std::move(s));
  if (format_ == LogFormat::Json)
    logger_->set_pattern(kJsonPattern, spdlog::pattern_time_type::utc);
  else
    logger_->set_pattern(kTextPattern);
  logger_->flush_on(spdlog::level::info);
}

Log::~Log() = default;

void Log::request(const RequestRecord& r) {
  const bool failed = !r.failure.empty();
  if (!failed && !requests_) return;
  const spdlog::level::level_enum level = failed ? spdlog::level::err : spdlog::level::info;
  if (format_ == LogFormat::Json) {
    nlohmann::json j = {{"method", r.method}, {"target", r.target},   {"status", r.status},
                        {"bytes", r.bytes},   {"us", r.microseconds}, {"peer", r.peer}};
    if (failed) j["failure"] = r.failure;
    logger_->log(level, "{}", members(j));
    return;
  }
  logger_->log(level, "{} {} {} {}B {}us {}{}{}", r.method, r.target, r.status, r.bytes, r.microseconds,
               r.peer, failed ? ": " : "", r.failure);
}

void Log::info(std::string_view what) {
  message(false, what);
}
void Log::error(std::string_view what) {
  message(true, what);
}

void Log::message(bool isError, std::string_view what) {
  const spdlog::level::level_enum level = isError ? spdlog::level::err : spdlog::level::info;
  if (format_ == LogFormat::Json)
    logger_->log(level, "{}", members({{"message", what}}));
  else
    logger_->log(level, "{}", what);
}

}  // namespace svo::server
