#include "link_delay.hpp"

#include <array>
#include <chrono>
#include <cmath>
#include <deque>
#include <stdexcept>
#include <thread>
#include <utility>  // before Asio: Boost 1.74's awaitable.hpp uses std::exchange without it
#include <vector>

#include <boost/asio.hpp>

namespace svo::tools::bench {
namespace {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using Clock = std::chrono::steady_clock;

// Bytes taken from a socket per read: a TCP window's worth on loopback.
constexpr std::size_t kChunkBytes = 64 * 1024;

// The link every connection shares: its one-way delay, its rate, and per direction when it has carried the
// bytes handed to it so far. Touched by the relay's one I/O thread only.
struct Link {
  Clock::duration delay{};
  double bytesPerSecond = 0.0;  // 0: unbounded
  std::array<Clock::time_point, 2> freeAt{};

  // When `bytes` arriving now in direction `d` reach the far end.
  Clock::time_point due(int d, std::size_t bytes) {
    const Clock::time_point now = Clock::now();
    if (bytesPerSecond <= 0.0) return now + delay;
    const auto sending = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(double(bytes) / bytesPerSecond));
    freeAt[d] = std::max(freeAt[d], now) + sending;
    return freeAt[d] + delay;
  }
};

// One relayed connection: two directions, each a queue of chunks stamped with when they may be delivered.
class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(const asio::any_io_executor& executor, tcp::socket client, const tcp::endpoint& upstream,
          std::shared_ptr<Link> link)
      : sockets_{std::move(client), tcp::socket(executor)},
        upstream_(upstream),
        link_(std::move(link)),
        handshakeDone_(Clock::now() + 2 * link_->delay),
        pipes_{Pipe(executor), Pipe(executor)} {}

  void start() {
    sockets_[1].async_connect(upstream_, [self = shared_from_this()](boost::system::error_code ec) {
      if (ec) return self->close();
      self->read(0);
      self->read(1);
    });
  }

 private:
  struct Chunk {
    Clock::time_point due;
    std::vector<char> bytes;
  };
  // Bytes from sockets_[d] to sockets_[1 - d].
  struct Pipe {
    explicit Pipe(const asio::any_io_executor& executor) : timer(executor) {}
    std::array<char, kChunkBytes> buffer{};
    std::deque<Chunk> queue;
    asio::steady_timer timer;
    bool writing = false, ended = false;
  };

  void read(int d) {
    sockets_[d].async_read_some(asio::buffer(pipes_[d].buffer),
                                [self = shared_from_this(), d](boost::system::error_code ec, std::size_t n) {
                                  Pipe& p = self->pipes_[d];
                                  if (n > 0) {
                                    // The handshake's round trip holds a new connection's first bytes.
                                    const Clock::time_point due =
                                        std::max(self->link_->due(d, n), self->handshakeDone_);
                                    p.queue.push_back({due, {p.buffer.begin(), p.buffer.begin() + n}});
                                    if (!p.writing) self->deliver(d);
                                  }
                                  if (ec == asio::error::eof) {
                                    p.ended = true;
                                    if (!p.writing) self->deliver(d);
                                  } else if (ec) {
                                    self->close();
                                  } else {
                                    self->read(d);
                                  }
                                });
  }

  void deliver(int d) {
    Pipe& p = pipes_[d];
    if (p.queue.empty()) {
      p.writing = false;
      boost::system::error_code ignored;
      if (p.ended) sockets_[1 - d].shutdown(tcp::socket::shutdown_send, ignored);  // pass the EOF on
      return;
    }
    p.writing = true;
    p.timer.expires_at(p.queue.front().due);
    p.timer.async_wait([self = shared_from_this(), d](boost::system::error_code ec) {
      if (ec) return;  // closed
      Pipe& p = self->pipes_[d];
      asio::async_write(self->sockets_[1 - d], asio::buffer(p.queue.front().bytes),
                        [self, d](boost::system::error_code ec, std::size_t) {
                          if (ec) return self->close();
                          self->pipes_[d].queue.pop_front();
                          self->deliver(d);
                        });
    });
  }

  void close() {
    boost::system::error_code ignored;
    for (int d = 0; d < 2; ++d) {
      sockets_[d].close(ignored);
      pipes_[d].timer.cancel();
    }
  }

  std::array<tcp::socket, 2> sockets_;  // the client's, the server's
  tcp::endpoint upstream_;
  std::shared_ptr<Link> link_;
  Clock::time_point handshakeDone_;
  std::array<Pipe, 2> pipes_;
};

}  // namespace

struct LinkDelay::Impl {
  asio::io_context io;
  tcp::acceptor acceptor{io};
  tcp::endpoint upstream;
  std::shared_ptr<Link> link = std::make_shared<Link>();
  std::thread thread;

  void accept() {
    acceptor.async_accept([this](boost::system::error_code ec, tcp::socket socket) {
      if (ec) return;  // stopped
      std::make_shared<Session>(io.get_executor(), std::move(socket), upstream, link)->start();
      accept();
    });
  }
};

LinkDelay::LinkDelay(const std::string& host, int port, double oneWaySeconds, double bitsPerSecond)
    : impl_(std::make_unique<Impl>()) {
  if (!(oneWaySeconds >= 0.0)) throw std::runtime_error("link delay: the delay must be >= 0");
  if (!(bitsPerSecond >= 0.0) || std::isinf(bitsPerSecond))
    throw std::runtime_error("link delay: the rate must be a finite number of bits per second >= 0");
  boost::system::error_code ec;
  const auto resolved = tcp::resolver(impl_->io).resolve(host, std::to_string(port), ec);
  if (ec || resolved.empty())
    throw std::runtime_error("link delay: cannot resolve " + host + " (" + ec.message() + ")");
  impl_->upstream = resolved.begin()->endpoint();
  impl_->link->delay =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(oneWaySeconds));
  impl_->link->bytesPerSecond = bitsPerSecond / 8.0;
  const tcp::endpoint local(asio::ip::address_v4::loopback(), 0);
  impl_->acceptor.open(local.protocol());
  impl_->acceptor.bind(local, ec);
  if (!ec) impl_->acceptor.listen(asio::socket_base::max_listen_connections, ec);
  if (ec) throw std::runtime_error("link delay: cannot listen on 127.0.0.1 (" + ec.message() + ")");
  impl_->accept();
  impl_->thread = std::thread([this] { impl_->io.run(); });
}

LinkDelay::~LinkDelay() {
  impl_->io.stop();
  impl_->thread.join();
}

int LinkDelay::port() const {
  return impl_->acceptor.local_endpoint().port();
}

}  // namespace svo::tools::bench
