// `svo serve FOLDER`: the HTTP paging service (server/) over every .svo store under FOLDER, until SIGINT or
// SIGTERM.
#include <cstdio>
#include <memory>
#include <string>

#include "commands.hpp"
#include "svo/server/server.hpp"

namespace svo::tools {

void addServeCommand(CLI::App& app) {
  struct Args {
    server::ServerOptions options;
    std::string folder;
    std::string logFormat = "text";
    bool quiet = false;
  };
  auto args = std::make_shared<Args>();
  server::ServerOptions& o = args->options;
  o.port = 8080;
  auto* cmd = app.add_subcommand(
      "serve",
      "serve every .svo store under a folder over HTTP: whole files with range requests (as a static server "
      "does), /NAME/info, /NAME/directory, /NAME/slices/ID, /scenes, /metrics, /healthz");
  cmd->add_option("folder,--root", args->folder, "the folder of stores (searched recursively)")->required();
  cmd->add_option("--port", o.port, "TCP port (0: a free one, printed)")->capture_default_str();
  cmd->add_option("--bind", o.bind, "address to listen on")->capture_default_str();
  cmd->add_option("--threads", o.threads, "I/O threads (0: one per hardware thread)")->capture_default_str();
  cmd->add_option("--cache", o.cacheBytes, "bytes of compressed slices kept in memory (64M, 1G)")
      ->transform(CLI::AsSizeValue(false))
      ->default_str("256M");
  cmd->add_option("--stream-window", o.streamWindowBytes,
                  "bytes a view stream may send ahead of its client's acknowledgements (4M)")
      ->transform(CLI::AsSizeValue(false))
      ->check(CLI::Range(std::uint64_t(1), std::uint64_t(1) << 30))
      ->default_str("4M");
  cmd->add_option("--token", o.token,
                  "require 'Authorization: Bearer TOKEN' on every route but /healthz (prefer the SVO_TOKEN "
                  "variable: a command line is visible to other users); a store's NAME.svo.token file gives "
                  "that scene its own token")
      ->envname("SVO_TOKEN");
  cmd->add_option("--log-format", args->logFormat, "text, or json (one object per line)")
      ->check(CLI::IsMember({"text", "json"}))
      ->capture_default_str();
  cmd->add_flag("--no-request-log", args->quiet, "log failures only, not one line per request");
  cmd->callback([args] {
    server::ServerOptions options = args->options;
    options.root = args->folder;
    options.logFormat = args->logFormat == "json" ? server::LogFormat::Json : server::LogFormat::Text;
    options.logRequests = !args->quiet;
    server::Server server(options);  // a missing or empty folder throws: one line, exit 1
    server.serveUntilSignal([&](const server::Server& s) {
      const std::size_t stores = s.storeCount();
      std::printf("svo serve: %s/ (%zu store%s under %s; SIGINT or SIGTERM stops)\n", s.url().c_str(), stores,
                  stores == 1 ? "" : "s", args->folder.c_str());
      std::fflush(stdout);
    });
  });
}

}  // namespace svo::tools
