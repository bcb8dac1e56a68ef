#pragma once
#include <vector>

#include <prometheus/collectable.h>
#include <prometheus/metric_family.h>

#include "server/workspace/cache.h"
#include "server/mesh_store.h"
#include "server/request_stats.h"

namespace geomfit::server {

/// Prometheus view of the server's own statistics, built at scrape time (so
/// GetStatistics and /metrics can never disagree): request counters and latency
/// histograms per method, cache bytes/entries/hits/misses/evictions per tier, store
/// size.
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
