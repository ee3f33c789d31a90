#include "session.hpp"

#include "stream_session.hpp"

#include <vector>

#include <fmt/format.h>
#include <boost/asio/dispatch.hpp>
#include <boost/asio/post.hpp>
#include <boost/beast/core/bind_handler.hpp>
#include <boost/beast/http/error.hpp>
#include <boost/beast/http/read.hpp>
#include <boost/beast/http/write.hpp>

namespace svo::server {
namespace beast = boost::beast;
namespace net = boost::asio;
namespace {

// A request's head: Beast's default is 8 KiB; long scene paths and tokens fit in twice that.
constexpr std::uint32_t kMaxHeaderBytes = 16 * 1024;
// A request's body: the routes read none, so anything beyond a small one is refused (413).
constexpr std::uint64_t kMaxBodyBytes = 64 * 1024;
// A client that takes no byte of a response for this long is gone (per write, not per response, so a
// whole store still reaches a slow reader).
constexpr std::chrono::seconds kWriteIdleTimeout{30};
// After refusing a request it did not read whole, the server reads and drops what the client still sends,
// for at most this long and this many bytes, so that closing with unread bytes (a TCP reset) does not
// destroy the refusal before the client reads it (nginx's lingering close does the same).
constexpr std::chrono::seconds kLingerTimeout{2};
constexpr std::uint64_t kLingerBytes = 1 << 20;
constexpr std::size_t kLingerReadBytes = 16 * 1024;  // dropped per read while lingering

std::string peerOf(const net::ip::tcp::socket& socket) {
  beast::error_code ec;
  const auto endpoint = socket.remote_endpoint(ec);
  return ec ? std::string("?") : fmt::format("{}:{}", endpoint.address().to_string(), endpoint.port());
}

bool clientGone(const beast::error_code& ec) {
  return ec == net::error::eof || ec == net::error::connection_reset || ec == net::error::broken_pipe ||
         ec == net::error::operation_aborted || ec == net::error::bad_descriptor ||
         ec == http::error::partial_message;
}

}  // namespace

void Sessions::add(const std::shared_ptr<Connection>& connection) {
  std::lock_guard lock(mutex_);
  live_.emplace(connection.get(), connection);
}

void Sessions::remove(Connection* connection) {
  std::lock_guard lock(mutex_);
  live_.erase(connection);
  if (live_.empty()) none_.notify_all();
}

void Sessions::stopAll() {
  std::vector<std::shared_ptr<Connection>> live;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [raw, weak] : live_)
      if (std::shared_ptr<Connection> c = weak.lock()) live.push_back(std::move(c));
  }
  // Outside the lock: a connection whose last owner is `live` removes itself when it goes.
  for (const std::shared_ptr<Connection>& c : live) c->stop();
}

bool Sessions::waitUntilNone(std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  return none_.wait_for(lock, timeout, [&] { return live_.empty(); });
}

Session::Session(net::ip::tcp::socket&& socket, Context& context, Sessions& sessions)
    : stream_(std::move(socket)),
      context_(context),
      sessions_(sessions),
      peer_(peerOf(stream_.socket())),
      buffer_(kMaxHeaderBytes + kMaxBodyBytes) {  // pipelined requests' bytes stay in it between reads
  context_.metrics.connectionOpened();
}

Session::~Session() {
  context_.metrics.connectionClosed();
  sessions_.remove(this);
}

void Session::start() {
  sessions_.add(shared_from_this());
  net::dispatch(stream_.get_executor(), beast::bind_front_handler(&Session::read, shared_from_this()));
}

void Session::stop() {
  net::post(stream_.get_executor(), [self = shared_from_this()] {
    self->closeAfterWrite_ = true;
    if (self->reading_) self->stream_.cancel();  // onRead sees operation_aborted and closes
  });
}

void Session::read() {
  if (context_.stopping) return close();
  parser_.emplace();
  parser_->header_limit(kMaxHeaderBytes);
  parser_->body_limit(kMaxBodyBytes);
  stream_.expires_after(context_.options.requestReadTimeout);
  reading_ = true;
  http::async_read(stream_, buffer_, *parser_,
                   [self = shared_from_this()](beast::error_code ec, std::size_t) { self->onRead(ec); });
}

