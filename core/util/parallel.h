#pragma once
#include <algorithm>
#include <cstdint>

#include <omp.h>

#include <atomic>

#include "absl/status/status.h"
#include "core/util/run_context.h"

namespace geomfit {

/// Number of threads to use: `requested` if positive, otherwise all available.
inline int ResolveThreads(int requested) {
  return requested > 0 ? requested : std::max(1, omp_get_max_threads());
}

/// Calls fn(begin, end, thread_index) on contiguous blocks covering [0, n), in parallel.
/// Blocks are a pure function of (n, threads), so per-item results never depend on the
/// schedule; callers that concatenate per-block output get the same order every time.
template <typename Fn>
void ParallelForBlocks(int64_t n, int threads, Fn&& fn) {
  threads = ResolveThreads(threads);
  if (n <= 0) return;
  const int64_t blocks = std::min<int64_t>(n, threads);
#pragma omp parallel for num_threads(threads) schedule(static, 1) if (blocks > 1)
  for (int64_t b = 0; b < blocks; ++b) {
    fn(n * b / blocks, n * (b + 1) / blocks, static_cast<int>(b));
  }
}

/// Calls fn(i) for each i in [0, n) in parallel, dynamically scheduled in chunks of
/// `grain` items. Use for independent per-item work (results must not depend on order).
template <typename Fn>
void ParallelFor(int64_t n, int threads, Fn&& fn, int64_t grain = 256) {
  threads = ResolveThreads(threads);
  grain = std::max<int64_t>(1, grain);
  const int64_t chunks = (n + grain - 1) / grain;
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (threads > 1 && chunks > 1)
  for (int64_t c = 0; c < chunks; ++c) {
    const int64_t end = std::min(n, (c + 1) * grain);
    for (int64_t i = c * grain; i < end; ++i) fn(i);
  }
}

/// ParallelFor on ctx.threads() that polls `ctx` between chunks: once it trips, the
/// remaining chunks are skipped and its status returned. Reports `phase` progress
/// (items done) when the context has a progress callback.
template <typename Fn>
absl::Status ParallelFor(int64_t n, const RunContext& ctx, Fn&& fn, int64_t grain = 256,
                         std::string_view phase = {}) {
  const int threads = ResolveThreads(ctx.threads());
  grain = std::max<int64_t>(1, grain);
  const int64_t chunks = (n + grain - 1) / grain;
  std::atomic<bool> stop{false};
  std::atomic<int64_t> done{0};
#pragma omp parallel for num_threads(threads) schedule(dynamic, 1) if (threads > 1 && chunks > 1)
  for (int64_t c = 0; c < chunks; ++c) {
    if (stop.load(std::memory_order_relaxed)) continue;
    if (ctx.cancelled()) {
      stop.store(true, std::memory_order_relaxed);
      continue;
    }
    const int64_t end = std::min(n, (c + 1) * grain);
    for (int64_t i = c * grain; i < end; ++i) fn(i);
    if (ctx.has_progress()) ctx.Report(phase, done += end - c * grain, n);
  }
  if (!stop) return absl::OkStatus();
  absl::Status s = ctx.Check();
  return s.ok() ? absl::CancelledError("computation cancelled") : s;
}

}  // namespace geomfit

