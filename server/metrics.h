#pragma once
#include <vector>

#include <prometheus/collectable.h>
#include <prometheus/metric_family.h>

#include "server/workspace/cache.h"
#include "server/mesh_store.h"
#include "server/request_stats.h"

namespace geomfit::server {

/// This process's resources as Prometheus's process_* metrics report them, read from
/// /proc/self (Linux); fields stay 0 where /proc is unreadable.
struct ProcessStats {
  double cpu_seconds = 0;         ///< user + system CPU time
  double resident_bytes = 0;      ///< resident set size
  double virtual_bytes = 0;
  double open_fds = 0;            ///< entries of /proc/self/fd
  double max_fds = 0;             ///< RLIMIT_NOFILE soft limit
  double start_time_seconds = 0;  ///< start time, seconds since the Unix epoch
};
ProcessStats ReadProcessStats();

/// Prometheus view of the server's own statistics, built at scrape time (so
/// GetStatistics and /metrics can never disagree): request counters and latency
/// histograms per method, cache bytes/entries/hits/misses/evictions per tier, store
/// size; plus process_* (ReadProcessStats) and geomfit_build_info{version,revision} 1.
class MetricsCollectable final : public prometheus::Collectable {
 public:
  MetricsCollectable(const RequestStats* stats, const Cache* cache, MeshStore* store)
      : stats_(stats), cache_(cache), store_(store) {}
  std::vector<prometheus::MetricFamily> Collect() const override;

 private:
  const RequestStats* stats_;
  const Cache* cache_;
  MeshStore* store_;
};

}  // namespace geomfit::server
