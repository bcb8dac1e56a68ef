#pragma once
#include <atomic>
#include <chrono>
#include <functional>

#include "absl/status/status.h"

namespace geomfit {

/// Cooperative cancellation for long computations: set by a caller (RPC cancelled,
/// deadline passed, server draining), polled by kernels between chunks of work.
class CancellationToken {
 public:
  using Clock = std::chrono::steady_clock;
  CancellationToken() = default;
  explicit CancellationToken(Clock::time_point deadline) : deadline_(deadline), has_deadline_(true) {}

  void Cancel() { cancelled_.store(true, std::memory_order_relaxed); }
  /// An extra predicate polled by Check() (e.g. "the RPC was cancelled").
  void SetPoll(std::function<bool()> poll) { poll_ = std::move(poll); }

  bool IsCancelled() const {
    if (cancelled_.load(std::memory_order_relaxed)) return true;
    if (poll_ && poll_()) return true;
    return has_deadline_ && Clock::now() > deadline_;
  }
  /// OK, or CANCELLED / DEADLINE_EXCEEDED naming what stopped the work.
  absl::Status Check() const {
    if (cancelled_.load(std::memory_order_relaxed) || (poll_ && poll_()))
      return absl::CancelledError("computation cancelled");
    if (has_deadline_ && Clock::now() > deadline_)
      return absl::DeadlineExceededError("deadline exceeded during computation");
    return absl::OkStatus();
  }

 private:
  std::atomic<bool> cancelled_{false};
  std::function<bool()> poll_;
  Clock::time_point deadline_{};
  bool has_deadline_ = false;
};

}  // namespace geomfit
