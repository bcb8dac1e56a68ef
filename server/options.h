#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace geomfit::server {

/// Server configuration. Every field has a flag (--port) and an environment variable
/// (GEOMFIT_PORT); flags win over the environment, which wins over the defaults.
struct ServerOptions {
  std::string host = "127.0.0.1";          ///< loopback: other hosts need --host 0.0.0.0 (with TLS)
  int port = 50051;                        ///< 0 = pick a free port (reported at start)
  std::string store = "sqlite";            ///< sqlite | memory
  std::string data_dir = "geomfit-data";   ///< SQLite database directory
  int64_t cache_bytes = int64_t{2} << 30;  ///< byte budget of the three cache tiers
  int64_t max_message_bytes = int64_t{64} << 20;
  int64_t max_vertices = 20'000'000;
  int threads = 0;                         ///< numeric threads per computation; 0 = all cores
  int workers = 2;                         ///< compute pool size (concurrent computations)
  int queue = 256;                         ///< pending tasks beyond which RESOURCE_EXHAUSTED
  int metrics_port = 0;                    ///< Prometheus exposition port; 0 = off
  std::string metrics_host;                ///< metrics listen address; "" = --host
  double drain_seconds = 10;               ///< SIGTERM: finish in-flight calls within this
  int64_t chunk_rows = 0;                  ///< rows per streamed response chunk; 0 = by chunk_bytes
  int64_t chunk_bytes = 128 << 10;         ///< target bytes per streamed chunk when chunk_rows = 0
  std::string log_level = "info";
  std::string log_format = "text";         ///< text | json (one JSON object per line)
  int prefetch = 1;                        ///< 1: after UpdatePositions, recompute last step's differentials
  int spin_us = 1000;                      ///< one idle compute worker polls this long before sleeping
  int job_threads = 1;                     ///< jobs running at once (own threads, apart from the pools)
  int max_jobs = 16;                       ///< pending + running jobs beyond which StartJob is RESOURCE_EXHAUSTED
  std::string tls_cert;                    ///< PEM certificate chain: serve gRPC over TLS (not metrics)
  std::string tls_key;                     ///< PEM private key of tls_cert
  std::string auth_tokens;                 ///< `TOKEN TENANT` lines: bearer tokens, one namespace per tenant
  std::string tls_client_ca;               ///< PEM CA bundle: require and verify client certificates (mTLS)
  int64_t max_inflight_bytes = 0;          ///< bytes client streams may reserve at once; 0 = cache_bytes / 2
  double stream_idle_seconds = 30;         ///< a client stream silent this long ends (DEADLINE_EXCEEDED); 0 = never

  /// max_inflight_bytes, or its default: half of cache_bytes.
  int64_t InflightBudget() const { return max_inflight_bytes > 0 ? max_inflight_bytes : cache_bytes / 2; }
  int64_t quota_meshes = 0;                ///< stored meshes per tenant; 0 = unlimited
  int64_t quota_bytes = 0;                 ///< their array bytes per tenant; 0 = unlimited
  int quota_inflight = 0;                  ///< one tenant's requests in compute until answered; 0 = unlimited

  std::string Address() const { return host + ":" + std::to_string(port); }
  /// True for 127.0.0.0/8, ::1 and localhost.
  static bool IsLoopback(const std::string& host);
};

/// Usage text listing every flag, its variable and default.
std::string ServerUsage();

/// Applies GEOMFIT_* environment variables, then `args` (argv without the program
/// name; "--name=value" or "--name value"). Errors name the flag and the bad value.
/// "--help" yields a NOT_FOUND status carrying the usage text.
absl::StatusOr<ServerOptions> ParseServerOptions(const std::vector<std::string>& args);

}  // namespace geomfit::server
