#include "server/metrics.h"

#include <limits>
#include <string>

namespace geomfit::server {
namespace {

using prometheus::ClientMetric;
using prometheus::MetricFamily;
using prometheus::MetricType;

MetricFamily Family(const char* name, const char* help, MetricType type) {
  MetricFamily f;
  f.name = name;
  f.help = help;
  f.type = type;
  return f;
}

ClientMetric Sample(std::vector<ClientMetric::Label> labels, double value, MetricType type) {
  ClientMetric m;
  m.label = std::move(labels);
  if (type == MetricType::Counter) m.counter.value = value;
  else m.gauge.value = value;
  return m;
}

}  // namespace

std::vector<MetricFamily> MetricsCollectable::Collect() const {
  std::vector<MetricFamily> out;
  MetricFamily requests = Family("geomfit_requests_total", "RPCs handled, by method and status code",
                                 MetricType::Counter);
  MetricFamily latency = Family("geomfit_request_duration_seconds", "RPC latency by method", MetricType::Histogram);
  for (const auto& [method, m] : stats_->Snapshot()) {
    for (const auto& [code, n] : m.codes)
      requests.metric.push_back(Sample({{"method", method}, {"code", code}}, static_cast<double>(n),
                                       MetricType::Counter));
    ClientMetric h;
    h.label = {{"method", method}};
    h.histogram.sample_count = static_cast<uint64_t>(m.count);
    h.histogram.sample_sum = m.total_ms / 1e3;
    uint64_t cumulative = 0;
    const auto& bounds = RequestStats::BucketsMs();
    for (size_t i = 0; i < m.buckets.size(); ++i) {
      cumulative += static_cast<uint64_t>(m.buckets[i]);
      const double upper = i < bounds.size() ? bounds[i] / 1e3 : std::numeric_limits<double>::infinity();
      h.histogram.bucket.push_back({cumulative, upper});
    }
    latency.metric.push_back(std::move(h));
  }
  out.push_back(std::move(requests));
  out.push_back(std::move(latency));

  MetricFamily bytes = Family("geomfit_cache_bytes", "bytes held per cache tier", MetricType::Gauge);
  MetricFamily entries = Family("geomfit_cache_entries", "entries per cache tier", MetricType::Gauge);
  MetricFamily hits = Family("geomfit_cache_hits_total", "cache hits per tier", MetricType::Counter);
  MetricFamily misses = Family("geomfit_cache_misses_total", "cache misses per tier", MetricType::Counter);
  MetricFamily evictions = Family("geomfit_cache_evictions_total", "cache evictions per tier", MetricType::Counter);
  for (Tier tier : {Tier::kTopology, Tier::kGeometry, Tier::kFitting}) {
    const TierStats t = cache_->Stats(tier);
    const std::vector<ClientMetric::Label> label = {{"tier", TierName(tier)}};
    bytes.metric.push_back(Sample(label, static_cast<double>(t.bytes), MetricType::Gauge));
    entries.metric.push_back(Sample(label, static_cast<double>(t.entries), MetricType::Gauge));
    hits.metric.push_back(Sample(label, static_cast<double>(t.hits), MetricType::Counter));
    misses.metric.push_back(Sample(label, static_cast<double>(t.misses), MetricType::Counter));
    evictions.metric.push_back(Sample(label, static_cast<double>(t.evictions), MetricType::Counter));
  }
  MetricFamily budget = Family("geomfit_cache_budget_bytes", "cache byte budget", MetricType::Gauge);
  budget.metric.push_back(Sample({}, static_cast<double>(cache_->budget()), MetricType::Gauge));
  const StoreStats store = store_->Stats();
  MetricFamily meshes = Family("geomfit_store_meshes", "meshes in the store", MetricType::Gauge);
  meshes.metric.push_back(Sample({}, static_cast<double>(store.meshes), MetricType::Gauge));
  MetricFamily store_bytes = Family("geomfit_store_bytes", "bytes of the store", MetricType::Gauge);
  store_bytes.metric.push_back(Sample({}, static_cast<double>(store.bytes), MetricType::Gauge));
  for (MetricFamily* f : {&bytes, &entries, &hits, &misses, &evictions, &budget, &meshes, &store_bytes})
    out.push_back(std::move(*f));
  return out;
}

}  // namespace geomfit::server
