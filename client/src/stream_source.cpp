#include "svo/client/stream_source.hpp"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <mutex>
#include <optional>
#include <thread>
#include <unordered_map>

#include <curl/curl.h>
#include <boost/asio/executor_work_guard.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/beast/core/buffers_to_string.hpp>
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/core/tcp_stream.hpp>
#include <boost/beast/websocket/stream.hpp>

#include "svo/store/store_reader.hpp"
#include "svo/store/view_stream.hpp"

namespace svo {
namespace beast = boost::beast;
namespace net = boost::asio;
namespace websocket = beast::websocket;
using tcp = net::ip::tcp;
using Clock = std::chrono::steady_clock;
namespace {

// Views closer together than this go out as one, the latest: a camera moving at 60 frames a second sends
// every third, and the server replans 20 times a second at most.
constexpr std::chrono::milliseconds kMinViewInterval{50};
// The stream's own timeouts: the upgrade, and a server that sends nothing, not even a ping's answer (pings
// go out after half of it), for this long is gone.
constexpr std::chrono::seconds kHandshakeTimeout{30};
constexpr std::chrono::seconds kIdleTimeout{30};
// A slice pushed and not yet fetched waits in memory up to this much beyond the pool's budget; past it,
// the oldest go (and are read by range if the pager still wants them).
constexpr std::size_t kMinReceivedBytes = std::size_t(16) << 20;

// Where the stream of the store at `url` lives: the same host and port, path /NAME/stream.
struct Endpoint {
  std::string host, port, target;
  bool usable = false;  // plain http: (a stream over TLS goes through a TLS-terminating proxy's range path)
};

Endpoint streamEndpoint(const std::string& url) {
  Endpoint e;
  const std::unique_ptr<CURLU, void (*)(CURLU*)> parsed(curl_url(), curl_url_cleanup);
  if (curl_url_set(parsed.get(), CURLUPART_URL, url.c_str(), 0) != CURLUE_OK) return e;
  const auto part = [&](CURLUPart which, unsigned flags = 0) {
    char* text = nullptr;
    std::string out;
    if (curl_url_get(parsed.get(), which, &text, flags) == CURLUE_OK && text) out = text;
    curl_free(text);
    return out;
  };
  e.usable = part(CURLUPART_SCHEME) == "http";
  e.host = part(CURLUPART_HOST);
  e.port = part(CURLUPART_PORT, CURLU_DEFAULT_PORT);
  std::string path = part(CURLUPART_PATH);
  if (path.ends_with(".svo")) path.resize(path.size() - 4);
  while (path.ends_with('/')) path.pop_back();
  e.target = path + "/stream";
  return e;
}

}  // namespace

struct ViewStreamSource::Impl {
  Impl(std::shared_ptr<const ByteSource> bytes, const std::string& url, const RemoteOptions& options);
  ~Impl();

  // On the I/O thread.
  void connect();
  void onConnected();
  void read();
  void onRead(beast::error_code ec);
  void takeSlice();
  void takeText(const std::string& text);
  void send(std::string text);
  void writeNext();
  void sendView();
  void lost(const std::string& why);
  void retryLater();

  // Under mutex: whether `slice` may be on its way: in the latest plan, or a newer view's plan is.
  bool coming(std::uint32_t slice) const;
  // Under mutex: the pushed slice `slice`, waiting while it is coming; false when it must be read by range.
  bool takePushed(std::unique_lock<std::mutex>& lock, std::uint32_t slice, SliceBytes& compressed);

  StoreSliceSource pull;
  RemoteOptions options;
  Endpoint endpoint;
  std::size_t sliceCount = 0;
  std::size_t maxMessageBytes = 0;

  net::io_context io{1};
  net::executor_work_guard<net::io_context::executor_type> work{io.get_executor()};
  tcp::resolver resolver{io};
  std::optional<websocket::stream<beast::tcp_stream>> ws;
  beast::flat_buffer in;
  websocket::response_type upgradeAnswer;
  net::steady_timer retryTimer{io}, viewTimer{io}, closeTimer{io};
  std::deque<std::string> out;
  bool writing = false;
  std::uint64_t generation = 0;  // of the connection: a handler of an earlier one does nothing
  double backoffSeconds = 0.0;
  std::uint64_t frameBytes = 0;  // slice frames received on this connection (what the acks count)
  Clock::time_point lastViewSent{};
  bool heldPending = false;  // the next view tells the server what this client has

