#include "server/options.h"

#include <cstdlib>
#include <functional>
#include <map>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "core/util/status_macros.h"

namespace geomfit::server {
namespace {

using Setter = std::function<absl::Status(const std::string&, ServerOptions*)>;

struct Flag {
  const char* name;
  const char* help;
  Setter set;
};

absl::Status Bad(const std::string& name, const std::string& value, const char* want) {
  return absl::InvalidArgumentError(absl::StrCat("--", name, "=", value, ": expected ", want));
}

/// Integer with an optional K/M/G (binary) suffix.
bool ParseBytes(std::string v, int64_t* out) {
  int64_t scale = 1;
  const std::string lower = absl::AsciiStrToLower(v);
  for (const auto& [suffix, s] : {std::pair<const char*, int64_t>{"gib", 1 << 30}, {"mib", 1 << 20},
                                  {"kib", 1 << 10}, {"g", 1 << 30}, {"m", 1 << 20}, {"k", 1 << 10}}) {
    if (absl::EndsWith(lower, suffix)) {
      scale = s;
      v = v.substr(0, v.size() - std::string(suffix).size());
      break;
    }
  }
  int64_t n = 0;
  if (!absl::SimpleAtoi(v, &n) || n < 0) return false;
  *out = n * scale;
  return true;
}

template <typename T>
Setter IntSetter(T ServerOptions::*field, const char* name, int64_t lo, int64_t hi) {
  return [=](const std::string& v, ServerOptions* o) {
    int64_t n = 0;
    if (!ParseBytes(v, &n) || n < lo || n > hi)
      return Bad(name, v, absl::StrCat("an integer in [", lo, ", ", hi, "]").c_str());
    o->*field = static_cast<T>(n);
    return absl::OkStatus();
  };
}

/// A file path; empty leaves the option off.
Setter PathSetter(std::string ServerOptions::*field) {
  return [=](const std::string& v, ServerOptions* o) {
    o->*field = v;
    return absl::OkStatus();
  };
}

const std::vector<Flag>& Flags() {
  static const auto* flags = new std::vector<Flag>{
      {"host", "listen address; the default is loopback only: 0.0.0.0 serves every interface (use TLS)",
       [](const std::string& v, ServerOptions* o) { o->host = v; return absl::OkStatus(); }},
      {"port", "gRPC port; 0 picks a free one", IntSetter(&ServerOptions::port, "port", 0, 65535)},
      {"store", "mesh store: sqlite (durable) or memory",
       [](const std::string& v, ServerOptions* o) {
         if (v != "sqlite" && v != "memory") return Bad("store", v, "sqlite or memory");
         o->store = v;
         return absl::OkStatus();
       }},
      {"data-dir", "directory of the SQLite store",
       [](const std::string& v, ServerOptions* o) {
         if (v.empty()) return Bad("data-dir", v, "a directory");
         o->data_dir = v;
         return absl::OkStatus();
       }},
      {"cache-bytes", "cache budget (bytes; K/M/G suffixes)",
       IntSetter(&ServerOptions::cache_bytes, "cache-bytes", 1 << 20, int64_t{1} << 50)},
      {"max-message-bytes", "largest gRPC message",
       IntSetter(&ServerOptions::max_message_bytes, "max-message-bytes", 1 << 16, (int64_t{1} << 31) - 1)},
      {"max-vertices", "largest mesh accepted",
       IntSetter(&ServerOptions::max_vertices, "max-vertices", 3, int64_t{1} << 31)},
      {"threads", "numeric threads per computation; 0 = all cores",
       IntSetter(&ServerOptions::threads, "threads", 0, 1024)},
      {"workers", "concurrent computations (compute pool size)",
       IntSetter(&ServerOptions::workers, "workers", 1, 1024)},
      {"queue", "pending computations before RESOURCE_EXHAUSTED",
       IntSetter(&ServerOptions::queue, "queue", 1, 1 << 20)},
      {"metrics-port", "Prometheus /metrics port; 0 = off",
       IntSetter(&ServerOptions::metrics_port, "metrics-port", 0, 65535)},
      {"metrics-host", "metrics listen address (default: --host)",
       [](const std::string& v, ServerOptions* o) { o->metrics_host = v; return absl::OkStatus(); }},
      {"drain-seconds", "on SIGTERM/SIGINT, stop within this many seconds",
       [](const std::string& v, ServerOptions* o) {
         double s = 0;
         if (!absl::SimpleAtod(v, &s) || s < 0 || s > 3600) return Bad("drain-seconds", v, "0..3600");
         o->drain_seconds = s;
         return absl::OkStatus();
       }},
      {"chunk-rows", "rows per streamed response chunk; 0 = as many as fit in --chunk-bytes",
       IntSetter(&ServerOptions::chunk_rows, "chunk-rows", 0, int64_t{1} << 24)},
      {"chunk-bytes", "target bytes per streamed response chunk (messages of ~100 KiB stream fastest)",
       IntSetter(&ServerOptions::chunk_bytes, "chunk-bytes", 1024, int64_t{1} << 30)},
      {"prefetch", "1: right after UpdatePositions, compute the differentials last requested on the previous "
                   "revision, so a time-stepping client's next request finds them under way; 0: off",
       IntSetter(&ServerOptions::prefetch, "prefetch", 0, 1)},
      {"spin-us", "microseconds one idle compute worker polls for the next task before it sleeps, so that a "
                  "time-stepping client's next update starts at once on a core that has not gone idle; 0: off",
       IntSetter(&ServerOptions::spin_us, "spin-us", 0, 1'000'000)},
      {"job-threads", "jobs (StartJob) running at once, on threads of their own",
       IntSetter(&ServerOptions::job_threads, "job-threads", 1, 256)},
      {"max-jobs", "pending + running jobs beyond which StartJob is RESOURCE_EXHAUSTED",
       IntSetter(&ServerOptions::max_jobs, "max-jobs", 1, 1 << 20)},
      {"tls-cert", "PEM certificate (chain): serve gRPC over TLS (metrics stay plaintext); without it, plaintext",
       PathSetter(&ServerOptions::tls_cert)},
      {"tls-key", "PEM private key of --tls-cert", PathSetter(&ServerOptions::tls_key)},
      {"tls-client-ca", "PEM CA bundle: require client certificates signed by it (mTLS; needs --tls-cert)",
       PathSetter(&ServerOptions::tls_client_ca)},
      {"auth-tokens", "file of `TOKEN TENANT` lines: calls need 'authorization: Bearer TOKEN' and see only "
                      "their tenant's meshes and jobs (reloaded on SIGHUP); without it, one tenant, no authentication",
       PathSetter(&ServerOptions::auth_tokens)},
      {"quota-meshes", "meshes one tenant may store (uploads, refinements, job results); 0 = unlimited",
       IntSetter(&ServerOptions::quota_meshes, "quota-meshes", 0, int64_t{1} << 40)},
      {"quota-bytes", "bytes of stored meshes one tenant may hold (24 per vertex + 16 per face; K/M/G "
                      "suffixes); 0 = unlimited",
       IntSetter(&ServerOptions::quota_bytes, "quota-bytes", 0, int64_t{1} << 60)},
      {"quota-inflight", "requests of one tenant in the compute pool at once (queued, computing or sending their "
                         "answer); 0 = unlimited",
       IntSetter(&ServerOptions::quota_inflight, "quota-inflight", 0, 1 << 20)},
      {"log-level", "trace|debug|info|warn|error|off",
       [](const std::string& v, ServerOptions* o) {
         for (const char* level : {"trace", "debug", "info", "warn", "error", "off"}) {
           if (v == level) {
             o->log_level = v;
             return absl::OkStatus();
           }
         }
         return Bad("log-level", v, "trace, debug, info, warn, error or off");
       }},
      {"log-format", "text, or json: one JSON object per line (for cluster log collectors)",
       [](const std::string& v, ServerOptions* o) {
         if (v != "text" && v != "json") return Bad("log-format", v, "text or json");
         o->log_format = v;
         return absl::OkStatus();
       }},
      {"max-inflight-bytes", "bytes that upload/update streams may hold at once: each reserves its declared size "
                             "(rows and the mesh built from them) when its header arrives, else RESOURCE_EXHAUSTED "
                             "(server streams' encoded chunks, at most two per stream, are counted too); "
                             "0 = half of --cache-bytes",
       IntSetter(&ServerOptions::max_inflight_bytes, "max-inflight-bytes", 0, int64_t{1} << 50)},
      {"stream-idle-seconds", "an upload/update stream with no message for this long, or a server stream "
                              "(download, compute, watch) whose reader takes no message that long, ends with "
                              "DEADLINE_EXCEEDED and releases its memory; 0 = never",
       [](const std::string& v, ServerOptions* o) {
         double s = 0;
         if (!absl::SimpleAtod(v, &s) || s < 0 || s > 86400) return Bad("stream-idle-seconds", v, "0..86400");
         o->stream_idle_seconds = s;
         return absl::OkStatus();
       }},
  };
  return *flags;
}

std::string EnvName(const char* flag) {
  return "GEOMFIT_" + absl::AsciiStrToUpper(absl::StrReplaceAll(flag, {{"-", "_"}}));
}

const Flag* Find(const std::string& name) {
  for (const Flag& f : Flags())
    if (name == f.name) return &f;
  return nullptr;
}

}  // namespace

bool ServerOptions::IsLoopback(const std::string& host) {
  return host == "localhost" || host == "::1" || host == "[::1]" || absl::StartsWith(host, "127.");
}

std::string ServerUsage() {
  ServerOptions d;
  std::string s = "usage: geomfit-server [--flag=value ...]\n       geomfit-server --version\n";
  for (const Flag& f : Flags()) absl::StrAppend(&s, "  --", f.name, "  (", EnvName(f.name), ")  ", f.help, "\n");
  absl::StrAppend(&s, "defaults: --host=", d.host, " --port=", d.port, " --store=", d.store, " --data-dir=", d.data_dir,
                  " --cache-bytes=", d.cache_bytes, " --max-message-bytes=", d.max_message_bytes,
                  " --max-vertices=", d.max_vertices, " --workers=", d.workers, " --drain-seconds=",
                  d.drain_seconds, " --chunk-bytes=", d.chunk_bytes, "\n");
  return s;
}

absl::StatusOr<ServerOptions> ParseServerOptions(const std::vector<std::string>& args) {
  ServerOptions o;
  for (const Flag& f : Flags()) {
    const std::string env = EnvName(f.name);
    if (const char* v = std::getenv(env.c_str()); v != nullptr && *v != '\0') {
      absl::Status s = f.set(v, &o);
      if (!s.ok()) return absl::InvalidArgumentError(absl::StrCat(env, ": ", s.message()));
    }
  }
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (a == "--help" || a == "-h") return absl::NotFoundError(ServerUsage());
    if (!absl::StartsWith(a, "--")) return absl::InvalidArgumentError("unexpected argument '" + a + "'");
    std::string name = a.substr(2), value;
    if (const size_t eq = name.find('='); eq != std::string::npos) {
      value = name.substr(eq + 1);
      name.resize(eq);
    } else if (i + 1 < args.size()) {
      value = args[++i];
    } else {
      return absl::InvalidArgumentError("--" + name + ": missing value");
    }
    const Flag* f = Find(name);
    if (f == nullptr) return absl::InvalidArgumentError("unknown flag --" + name + " (see --help)");
    GF_RETURN_IF_ERROR(f->set(value, &o));
  }
  if (o.tls_cert.empty() != o.tls_key.empty()) return absl::InvalidArgumentError("--tls-cert and --tls-key go together");
  if (!o.tls_client_ca.empty() && o.tls_cert.empty())
    return absl::InvalidArgumentError("--tls-client-ca needs --tls-cert and --tls-key");
  return o;
}

}  // namespace geomfit::server