void Session::onRead(beast::error_code ec) {
  reading_ = false;
  if (ec == http::error::end_of_stream) return close();  // the client closed between requests
  if (ec) return refuse(ec);
  const Request& request = parser_->get();
  method_ = std::string(request.method_string());
  target_ = std::string(request.target());
  answered_ = std::chrono::steady_clock::now();
  Answer answer = handle(request, context_);
  if (answer.stream) return upgrade(std::move(answer));
  send(std::move(answer));
}

void Session::upgrade(Answer answer) {
  if (context_.stopping) return send(svo::server::refuse(http::status::service_unavailable, "stopping"));
  auto stream = std::make_shared<StreamSession>(stream_.release_socket(), context_, sessions_,
                                                std::move(answer.stream), peer_, target_);
  stream->start(parser_->release());
}

void Session::refuse(beast::error_code ec) {
  if (ec == beast::error::timeout && !parser_->got_some()) return close();  // an idle keep-alive connection
  if (ec == beast::error::timeout) {
    context_.log.error(fmt::format("{}: no complete request within {} ms: connection closed", peer_,
                                   context_.options.requestReadTimeout.count()));
    return close();
  }
  if (clientGone(ec)) return close();
  http::status status = http::status::bad_request;
  if (ec == http::error::header_limit || ec == http::error::buffer_overflow)
    status = http::status::request_header_fields_too_large;
  else if (ec == http::error::body_limit)
    status = http::status::payload_too_large;
  method_.clear();
  target_.clear();
  if (parser_->is_header_done()) target_ = parser_->get().target();
  answered_ = std::chrono::steady_clock::now();
  closeAfterWrite_ = true;
  lingerAfterWrite_ = true;
  send(svo::server::refuse(status, ec.message()));
}

void Session::send(Answer answer) {
  answer_ = std::move(answer);
  if (context_.stopping) closeAfterWrite_ = true;
  if (closeAfterWrite_ || !answer_.response.keep_alive()) {
    closeAfterWrite_ = true;
    answer_.response.keep_alive(false);
  }
  serializer_.emplace(answer_.response);
  written_ = 0;
  writeSome();
}

void Session::writeSome() {
  stream_.expires_after(kWriteIdleTimeout);
  http::async_write_some(stream_, *serializer_,
                         beast::bind_front_handler(&Session::onWrite, shared_from_this()));
}

void Session::onWrite(beast::error_code ec, std::size_t bytes) {
  written_ += bytes;
  if (!ec && !serializer_->is_done()) return writeSome();
  account(ec);
  serializer_.reset();
  answer_ = {};  // lets go of a cached slice
  if (!ec && lingerAfterWrite_) return linger();
  if (ec || closeAfterWrite_) return close();
  read();
}

void Session::linger() {
  if (lingered_ == 0) {
    beast::error_code ignored;
    stream_.socket().shutdown(net::ip::tcp::socket::shutdown_send, ignored);
    stream_.expires_after(kLingerTimeout);
    buffer_.clear();
  }
  const std::size_t room = std::min<std::size_t>(buffer_.max_size(), kLingerReadBytes);
  stream_.async_read_some(buffer_.prepare(room),
                          [self = shared_from_this()](beast::error_code ec, std::size_t n) {
                            self->lingered_ += n + 1;  // counts reads too, so that it ends even on empty ones
                            if (ec || self->lingered_ >= kLingerBytes) return self->stream_.close();
                            self->linger();
                          });
}

void Session::account(beast::error_code ec) {
  const unsigned status = answer_.response.result_int();
  const auto elapsed = std::chrono::steady_clock::now() - answered_;
  context_.metrics.countRequest(answer_.route, status, std::chrono::duration<double>(elapsed).count(),
                                written_);
  if (!ec && answer_.slice && method_ == "GET" && (status == 200 || status == 206))
    context_.metrics.countSliceSent();
  // A refused request may have no method or target to name.
  const std::string_view method = method_.empty() ? std::string_view("-") : std::string_view(method_);
  const std::string_view target = target_.empty() ? std::string_view("-") : std::string_view(target_);
  std::string failure = answer_.failure;
  if (ec) failure += (failure.empty() ? "cut: " : "; cut: ") + ec.message();
  context_.log.request({method, target, peer_, status, written_,
                        std::chrono::duration_cast<std::chrono::microseconds>(elapsed).count(), failure});
}

void Session::close() {
  beast::error_code ec;
  stream_.socket().shutdown(net::ip::tcp::socket::shutdown_send, ec);
  stream_.close();
}

}  // namespace svo::server