  mutable std::mutex mutex;
  mutable std::condition_variable changed;
  bool connected = false, declined = false, stopping = false;
  std::unordered_map<std::uint32_t, SliceBytes> received;
  std::deque<std::uint32_t> receivedOrder;
  std::size_t receivedBytes = 0;
  std::vector<bool> delivered;  // handed to the pager (held, as far as the server need know)
  std::vector<bool> expected;   // in the plan of the latest view sent, not received
  std::vector<std::uint32_t> expectedList;
  std::uint64_t nextViewId = 1, viewSent = 0, planView = 0;
  std::optional<std::pair<ViewQuery, std::size_t>> latestView;
  std::vector<std::uint32_t> latestFirst;  // the pager's next requests when it gave latestView
  std::string latestKey;
  bool viewDirty = false;
  StreamStats stats;
  std::thread thread;
};

ViewStreamSource::Impl::Impl(std::shared_ptr<const ByteSource> bytes, const std::string& url,
                             const RemoteOptions& o)
    : pull(std::move(bytes)), options(o), endpoint(streamEndpoint(url)) {
  sliceCount = pull.index().slices().size();
  // The largest message a server of this store sends: a slice frame, or a plan naming every slice.
  for (const SliceInfo& s : pull.index().slices())
    maxMessageBytes = std::max<std::size_t>(maxMessageBytes, stream::kSliceFrameHeaderBytes + s.compressedBytes);
  maxMessageBytes = std::max(maxMessageBytes, stream::maxClientMessageBytes(sliceCount));
  delivered.assign(sliceCount, false);
  expected.assign(sliceCount, false);
  if (!endpoint.usable) {
    declined = stats.declined = true;
    return;
  }
  net::post(io, [this] { connect(); });
  thread = std::thread([this] { io.run(); });
}

ViewStreamSource::Impl::~Impl() {
  {
    std::lock_guard lock(mutex);
    stopping = true;
  }
  changed.notify_all();
  if (!thread.joinable()) return;
  net::post(io, [this] {
    retryTimer.cancel();
    viewTimer.cancel();
    resolver.cancel();
    if (!ws || !connected) return io.stop();
    // A clean close, bounded: the server may be gone. Stopping the context drops what is still pending
    // (Beast's own timers among it).
    closeTimer.expires_after(std::chrono::seconds(1));
    closeTimer.async_wait([this](beast::error_code) { io.stop(); });
    ws->async_close(websocket::close_code::normal, [this](beast::error_code) { io.stop(); });
  });
  work.reset();
  thread.join();
}

void ViewStreamSource::Impl::connect() {
  if (stopping) return;
  const std::uint64_t gen = ++generation;
  ws.emplace(io);
  upgradeAnswer = {};
  in.clear();
  out.clear();
  writing = false;
  frameBytes = 0;
  resolver.async_resolve(
      endpoint.host, endpoint.port, [this, gen](beast::error_code ec, tcp::resolver::results_type r) {
        if (gen != generation) return;
        if (ec) return lost("resolving " + endpoint.host + ": " + ec.message());
        beast::get_lowest_layer(*ws).expires_after(
            std::chrono::milliseconds(std::int64_t(options.connectTimeoutSeconds * 1000)));
        beast::get_lowest_layer(*ws).async_connect(
            r, [this, gen](beast::error_code ec2, const tcp::endpoint&) {
              if (gen != generation) return;
              if (ec2) return lost("connecting: " + ec2.message());
              beast::get_lowest_layer(*ws).expires_never();
      // Acknowledgements and views are small: out at once, not held back for the server's delayed ACK.
      beast::error_code ignored;
      beast::get_lowest_layer(*ws).socket().set_option(tcp::no_delay(true), ignored);
              ws->set_option(websocket::stream_base::timeout{kHandshakeTimeout, kIdleTimeout, true});
              ws->set_option(
                  websocket::stream_base::decorator([token = options.token](websocket::request_type& req) {
                    if (!token.empty()) req.set(beast::http::field::authorization, "Bearer " + token);
                  }));
              ws->read_message_max(maxMessageBytes);
              ws->async_handshake(upgradeAnswer, endpoint.host + ":" + endpoint.port, endpoint.target,
                                  [this, gen](beast::error_code ec3) {
                                    if (gen != generation) return;
                                    if (ec3 == websocket::error::upgrade_declined) {
                                      // Not a svo serve (a static server answers 404): range requests only.
                                      beast::get_lowest_layer(*ws).close();
                                      std::lock_guard lock(mutex);
                                      declined = stats.declined = true;
                                      changed.notify_all();
                                      return;
                                    }
                                    if (ec3) return lost("upgrading to the view stream: " + ec3.message());
                                    onConnected();
                                  });
            });
      });
}

void ViewStreamSource::Impl::onConnected() {
  {
    std::lock_guard lock(mutex);
    connected = true;
    ++stats.connections;
    viewDirty = latestView.has_value();
  }
  backoffSeconds = 0.0;
  heldPending = true;
  read();
  sendView();
}

void ViewStreamSource::Impl::read() {
  ws->async_read(in, [this, gen = generation](beast::error_code ec, std::size_t) {
    if (gen == generation) onRead(ec);
  });
}

void ViewStreamSource::Impl::onRead(beast::error_code ec) {
  if (ec) return lost("the view stream ended: " + ec.message());
  try {
    if (ws->got_binary())
      takeSlice();
    else
      takeText(beast::buffers_to_string(in.data()));
  } catch (const stream::ProtocolError& e) {
    // A server that breaks the format is not streamed from again: range requests only.
    {
      std::lock_guard lock(mutex);
      declined = stats.declined = true;
    }
    ws->async_close(websocket::close_code::protocol_error, [](beast::error_code) {});
    return lost(std::string("the server's view stream is malformed: ") + e.what());
  }
  in.consume(in.size());
  read();
}

void ViewStreamSource::Impl::takeSlice() {
  const auto* data = static_cast<const std::byte*>(in.data().data());
  const std::span<const std::byte> frame(data, in.size());
  const stream::SliceFrameHeader head = stream::readSliceFrameHeader(frame);
  if (head.slice >= sliceCount) throw stream::ProtocolError("a slice frame for no slice of the store");
  const std::size_t bytes = frame.size() - stream::kSliceFrameHeaderBytes;
  if (bytes != pull.index().slices()[head.slice].compressedBytes)
    throw stream::ProtocolError("a slice frame whose size is not the directory's");
  frameBytes += frame.size();
  {
    std::lock_guard lock(mutex);
    ++stats.pushed;
    stats.pushedBytes += frame.size();
    expected[head.slice] = false;
    if (!delivered[head.slice] && !received.contains(head.slice)) {
      SliceBytes& slice = received[head.slice];
      slice.assign(frame.begin() + stream::kSliceFrameHeaderBytes, frame.end());
      receivedOrder.push_back(head.slice);
      receivedBytes += bytes;
      const std::size_t cap = kMinReceivedBytes + (latestView ? latestView->second : 0);
      while (receivedBytes > cap && !receivedOrder.empty()) {
        const auto it = received.find(receivedOrder.front());
        receivedOrder.pop_front();
        if (it == received.end()) continue;
        receivedBytes -= it->second.size();
        received.erase(it);
      }
    }
  }
  changed.notify_all();
  send(stream::encodeAck(frameBytes));
}

void ViewStreamSource::Impl::takeText(const std::string& text) {
  const stream::ServerMessage m = stream::parseServerMessage(text, sliceCount);
  {
    std::lock_guard lock(mutex);
    if (m.kind == stream::ServerMessage::Kind::SliceError) {
      expected[m.slice] = false;  // its fetch reads it by range and meets the error itself
    } else if (m.view == viewSent) {
      for (const std::uint32_t s : expectedList) expected[s] = false;
      expectedList.clear();
      for (const std::uint32_t s : m.plan)
        if (!received.contains(s) && !delivered[s]) expected[s] = true, expectedList.push_back(s);
      planView = m.view;
    }
  }
  changed.notify_all();
}

void ViewStreamSource::Impl::send(std::string text) {
  out.push_back(std::move(text));
  if (!writing) writeNext();
}

void ViewStreamSource::Impl::writeNext() {
  if (out.empty() || !ws) {
    writing = false;
    return;
  }
  writing = true;
  ws->text(true);
  ws->async_write(net::buffer(out.front()), [this, gen = generation](beast::error_code ec, std::size_t) {
    if (gen != generation) return;
    writing = false;
    if (ec) return;  // the read fails too, and that reconnects
    out.pop_front();
    writeNext();
  });
}

void ViewStreamSource::Impl::sendView() {
  stream::View view;
  {
    std::lock_guard lock(mutex);
    if (!connected || !viewDirty || !latestView) return;
    const auto wait = lastViewSent + kMinViewInterval - Clock::now();
    if (!heldPending && wait > Clock::duration::zero()) {
      viewTimer.expires_after(wait);
      viewTimer.async_wait([this](beast::error_code ec) {
        if (!ec) sendView();
      });
      return;
    }
    view.id = nextViewId++;
    view.query = latestView->first;
    view.budgetBytes = std::max<std::uint64_t>(1, latestView->second);
    for (const std::uint32_t s : latestFirst)
      if (!delivered[s] && !received.contains(s)) view.first.push_back(s);
    if (heldPending) {
      for (std::uint32_t s = 0; s < sliceCount; ++s)
        if (delivered[s] || received.contains(s)) view.held.push_back(s);
      heldPending = false;
    }
    viewSent = view.id;
    viewDirty = false;
    ++stats.viewsSent;
  }
  lastViewSent = Clock::now();
  send(stream::encodeView(view));
}

void ViewStreamSource::Impl::lost(const std::string& why) {
  {
    std::lock_guard lock(mutex);
    stats.lastError = why;
    connected = false;
    for (const std::uint32_t s : expectedList) expected[s] = false;
    expectedList.clear();
    planView = viewSent;
  }
  changed.notify_all();
  retryLater();
}

void ViewStreamSource::Impl::retryLater() {
  {
    std::lock_guard lock(mutex);
    if (stopping || declined) return;
  }
  backoffSeconds = backoffSeconds == 0.0 ? options.backoffBaseSeconds
                                         : std::min(2.0 * backoffSeconds, options.backoffMaxSeconds);
  retryTimer.expires_after(std::chrono::microseconds(std::int64_t(backoffSeconds * 1e6)));
  retryTimer.async_wait([this](beast::error_code ec) {
    if (!ec) connect();
  });
}

bool ViewStreamSource::Impl::coming(std::uint32_t slice) const {
  return connected && !stopping && (viewDirty || planView < viewSent || expected[slice]);
}

bool ViewStreamSource::Impl::takePushed(std::unique_lock<std::mutex>& lock, std::uint32_t slice,
                                        SliceBytes& compressed) {
  const auto deadline = Clock::now() + std::chrono::duration_cast<Clock::duration>(
                                           std::chrono::duration<double>(kPushWaitSeconds));
  bool asked = false;
  while (true) {
    if (const auto it = received.find(slice); it != received.end()) {
      compressed = std::move(it->second);
      receivedBytes -= compressed.size();
      received.erase(it);
      ++stats.usedPushed;
      delivered[slice] = true;
      return true;
    }
    if (!coming(slice)) return false;
    if (!asked) {  // the pager wants it now: the server sends it next
      net::post(io, [this, slice] {
        if (connected) send(stream::encodeWant(std::span(&slice, 1)));
      });
      asked = true;
    }
    if (changed.wait_until(lock, deadline) == std::cv_status::timeout) return false;
  }
}

ViewStreamSource::ViewStreamSource(std::shared_ptr<const ByteSource> bytes, const std::string& url,
                                   const RemoteOptions& options)
    : impl_(std::make_unique<Impl>(std::move(bytes), url, options)) {}

ViewStreamSource::~ViewStreamSource() = default;

const StoreIndex& ViewStreamSource::index() const {
  return impl_->pull.index();
}

void ViewStreamSource::fetch(std::uint32_t slice, SliceBytes& compressed) const {
  std::vector<SliceBytes> one;
  fetchAll(std::span(&slice, 1), one);
  compressed = std::move(one.front());
}

void ViewStreamSource::fetchAll(std::span<const std::uint32_t> slices,
                                std::vector<SliceBytes>& compressed) const {
  Impl& m = *impl_;
  std::size_t i = 0;
  while (i < slices.size()) {
    std::size_t end = i + 1;
    {
      std::unique_lock lock(m.mutex);
      SliceBytes bytes;
      if (m.takePushed(lock, slices[i], bytes)) {
        compressed.push_back(std::move(bytes));
        ++i;
        continue;
      }
      // The run of slices the stream does not bring, read together (neighbours in a chain lie back to back).
      while (end < slices.size() && !m.received.contains(slices[end]) && !m.coming(slices[end])) ++end;
      for (std::size_t k = i; k < end; ++k) m.delivered[slices[k]] = true;
      m.stats.pulled += end - i;
    }
    m.pull.fetchAll(slices.subspan(i, end - i), compressed);
    i = end;
  }
}

void ViewStreamSource::follow(const ViewQuery& view, std::size_t budgetBytes,
                              std::span<const std::uint32_t> first) const {
  Impl& m = *impl_;
  stream::View v;
  v.query = view;
  v.budgetBytes = budgetBytes;
  std::string key = stream::encodeView(v);  // the view without `first`: a new order alone is no new view
  {
    std::lock_guard lock(m.mutex);
    if (m.declined || key == m.latestKey) return;
    m.latestKey = std::move(key);
    m.latestView.emplace(view, budgetBytes);
    m.latestFirst.assign(first.begin(), first.end());
    m.viewDirty = true;
  }
  net::post(m.io, [&m] { m.sendView(); });
}

StreamStats ViewStreamSource::stats() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->stats;
}

bool ViewStreamSource::streaming() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->connected;
}

}  // namespace svo
