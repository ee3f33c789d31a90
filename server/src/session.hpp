// One client connection: reads requests with Beast under a deadline and writes each answer before reading
// the next (HTTP/1.1 keep-alive), all on the one thread that runs the connection's I/O context.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <unordered_map>

#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/http/parser.hpp>
#include <boost/beast/http/serializer.hpp>

#include "handler.hpp"

namespace svo::server {

// An open connection as the server's registry sees it.
class Connection {
 public:
  virtual ~Connection() = default;
  // Asks the connection to end: now when idle, else at the end of what it is writing. Any thread.
  virtual void stop() = 0;
};

// The open connections, so that a stopping server can close the idle ones and wait for the others.
class Sessions {
 public:
  void add(const std::shared_ptr<Connection>& connection);
  void remove(Connection* connection);
  // Asks every connection to stop: idle ones close now, the others after the response in flight.
  void stopAll();
  // Waits until every connection has closed or `timeout` has passed; true when all closed.
  bool waitUntilNone(std::chrono::milliseconds timeout);

 private:
  std::mutex mutex_;
  std::condition_variable none_;
  std::unordered_map<Connection*, std::weak_ptr<Connection>> live_;
};

// An HTTP connection; a request to a view stream hands its socket on to a StreamSession.
class Session final : public Connection, public std::enable_shared_from_this<Session> {
 public:
  Session(boost::asio::ip::tcp::socket&& socket, Context& context, Sessions& sessions);
  ~Session();
  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;
  void start();
  void stop() override;

 private:
  void read();
  void onRead(boost::beast::error_code ec);
  void refuse(boost::beast::error_code ec);
  void send(Answer answer);
  void upgrade(Answer answer);
  void writeSome();
  void onWrite(boost::beast::error_code ec, std::size_t bytes);
  void account(boost::beast::error_code ec);
  void linger();
  void close();

  boost::beast::tcp_stream stream_;
  Context& context_;
  Sessions& sessions_;
  std::string peer_;
  boost::beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  Answer answer_;
  std::optional<http::response_serializer<PayloadBody>> serializer_;
  std::string method_, target_;  // of the request being answered, for the log
  std::chrono::steady_clock::time_point answered_;
  std::uint64_t written_ = 0;
  bool reading_ = false;
  bool closeAfterWrite_ = false;
  bool lingerAfterWrite_ = false;  // a refused request: the client may still be sending it
  std::uint64_t lingered_ = 0;
};

}  // namespace svo::server
