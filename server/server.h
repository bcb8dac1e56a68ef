#pragma once
#include <memory>

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "server/options.h"

namespace prometheus {
class Exposer;
}

namespace geomfit::server {

class Cache;
class Handlers;
class Workspace;
class JobHandlers;
class JobManager;
class MeshStore;
class MetricsCollectable;
class RequestStats;
class Service;
class StreamLimits;
class TokenTable;
class ThreadPool;

/// A running geomfit server: store, caches, pools, gRPC service with health and
/// reflection, optional Prometheus exposer. Used by main and by in-process tests.
class Server {
 public:
  /// Opens the store and starts listening; errors say which resource failed.
  static absl::StatusOr<std::unique_ptr<Server>> Start(const ServerOptions& options);
  ~Server();

  int port() const { return port_; }
  /// Health NOT_SERVING, new calls UNAVAILABLE, running jobs are cancelled (they end
  /// FAILED, "interrupted by server shutdown"), in-flight calls get `drain_seconds` to
  /// finish (then they are cancelled), pools stop. Idempotent.
  void Shutdown(double drain_seconds);
  /// Re-reads --auth-tokens (SIGHUP); on error the old tokens stay. OK without a file.
  absl::Status ReloadTokens();
  /// The compute pool (fair across tenants, --quota-inflight); tests look at its lanes.
  ThreadPool& compute_pool() { return *compute_; }

 private:
  Server() = default;

  ServerOptions options_;
  std::unique_ptr<MeshStore> store_;
  std::unique_ptr<Cache> cache_;
  std::unique_ptr<RequestStats> stats_;
  std::unique_ptr<Workspace> workspace_;
  std::unique_ptr<Handlers> handlers_;
  std::unique_ptr<ThreadPool> compute_, io_;
  std::unique_ptr<Service> service_;
  std::unique_ptr<grpc::Server> grpc_server_;
  std::shared_ptr<MetricsCollectable> metrics_;
  std::unique_ptr<prometheus::Exposer> exposer_;
  std::unique_ptr<TokenTable> tokens_;
  std::unique_ptr<JobManager> jobs_;  // last: shut down first (its jobs use the handlers)
  std::unique_ptr<JobHandlers> job_handlers_;
  int port_ = 0;
  bool stopped_ = false;
  std::unique_ptr<StreamLimits> stream_limits_;  ///< in-flight budget and idle watchdog of streams
};

}  // namespace geomfit::server
