// One client's view stream (svo/store/view_stream.hpp for the messages): a WebSocket over the connection an
// upgrade request came on. Each view the client sends replaces the plan (planSlices: the shared scheduler,
// within the client's budget, less what this connection already sent or the client holds); the session writes
// the plan's slices one message at a time, most valuable first, while the bytes the client has not
// acknowledged stay within the stream window. Slices a client's fetch waits for go before the rest of the
// plan. Everything runs on the connection's one I/O thread.
#pragma once

#include <array>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <vector>

#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/websocket/stream.hpp>

#include "handler.hpp"
#include "session.hpp"
#include "svo/store/view_stream.hpp"

namespace svo::server {

class StreamSession final : public Connection, public std::enable_shared_from_this<StreamSession> {
 public:
  StreamSession(boost::asio::ip::tcp::socket&& socket, Context& context, Sessions& sessions,
                std::shared_ptr<const Scene> scene, std::string peer, std::string target);
  ~StreamSession() override;
  StreamSession(const StreamSession&) = delete;
  StreamSession& operator=(const StreamSession&) = delete;
  // Answers the upgrade `request` (101) and starts reading views.
  void start(Request request);
  // Closes the stream (going away) after the message being written.
  void stop() override;

 private:
  void read();
  void onRead(boost::beast::error_code ec);
  // A client message, or a close with `code` and one line saying why.
  void take(std::string_view text);
  void follow(stream::View view);
  // Moves `slices` to the front of what is left of the plan (those in no plan yet wait for the next one).
  void prefer(const std::vector<std::uint32_t>& slices);
  // Moves `slice` to the front of what is left of the plan; false when it is not there.
  bool moveToFront(std::uint32_t slice);
  // Starts the next write (a text message first, then the plan's next slice within the window) unless one
  // is in flight.
  void pump();
  void writeNextSlice();
  void onWrite(boost::beast::error_code ec);
  void refuse(boost::beast::websocket::close_code code, const std::string& why);
  // Closes with `code` and `reason`, or once the handshake or the message being written is out.
  void closeNow(boost::beast::websocket::close_code code, std::string reason);
  // Starts the close that closeNow put off, if it did; true if so.
  bool closeIfPending();
  void end(boost::beast::error_code ec);

  boost::beast::websocket::stream<boost::beast::tcp_stream> ws_;
  Context& context_;
  Sessions& sessions_;
  std::shared_ptr<const Scene> scene_;
  std::string peer_, target_;
  std::chrono::steady_clock::time_point opened_;
  boost::beast::flat_buffer in_;

  std::uint64_t view_ = 0;  // the plan's view id
  bool haveView_ = false;
  std::vector<std::uint32_t> plan_;
  std::size_t next_ = 0;               // plan_'s next slice to write
  std::vector<bool> sent_;             // by slice: written on this connection, or held by the client
  std::vector<std::uint32_t> wanted_;  // asked for first but in no plan yet: first in the next one
  std::deque<std::string> texts_;
  std::uint64_t sentBytes_ = 0, ackedBytes_ = 0;  // slice frames' bytes, as the client acknowledges them

  // The message being written, kept alive until its write completes.
  std::string text_;
  std::array<std::byte, stream::kSliceFrameHeaderBytes> frameHeader_{};
  std::shared_ptr<const SliceBytes> slice_;
  bool writing_ = false;
  // The upgrade's answer is being written; Beast allows no other operation on the stream meanwhile.
  bool handshaking_ = false;
  bool closing_ = false;  // close once the handshake or the message being written is out, with pendingClose_
  bool closed_ = false;   // the close handshake started or the connection failed: nothing more is written
  boost::beast::websocket::close_reason pendingClose_;

  std::uint64_t written_ = 0, views_ = 0, slicesSent_ = 0, superseded_ = 0;
  std::string failure_;  // why the stream ended badly, for its log line
};

}  // namespace svo::server
