#include "svo/server/server.hpp"

#include <algorithm>
#include <csignal>
#include <memory>
#include <stdexcept>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <boost/asio/executor_work_guard.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>

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

// One I/O context per thread, each run by that thread alone, connections spread over them as they are
// accepted: no lock or wake-up between threads on the path of a request (as nginx's workers). Members are
// destroyed bottom up: acceptor and guards before their contexts, the contexts (and the handlers they still
// hold) before the sessions' registry and the shared context that those handlers use.
struct Server::Impl {
  explicit Impl(ServerOptions options) : context(std::move(options)) {}
  void accept();
  void run(net::io_context& io);

  Context context;
  Sessions sessions;
  std::size_t stores = 0;
  std::vector<std::unique_ptr<net::io_context>> ios;
  std::vector<net::executor_work_guard<net::io_context::executor_type>> work;
  std::unique_ptr<tcp::acceptor> acceptor;
  std::unique_ptr<net::steady_timer> acceptRetry;
  std::size_t nextIo = 0;  // the context of the next connection (used by the acceptor's thread only)
  std::vector<std::thread> threads;
  std::uint16_t port = 0;
  bool started = false, stopped = false;
};

void Server::Impl::accept() {
  net::io_context& io = *ios[nextIo++ % ios.size()];
  acceptor->async_accept(io, [this](boost::system::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !acceptor->is_open() || context.stopping) return;
    if (ec) {
      context.log.error("accepting a connection: " + ec.message());
      acceptRetry->expires_after(kAcceptRetryDelay);
      acceptRetry->async_wait([this](boost::system::error_code waited) {
        if (!waited) accept();
      });
      return;
    }
    std::make_shared<Session>(std::move(socket), context, sessions)->start();
    accept();
  });
}

void Server::Impl::run(net::io_context& io) {
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
  const unsigned threads = o.threads ? o.threads : std::max(1u, std::thread::hardware_concurrency());
  for (unsigned i = 0; i < threads; ++i) {
    m.ios.push_back(std::make_unique<net::io_context>(1));  // the hint: one thread runs it
    m.work.push_back(net::make_work_guard(*m.ios.back()));
  }
  m.acceptor = std::make_unique<tcp::acceptor>(*m.ios.front());
  m.acceptRetry = std::make_unique<net::steady_timer>(*m.ios.front());
  boost::system::error_code ec;
  const net::ip::address address = net::ip::make_address(o.bind, ec);
  if (ec) throw std::runtime_error("not an IP address to listen on: " + o.bind);
  const tcp::endpoint endpoint(address, o.port);
  const auto check = [&](const char* step) {
    if (ec)
      throw std::runtime_error(
          fmt::format("cannot listen on {}:{} ({}): {}", o.bind, o.port, step, ec.message()));
  };
  m.acceptor->open(endpoint.protocol(), ec);
  check("open");
  m.acceptor->set_option(net::socket_base::reuse_address(true), ec);
  check("reuse address");
  m.acceptor->bind(endpoint, ec);
  check("bind");
  m.acceptor->listen(net::socket_base::max_listen_connections, ec);
  check("listen");
  m.port = m.acceptor->local_endpoint().port();
  m.started = true;
  m.accept();
  for (const auto& io : m.ios) m.threads.emplace_back([&m, &io = *io] { m.run(io); });
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
  net::post(m.acceptor->get_executor(), [&m] {
    boost::system::error_code ignored;
    m.acceptor->close(ignored);
    m.acceptRetry->cancel();
  });
  m.sessions.stopAll();
  if (!m.sessions.waitUntilNone(kStopGrace))
    m.context.log.error(
        fmt::format("stopping: connections still open after {} s are cut", kStopGrace.count()));
  m.work.clear();
  for (const auto& io : m.ios) io->stop();
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
