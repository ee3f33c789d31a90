#include "svo/server/server.hpp"

#include <algorithm>
#include <csignal>
#include <stdexcept>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>

#include "handler.hpp"
#include "session.hpp"

namespace svo::server {
namespace net = boost::asio;
using tcp = net::ip::tcp;
namespace {

// How long stop() lets responses in flight finish before it ends the rest.
constexpr std::chrono::seconds kStopGrace{5};
// After a failed accept (out of file descriptors, say), the wait before the next: connections close
// meanwhile instead of the acceptor spinning.
constexpr std::chrono::milliseconds kAcceptRetryDelay{100};

}  // namespace

// Members in destruction order reversed: the I/O context goes before the sessions' registry and the
// context, which handlers it still holds use when they are destroyed with it.
struct Server::Impl {
  explicit Impl(ServerOptions options) : context(std::move(options)) {}
  void accept();
  void run();

  Context context;
  Sessions sessions;
  std::size_t stores = 0;
  net::io_context io;
  tcp::acceptor acceptor{net::make_strand(io)};
  net::steady_timer acceptRetry{acceptor.get_executor()};
  std::vector<std::thread> threads;
  std::uint16_t port = 0;
  bool started = false, stopped = false;
};

void Server::Impl::accept() {
  acceptor.async_accept(net::make_strand(io), [this](boost::system::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !acceptor.is_open() || context.stopping) return;
    if (ec) {
      context.log.error("accepting a connection: " + ec.message());
      acceptRetry.expires_after(kAcceptRetryDelay);
      acceptRetry.async_wait([this](boost::system::error_code waited) {
        if (!waited) accept();
      });
      return;
    }
    std::make_shared<Session>(std::move(socket), context, sessions)->start();
    accept();
  });
}

void Server::Impl::run() {
  // A handler that throws is a bug; the thread logs it and goes on serving the other connections.
  while (true) {
    try {
      io.run();
      return;
    } catch (const std::exception& e) {
      context.log.error(std::string("unexpected failure in a connection: ") + e.what());
    }
  }
}

Server::Server(ServerOptions options) : impl_(std::make_unique<Impl>(std::move(options))) {
  impl_->stores = impl_->context.catalog.names().size();
  if (impl_->stores == 0)
    throw std::runtime_error(impl_->context.options.root.string() + ": no .svo store in this folder");
}

Server::~Server() {
  stop();
}

void Server::start() {
  Impl& m = *impl_;
  if (m.started) throw std::logic_error("Server::start called twice");
  const ServerOptions& o = m.context.options;
  boost::system::error_code ec;
  const net::ip::address address = net::ip::make_address(o.bind, ec);
  if (ec) throw std::runtime_error("not an IP address to listen on: " + o.bind);
  const tcp::endpoint endpoint(address, o.port);
  const auto check = [&](const char* step) {
    if (ec)
      throw std::runtime_error(
          fmt::format("cannot listen on {}:{} ({}): {}", o.bind, o.port, step, ec.message()));
  };
  m.acceptor.open(endpoint.protocol(), ec);
  check("open");
  m.acceptor.set_option(net::socket_base::reuse_address(true), ec);
  check("reuse address");
  m.acceptor.bind(endpoint, ec);
  check("bind");
  m.acceptor.listen(net::socket_base::max_listen_connections, ec);
  check("listen");
  m.port = m.acceptor.local_endpoint().port();
  m.started = true;
  m.accept();
  const unsigned threads = o.threads ? o.threads : std::max(1u, std::thread::hardware_concurrency());
  for (unsigned i = 0; i < threads; ++i) m.threads.emplace_back([&m] { m.run(); });
}

std::uint16_t Server::port() const {
  return impl_->port;
}

std::string Server::url() const {
  const std::string& bind = impl_->context.options.bind;
  const bool v6 = bind.find(':') != std::string::npos;
  return fmt::format("http://{}{}{}:{}", v6 ? "[" : "", bind, v6 ? "]" : "", impl_->port);
}

std::size_t Server::storeCount() const {
  return impl_->stores;
}

void Server::stop() {
  Impl& m = *impl_;
  if (!m.started || m.stopped) return;
  m.stopped = true;
  m.context.stopping = true;
  net::post(m.acceptor.get_executor(), [&m] {
    boost::system::error_code ignored;
    m.acceptor.close(ignored);
    m.acceptRetry.cancel();
  });
  m.sessions.stopAll();
  if (!m.sessions.waitUntilNone(kStopGrace))
    m.context.log.error(
        fmt::format("stopping: connections still open after {} s are cut", kStopGrace.count()));
  m.io.stop();
  for (std::thread& t : m.threads) t.join();
  m.threads.clear();
}

void Server::serveUntilSignal(const std::function<void(const Server&)>& listening) {
  // The signals are caught from here on, before anyone is told where the server listens.
  net::io_context signalsIo;
  net::signal_set signals(signalsIo, SIGINT, SIGTERM);
  int received = 0;
  signals.async_wait([&](boost::system::error_code, int signal) { received = signal; });
  start();
  if (listening) listening(*this);
  signalsIo.run();
  impl_->context.log.info(fmt::format("signal {}: stopping", received));
  stop();
}

}  // namespace svo::server
