#pragma once
// How to run a computation, apart from what to compute (the Options structs): threads,
// cancellation (caller, deadline, shutdown) and progress. Every loop that can run longer
// than ~10 ms polls it; kernels that cannot fail take only `threads()`.
#include <cstdint>
#include <functional>
#include <string_view>
#include <utility>

#include "absl/status/status.h"
#include "core/util/cancel.h"

namespace geomfit {

/// Progress of one phase of a computation: `done` of `total` units (vertices, faces,
/// points, steps); total 0 when unknown.
struct Progress {
  std::string_view phase;
  int64_t done = 0;
  int64_t total = 0;
};

class RunContext {
 public:
  using ProgressFn = std::function<void(const Progress&)>;

  /// All cores, never cancelled, no progress.
  RunContext() = default;
  /// `cancel` (may be null) must outlive the context and its copies.
  explicit RunContext(const CancellationToken* cancel, int threads = 0, ProgressFn progress = nullptr)
      : cancel_(cancel), threads_(threads), progress_(std::move(progress)) {}

  /// Threads for parallel loops; 0 = all cores. Results never depend on it.
  int threads() const { return threads_; }
  const CancellationToken* token() const { return cancel_; }

  /// OK, or CANCELLED / DEADLINE_EXCEEDED naming what stopped the work.
  absl::Status Check() const { return cancel_ ? cancel_->Check() : absl::OkStatus(); }
  bool cancelled() const { return cancel_ && cancel_->IsCancelled(); }

  /// Reports progress (from any thread; the callback must be thread-safe).
  void Report(std::string_view phase, int64_t done, int64_t total) const {
    if (progress_) progress_(Progress{phase, done, total});
  }
  bool has_progress() const { return static_cast<bool>(progress_); }

  RunContext WithThreads(int threads) const {
    RunContext c = *this;
    c.threads_ = threads;
    return c;
  }
  RunContext WithProgress(ProgressFn progress) const {
    RunContext c = *this;
    c.progress_ = std::move(progress);
    return c;
  }
  RunContext WithToken(const CancellationToken* cancel) const {
    RunContext c = *this;
    c.cancel_ = cancel;
    return c;
  }

 private:
  const CancellationToken* cancel_ = nullptr;
  int threads_ = 0;
  ProgressFn progress_;
};

}  // namespace geomfit
