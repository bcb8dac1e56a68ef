#include "server/metrics.h"

#include <sys/resource.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>

#include "geomfit/version.h"

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

/// Boot time (seconds since the epoch): the "btime" line of /proc/stat.
double BootTimeSeconds() {
  std::ifstream in("/proc/stat");
  for (std::string key; in >> key;) {
    if (key == "btime") {
      double t = 0;
      in >> t;
      return t;
    }
    in.ignore(std::numeric_limits<std::streamsize>::max(), '\n');
  }
  return 0;
}

void AddGauge(std::vector<MetricFamily>* out, const char* name, const char* help, double value,
              MetricType type = MetricType::Gauge, std::vector<ClientMetric::Label> labels = {}) {
  MetricFamily f = Family(name, help, type);
  f.metric.push_back(Sample(std::move(labels), value, type));
  out->push_back(std::move(f));
}

}  // namespace

ProcessStats ReadProcessStats() {
  ProcessStats p;
  const double ticks = static_cast<double>(sysconf(_SC_CLK_TCK));
  const double page = static_cast<double>(sysconf(_SC_PAGESIZE));
  std::ifstream in("/proc/self/stat");
  std::string line;
  if (std::getline(in, line)) {
    // Fields after the command name, which is in parentheses and may hold spaces:
    // field 3 (state) onwards; utime 14, stime 15, starttime 22, vsize 23, rss 24.
    std::istringstream rest(line.substr(line.rfind(')') + 2));
    std::vector<std::string> f{"", "", ""};
    for (std::string x; rest >> x;) f.push_back(x);
    if (f.size() > 24) {
      p.cpu_seconds = (std::stod(f[14]) + std::stod(f[15])) / ticks;
      p.start_time_seconds = BootTimeSeconds() + std::stod(f[22]) / ticks;
      p.virtual_bytes = std::stod(f[23]);
      p.resident_bytes = std::stod(f[24]) * page;
    }
  }
  std::error_code ec;
  for (auto it = std::filesystem::directory_iterator("/proc/self/fd", ec); !ec && it != std::filesystem::end(it);
       it.increment(ec)) {
    p.open_fds += 1;
  }
  if (rlimit r{}; getrlimit(RLIMIT_NOFILE, &r) == 0) p.max_fds = static_cast<double>(r.rlim_cur);
  return p;
}

std::vector<MetricFamily> MetricsCollectable::Collect() const {
  std::vector<MetricFamily> out;
  const ProcessStats p = ReadProcessStats();
  AddGauge(&out, "process_cpu_seconds_total", "Total user and system CPU time spent in seconds.", p.cpu_seconds,
           MetricType::Counter);
  AddGauge(&out, "process_resident_memory_bytes", "Resident memory size in bytes.", p.resident_bytes);
  AddGauge(&out, "process_virtual_memory_bytes", "Virtual memory size in bytes.", p.virtual_bytes);
  AddGauge(&out, "process_open_fds", "Number of open file descriptors.", p.open_fds);
  AddGauge(&out, "process_max_fds", "Maximum number of open file descriptors.", p.max_fds);
  AddGauge(&out, "process_start_time_seconds", "Start time of the process since unix epoch in seconds.",
           p.start_time_seconds);
  AddGauge(&out, "geomfit_build_info", "geomfit version and git revision (value 1)", 1, MetricType::Gauge,
           {{"version", kVersion}, {"revision", kRevision}});
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
