#pragma once
#include <algorithm>
#include <cstdint>

#include <omp.h>

#include <atomic>
#include <memory>

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

/// Chunks [0, chunks) in contiguous shares, one per thread: thread t owns
/// [chunks * t / threads, chunks * (t + 1) / threads) and takes its chunks in order (the
/// next chunk's data neighbour this one's: a thread's prefetches of its next chunk and
/// its cache serve itself, not the other thread); a thread done with its share takes
/// the others' remaining chunks from their far end, so a slower or descheduled thread
/// still ends with the team. Each share's [front, back) is one atomic word: every chunk
/// is handed out exactly once.
class ChunkShares {
 public:
  ChunkShares(int64_t chunks, int threads) : threads_(threads), shares_(new Share[threads]) {
    for (int t = 0; t < threads; ++t)
      shares_[t].range.store(Pack(chunks * t / threads, chunks * (t + 1) / threads), std::memory_order_relaxed);
  }
  /// Thread t's next chunk, or -1 once every chunk is handed out.
  int64_t Next(int t) {
    if (const int64_t c = Take(t, true); c >= 0) return c;
    for (int k = 1; k < threads_; ++k)
      if (const int64_t c = Take((t + k) % threads_, false); c >= 0) return c;
    return -1;
  }

 private:
  struct alignas(64) Share {
    std::atomic<uint64_t> range;  // front << 32 | back
  };
  static uint64_t Pack(int64_t front, int64_t back) { return static_cast<uint64_t>(front) << 32 | static_cast<uint64_t>(back); }
  int64_t Take(int t, bool front) {
    std::atomic<uint64_t>& r = shares_[t].range;
    uint64_t cur = r.load(std::memory_order_relaxed);
    for (;;) {
      const int64_t f = static_cast<int64_t>(cur >> 32), b = static_cast<int64_t>(cur & 0xffffffffu);
      if (f >= b) return -1;
      if (r.compare_exchange_weak(cur, front ? Pack(f + 1, b) : Pack(f, b - 1), std::memory_order_relaxed))
        return front ? f : b - 1;
    }
  }
  int threads_;
  std::unique_ptr<Share[]> shares_;
};

/// Calls fn(begin, end) on the ranges of `grain` items covering [0, n), in parallel, the
/// chunks handed out by ChunkShares (one thread: in order). For per-range work whose
/// results do not depend on which thread runs a range; polls `ctx` between ranges as
/// ParallelFor does and reports `phase` progress in items.
template <typename Fn>
absl::Status ParallelForShares(int64_t n, int64_t grain, const RunContext& ctx, Fn&& fn, std::string_view phase = {}) {
  grain = std::max<int64_t>(1, grain);
  const int64_t chunks = (n + grain - 1) / grain;
  const int threads = static_cast<int>(std::min<int64_t>(ResolveThreads(ctx.threads()), std::max<int64_t>(1, chunks)));
  ChunkShares shares(chunks, threads);
  std::atomic<bool> stop{false};
  std::atomic<int64_t> done{0};
#pragma omp parallel num_threads(threads) if (threads > 1)
  {
    for (int64_t c; !stop.load(std::memory_order_relaxed) && (c = shares.Next(omp_get_thread_num())) >= 0;) {
      if (ctx.cancelled()) {
        stop.store(true, std::memory_order_relaxed);
        break;
      }
      const int64_t begin = c * grain, end = std::min(n, begin + grain);
      fn(begin, end);
      if (ctx.has_progress()) ctx.Report(phase, done += end - begin, n);
    }
  }
  if (!stop) return absl::OkStatus();
  absl::Status s = ctx.Check();
  return s.ok() ? absl::CancelledError("computation cancelled") : s;
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

