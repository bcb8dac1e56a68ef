#pragma once
#include <array>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace geomfit::server {

/// Per-method request counts and latency histograms: the single source of
/// GetStatistics and the Prometheus exposition.
class RequestStats {
 public:
  /// Upper bounds (ms) of the latency buckets, 0.1 ms to 10 min (a 480k-vertex
  /// degree-6 fit takes ~40 s); a final +inf bucket is implied.
  static const std::vector<double>& BucketsMs();

  struct Method {
    int64_t count = 0, errors = 0;
    double total_ms = 0, max_ms = 0;
    std::vector<int64_t> buckets;  ///< non-cumulative, BucketsMs().size() + 1 entries
    std::map<std::string, int64_t> codes;  ///< status code name -> count
  };

  void Record(const std::string& method, const std::string& code, bool ok, double ms);
  std::map<std::string, Method> Snapshot() const;

 private:
  mutable std::mutex mu_;
  std::map<std::string, Method> methods_;
};

}  // namespace geomfit::server
