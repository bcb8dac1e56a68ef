#pragma once
#include <chrono>

namespace geomfit {

/// Wall-clock stopwatch for --verbose timings and server latency logs.
class Stopwatch {
 public:
  Stopwatch() : start_(std::chrono::steady_clock::now()) {}
  double Seconds() const {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  }
  double Millis() const { return 1e3 * Seconds(); }

 private:
  std::chrono::steady_clock::time_point start_;
};

}  // namespace geomfit
