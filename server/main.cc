// geomfit-server: the long-running gRPC service. See --help for flags; every flag
// also reads a GEOMFIT_* environment variable.
#include <csignal>
#include <cstdio>
#include <thread>

#include <spdlog/async.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include "geomfit/version.h"
#include "server/logging.h"
#include "server/options.h"
#include "server/server.h"

int main(int argc, char** argv) {
  if (argc == 2 && std::string(argv[1]) == "--version") {
    std::printf("%s\n", geomfit::VersionLine("geomfit-server").c_str());
    return 0;
  }
  absl::StatusOr<geomfit::server::ServerOptions> options =
      geomfit::server::ParseServerOptions(std::vector<std::string>(argv + 1, argv + argc));
  if (!options.ok()) {
    const bool help = absl::IsNotFound(options.status());
    std::fprintf(help ? stdout : stderr, "%s%s\n", help ? "" : "geomfit-server: ",
                 std::string(options.status().message()).c_str());
    if (!help) std::fprintf(stderr, "%s", geomfit::server::ServerUsage().c_str());
    return help ? 0 : 2;
  }
  // Signals are taken synchronously by this thread only (blocked before any other
  // thread starts, so gRPC and pool threads inherit the mask).
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  // Logs go to stderr; stdout carries only the "listening on port N" line. A thread of
  // its own writes them: a request's log line does not delay its response.
  spdlog::init_thread_pool(8192, 1);
  spdlog::set_default_logger(spdlog::stderr_color_mt<spdlog::async_factory>("geomfit-server"));
  spdlog::set_level(spdlog::level::from_str(options->log_level));
  if (options->log_format == "json") spdlog::set_formatter(geomfit::server::NewJsonLogFormatter());

  auto server = geomfit::server::Server::Start(*options);
  if (!server.ok()) {
    spdlog::error("cannot start: {}", std::string(server.status().message()));
    spdlog::shutdown();
    return 1;
  }
  std::printf("geomfit-server listening on port %d\n", (*server)->port());
  std::fflush(stdout);

  int sig = 0;
  while (sigwait(&signals, &sig) == 0 && sig == SIGHUP) {  // SIGHUP: re-read --auth-tokens
    if (absl::Status s = (*server)->ReloadTokens(); !s.ok()) {
      spdlog::error("SIGHUP: keeping the old tokens: {}", std::string(s.message()));
    }
  }
  spdlog::info("received signal {}", sig);
  const bool json = options->log_format == "json";
  std::thread([&signals, json] {  // a second signal stops at once
    int again = 0;
    while (sigwait(&signals, &again) == 0 && again == SIGHUP) {
    }
    if (json) {
      std::fprintf(stderr, "{\"level\":\"critical\",\"logger\":\"geomfit-server\",\"message\":\"second signal %d: "
                           "exiting without draining\"}\n", again);
    } else {
      std::fprintf(stderr, "geomfit-server: second signal %d: exiting without draining\n", again);
    }
    std::_Exit(128 + again);
  }).detach();
  (*server)->Shutdown(options->drain_seconds);
  server->reset();  // closes the store
  spdlog::info("exit");
  spdlog::shutdown();  // writes what is queued
  // gRPC's global teardown can linger for seconds after a clean shutdown; nothing
  // is left to flush, so skip it.
  std::fflush(stdout);
  std::_Exit(0);
}
