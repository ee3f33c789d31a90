#include "stream_session.hpp"

#include <algorithm>

#include <fmt/format.h>
#include <boost/asio/buffer.hpp>
#include <boost/asio/post.hpp>
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/websocket/error.hpp>

#include "svo/store/store_reader.hpp"

namespace svo::server {
namespace beast = boost::beast;
namespace net = boost::asio;
namespace websocket = beast::websocket;
namespace {

// The upgrade's answer and a close handshake must complete within this (Beast's suggested server value).
constexpr std::chrono::seconds kHandshakeTimeout{30};
// A client that sends nothing, not even the answer to a ping (sent after half of it), for this long is
// gone: its stream closes and its window's bytes are let go.
constexpr std::chrono::seconds kIdleTimeout{30};
constexpr const char* kStoppingReason = "the server is stopping";
// A WebSocket close reason holds at most 123 bytes (RFC 6455 sec. 5.5: control frames carry 125).
constexpr std::size_t kMaxCloseReasonBytes = 123;

}  // namespace

StreamSession::StreamSession(net::ip::tcp::socket&& socket, Context& context, Sessions& sessions,
                             std::shared_ptr<const Scene> scene, std::string peer, std::string target)
    : ws_(std::move(socket)),
      context_(context),
      sessions_(sessions),
      scene_(std::move(scene)),
      peer_(std::move(peer)),
      target_(std::move(target)),
      opened_(std::chrono::steady_clock::now()),
      sent_(scene_->index->slices().size(), false) {
  context_.metrics.connectionOpened();
  context_.metrics.streamOpened();
}

StreamSession::~StreamSession() {
  context_.metrics.streamClosed(written_);
  context_.metrics.connectionClosed();
  sessions_.remove(this);
  const auto elapsed = std::chrono::steady_clock::now() - opened_;
  const std::string summary = fmt::format("{} views, {} slices sent, {} superseded{}", views_, slicesSent_,
                                          superseded_, failure_.empty() ? "" : "; " + failure_);
  // The summary is the line's failure field only when the stream failed: a clean one logs at info level.
  context_.log.request({"GET", target_, peer_, 101, written_,
                        std::chrono::duration_cast<std::chrono::microseconds>(elapsed).count(),
                        failure_.empty() ? std::string_view() : std::string_view(summary)});
}

void StreamSession::start(Request request) {
  sessions_.add(shared_from_this());
  beast::get_lowest_layer(ws_).expires_never();  // the WebSocket's own timeouts take over
  // Small messages (plans, acknowledgements) go out at once, not held back for the peer's delayed ACK.
  beast::error_code ignored;
  beast::get_lowest_layer(ws_).socket().set_option(net::ip::tcp::no_delay(true), ignored);
  ws_.set_option(websocket::stream_base::timeout{kHandshakeTimeout, kIdleTimeout, /*keep_alive_pings=*/true});
  ws_.set_option(websocket::stream_base::decorator(
      [](websocket::response_type& res) { res.set(http::field::server, "svostream"); }));
  ws_.read_message_max(stream::maxClientMessageBytes(scene_->index->slices().size()));
  ws_.auto_fragment(false);  // one frame per slice: one gather write of its header and bytes
  handshaking_ = true;
  if (context_.stopping)  // stopAll may have missed it, added after it looked: it closes after the handshake
    closeNow(websocket::close_code::going_away, kStoppingReason);
  ws_.async_accept(request, [self = shared_from_this()](beast::error_code ec) {
    self->handshaking_ = false;
    if (ec) return self->end(ec);
    if (self->closeIfPending()) return;  // the server stopped during the handshake
    self->read();
  });
}

void StreamSession::stop() {
  net::post(ws_.get_executor(), [self = shared_from_this()] {
    self->closeNow(websocket::close_code::going_away, kStoppingReason);
  });
}

void StreamSession::read() {
  ws_.async_read(in_, [self = shared_from_this()](beast::error_code ec, std::size_t) { self->onRead(ec); });
}

void StreamSession::onRead(beast::error_code ec) {
  if (ec) return end(ec);
  if (!ws_.got_text()) {
    in_.consume(in_.size());
    return refuse(websocket::close_code::bad_payload, "a binary message: the view stream takes JSON text");
  }
  const std::string text = beast::buffers_to_string(in_.data());
  in_.consume(in_.size());
  take(text);
  if (!closing_ && !closed_) read();
}

void StreamSession::take(std::string_view text) {
  stream::ClientMessage message;
  try {
    message = stream::parseClientMessage(text, sent_.size());
  } catch (const stream::ProtocolError& e) {
    return refuse(websocket::close_code::policy_error, std::string("bad message: ") + e.what());
  }
  if (message.kind == stream::ClientMessage::Kind::Ack) {
    if (message.ackedBytes > sentBytes_)
      return refuse(websocket::close_code::policy_error,
                    fmt::format("bad message: ack of {} bytes, {} sent", message.ackedBytes, sentBytes_));
    ackedBytes_ = std::max(ackedBytes_, message.ackedBytes);
    return pump();
  }
  if (message.kind == stream::ClientMessage::Kind::Want) return prefer(message.wanted);
  if (haveView_ && message.view.id <= view_)
    return refuse(websocket::close_code::policy_error,
                  fmt::format("bad message: view {} after view {}", message.view.id, view_));
  follow(std::move(message.view));
}

void StreamSession::follow(stream::View view) {
  ++views_;
  context_.metrics.countViewUpdate();
  std::uint64_t dropped = 0;
  for (std::size_t k = next_; k < plan_.size(); ++k) dropped += !sent_[plan_[k]];
  superseded_ += dropped;
  context_.metrics.countSuperseded(dropped);
  for (const std::uint32_t id : view.held) sent_[id] = true;
  plan_.clear();
  for (const std::uint32_t id : stream::planSlices(*scene_->index, view.query, view.budgetBytes))
    if (!sent_[id]) plan_.push_back(id);
  next_ = 0;
  // The client's next requests go first, and before them the slices a fetch asked for before this plan
  // existed; those it leaves out are not sent.
  for (auto it = view.first.rbegin(); it != view.first.rend(); ++it) moveToFront(*it);
  for (auto it = wanted_.rbegin(); it != wanted_.rend(); ++it) moveToFront(*it);
  wanted_.clear();
  view_ = view.id;
  haveView_ = true;
  texts_.push_back(stream::encodePlan(view_, plan_));
  pump();
}

bool StreamSession::moveToFront(std::uint32_t slice) {
  const auto at = std::find(plan_.begin() + std::ptrdiff_t(next_), plan_.end(), slice);
  if (at == plan_.end()) return false;
  std::rotate(plan_.begin() + std::ptrdiff_t(next_), at, at + 1);
  return true;
}

void StreamSession::prefer(const std::vector<std::uint32_t>& slices) {
  // Last first, so that the first asked for ends up in front.
  for (auto it = slices.rbegin(); it != slices.rend(); ++it)
    if (!sent_[*it] && !moveToFront(*it) && std::find(wanted_.begin(), wanted_.end(), *it) == wanted_.end())
      wanted_.push_back(*it);
  pump();
}

void StreamSession::pump() {
  if (writing_ || closed_ || closing_) return;
  if (!texts_.empty()) {
    text_ = std::move(texts_.front());
    texts_.pop_front();
    writing_ = true;
    ws_.text(true);
    ws_.async_write(net::buffer(text_), [self = shared_from_this()](beast::error_code ec, std::size_t n) {
      self->written_ += n;
      self->onWrite(ec);
    });
    return;
  }
  writeNextSlice();
}

void StreamSession::writeNextSlice() {
  while (next_ < plan_.size() && sentBytes_ - ackedBytes_ < context_.options.streamWindowBytes) {
    const std::uint32_t id = plan_[next_++];
    sent_[id] = true;
    try {
      slice_ = cachedSlice(context_, *scene_, id);
    } catch (const SliceError& e) {
      context_.log.error(fmt::format("{} {}: {}", peer_, target_, e.what()));
      texts_.push_back(stream::encodeSliceError(view_, id, publicMessage(e.what(), *scene_)));
      return pump();
    }
    stream::writeSliceFrameHeader({id, view_}, frameHeader_);
    sentBytes_ += frameHeader_.size() + slice_->size();
    writing_ = true;
    ws_.binary(true);
    const std::array<net::const_buffer, 2> frame{net::buffer(frameHeader_),
                                                 net::buffer(slice_->data(), slice_->size())};
    ws_.async_write(frame, [self = shared_from_this()](beast::error_code ec, std::size_t n) {
      self->written_ += n;
      if (!ec) {
        ++self->slicesSent_;
        self->context_.metrics.countStreamSliceSent();
      }
      self->slice_.reset();
      self->onWrite(ec);
    });
    return;
  }
}

void StreamSession::onWrite(beast::error_code ec) {
  writing_ = false;
  if (ec) return end(ec);
  if (!closeIfPending()) pump();
}

bool StreamSession::closeIfPending() {
  if (!closing_) return false;
  closing_ = false;
  closeNow(websocket::close_code(pendingClose_.code),
           std::string(pendingClose_.reason.data(), pendingClose_.reason.size()));
  return true;
}

void StreamSession::refuse(websocket::close_code code, const std::string& why) {
  failure_ = why;
  closeNow(code, why);
}

void StreamSession::closeNow(websocket::close_code code, std::string reason) {
  if (closed_) return;
  if (reason.size() > kMaxCloseReasonBytes) reason.resize(kMaxCloseReasonBytes);
  if (writing_ || handshaking_) {  // after it: a frame is never cut, nor the handshake
    closing_ = true;
    pendingClose_ = websocket::close_reason(code, reason);
    return;
  }
  closed_ = true;
  ws_.async_close(websocket::close_reason(code, reason),
                  [self = shared_from_this()](beast::error_code ec) { self->end(ec); });
}

void StreamSession::end(beast::error_code ec) {
  closed_ = true;
  const bool clean = !ec || ec == websocket::error::closed || ec == net::error::operation_aborted;
  if (!clean && failure_.empty()) failure_ = "cut: " + ec.message();
}

}  // namespace svo::server
