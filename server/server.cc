#include "server/server.h"

#include <thread>

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/health_check_service_interface.h>
#include <prometheus/exposer.h>
#include <spdlog/spdlog.h>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "server/auth.h"
#include "server/handlers/handlers.h"
#include "server/handlers/jobs.h"
#include "server/jobs/job_manager.h"
#include "server/mesh_store.h"
#include "server/metrics.h"
#include "server/request_stats.h"
#include "server/rpc/service.h"
#include "server/rpc/stream_limits.h"
#include "server/thread_pool.h"
#include "server/tls.h"
#include "server/workspace/cache.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {
namespace {
const char* const kServiceName = "geomfit.v1.GeomFit";
}  // namespace

absl::StatusOr<std::unique_ptr<Server>> Server::Start(const ServerOptions& options) {
  std::unique_ptr<Server> s(new Server());
  s->options_ = options;
  if (options.store == "memory") {
    s->store_ = NewMemoryStore();
  } else {
    GF_ASSIGN_OR_RETURN(s->store_, OpenSqliteStore(options.data_dir));
  }
  s->cache_ = std::make_unique<Cache>(options.cache_bytes);
  s->stats_ = std::make_unique<RequestStats>();
  WorkspaceOptions w;
  w.max_vertices = options.max_vertices;
  w.threads = options.threads;
  w.prefetch = options.prefetch != 0;
  w.quotas = {options.quota_meshes, options.quota_bytes};
  s->workspace_ = std::make_unique<Workspace>(s->store_.get(), s->cache_.get(), w);
  GF_RETURN_IF_ERROR(s->workspace_->quotas().Load(*s->store_));  // usage is derived, never persisted
  HandlerOptions h;
  h.max_vertices = options.max_vertices;
  h.max_message_bytes = options.max_message_bytes;
  h.chunk_rows = options.chunk_rows;
  h.chunk_bytes = options.chunk_bytes;
  h.workers = options.workers;
  s->handlers_ = std::make_unique<Handlers>(s->workspace_.get(), s->stats_.get(), h);
  s->compute_ = std::make_unique<ThreadPool>(options.workers, options.queue, std::chrono::microseconds(options.spin_us));
  s->io_ = std::make_unique<ThreadPool>(2, options.queue, std::chrono::microseconds(0), "io");
  s->service_ = std::make_unique<Service>(s->handlers_.get(), s->compute_.get(), s->io_.get(), s->stats_.get());
  s->service_->SetInflightQuota(options.quota_inflight);
  JobManagerOptions jobs;
  jobs.threads = options.job_threads;
  jobs.max_jobs = options.max_jobs;
  jobs.numeric_threads = options.threads;
  GF_ASSIGN_OR_RETURN(s->jobs_, JobManager::Create(s->store_.get(), jobs));
  s->job_handlers_ = std::make_unique<JobHandlers>(s->jobs_.get(), s->handlers_.get(), options.max_vertices);
  s->service_->SetJobs(s->job_handlers_.get());
  s->stream_limits_ = std::make_unique<StreamLimits>(
      options.InflightBudget(), std::chrono::milliseconds(static_cast<int64_t>(options.stream_idle_seconds * 1e3)));
  s->service_->SetStreamLimits(s->stream_limits_.get());
  if (!options.auth_tokens.empty()) {
    GF_ASSIGN_OR_RETURN(s->tokens_, TokenTable::Load(options.auth_tokens));
    s->service_->SetTokens(s->tokens_.get());
  }

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  builder.SetMaxReceiveMessageSize(static_cast<int>(options.max_message_bytes));
  builder.SetMaxSendMessageSize(static_cast<int>(options.max_message_bytes));
  GF_ASSIGN_OR_RETURN(const std::shared_ptr<grpc::ServerCredentials> credentials, ServerCredentialsFor(options));
  builder.AddListeningPort(options.Address(), credentials, &s->port_);
  builder.RegisterService(s->service_.get());
  s->grpc_server_ = builder.BuildAndStart();
  if (s->grpc_server_ == nullptr || s->port_ == 0) {
    return absl::UnavailableError(absl::StrCat("cannot listen on ", options.Address(), " (port in use?)"));
  }
  s->grpc_server_->GetHealthCheckService()->SetServingStatus(kServiceName, true);
  s->grpc_server_->GetHealthCheckService()->SetServingStatus(true);

  if (options.metrics_port > 0) {
    try {
      s->exposer_ = std::make_unique<prometheus::Exposer>(
          absl::StrCat(options.metrics_host.empty() ? options.host : options.metrics_host, ":", options.metrics_port));
    } catch (const std::exception& e) {
      return absl::UnavailableError(absl::StrCat("metrics: cannot listen on port ", options.metrics_port, ": ", e.what()));
    }
    if (!options.tls_cert.empty()) {
      spdlog::warn("metrics on port {} are plaintext HTTP (no TLS, see server/tls.h): keep them on a private "
                   "address or behind a TLS proxy", options.metrics_port);
    }
    s->metrics_ = std::make_shared<MetricsCollectable>(s->stats_.get(), s->cache_.get(), s->store_.get());
    s->exposer_->RegisterCollectable(s->metrics_);
  }
  if (!ServerOptions::IsLoopback(options.host) && options.tls_cert.empty()) {
    spdlog::warn("listening on {} without TLS: anyone on the network can read and change the meshes "
                 "(use --tls-cert/--tls-key, and --auth-tokens)", options.host);
  }
  spdlog::info("geomfit-server listening on {}:{} ({}, store={} data-dir={} cache-bytes={} workers={} metrics-port={})",
               options.host, s->port_,
               absl::StrCat(options.tls_cert.empty() ? "plaintext" : options.tls_client_ca.empty() ? "TLS" : "mTLS",
                            options.auth_tokens.empty() ? "" : ", bearer tokens"), options.store, options.data_dir, options.cache_bytes, options.workers,
               options.metrics_port);
  return s;
}

void Server::Shutdown(double drain_seconds) {
  if (stopped_) return;
  stopped_ = true;
  if (grpc_server_ == nullptr) return;  // Start failed before serving
  spdlog::info("draining: health NOT_SERVING, finishing in-flight calls within {}s", drain_seconds);
  grpc_server_->GetHealthCheckService()->SetServingStatus(false);
  service_->StartDraining();
  jobs_->Shutdown();  // running jobs end now: their watchers get the final event
  // Our calls get until the deadline; then Shutdown cancels what is left at once
  // (waiting in Shutdown itself would also wait out the health service's idle
  // internal calls, i.e. always the full deadline).
  const auto deadline = std::chrono::steady_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(drain_seconds * 1e3));
  while (service_->in_flight() > 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  if (service_->in_flight() > 0) spdlog::warn("drain deadline passed: cancelling {} calls", service_->in_flight());
  grpc_server_->Shutdown(std::chrono::system_clock::now());
  compute_->Stop();
  io_->Stop();
  grpc_server_->Wait();
  exposer_.reset();
  spdlog::info("stopped");
}

absl::Status Server::ReloadTokens() {
  if (tokens_ == nullptr) return absl::OkStatus();
  GF_RETURN_IF_ERROR(tokens_->Reload());
  spdlog::info("auth tokens reloaded: {} tokens", tokens_->size());
  return absl::OkStatus();
}

Server::~Server() { Shutdown(0); }

}  // namespace geomfit::server
