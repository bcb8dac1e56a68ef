#include "server/request_stats.h"

#include <algorithm>

namespace geomfit::server {

const std::vector<double>& RequestStats::BucketsMs() {
  static const auto* b = new std::vector<double>{0.1, 0.25, 0.5, 1, 2.5, 5, 10, 25, 50, 100,
                                                 250, 500, 1000, 2500, 5000, 10000, 30000,
                                                 60000, 120000, 300000, 600000};
  return *b;
}

void RequestStats::Record(const std::string& method, const std::string& code, bool ok, double ms) {
  const auto& bounds = BucketsMs();
  const size_t bucket = std::lower_bound(bounds.begin(), bounds.end(), ms) - bounds.begin();
  std::lock_guard<std::mutex> lock(mu_);
  Method& m = methods_[method];
  if (m.buckets.empty()) m.buckets.assign(bounds.size() + 1, 0);
  ++m.count;
  m.errors += ok ? 0 : 1;
  m.total_ms += ms;
  m.max_ms = std::max(m.max_ms, ms);
  ++m.buckets[bucket];
  ++m.codes[code];
}

std::map<std::string, RequestStats::Method> RequestStats::Snapshot() const {
  std::lock_guard<std::mutex> lock(mu_);
  return methods_;
}

}  // namespace geomfit::server
