#include "clients/cpp/cli/run_heap.h"

#include <algorithm>
#include <cstdint>
#include <cstdlib>

#if defined(__linux__) && defined(__GLIBC__)
#include <malloc.h>
#include <sys/mman.h>
#include <time.h>
#define GEOMFIT_RUN_HEAP 1
#endif

namespace geomfit::cli {
namespace {

#if defined(GEOMFIT_RUN_HEAP)
#ifndef MADV_POPULATE_WRITE
#define MADV_POPULATE_WRITE 23  // Linux 5.14; older kernels refuse it (EINVAL)
#endif

constexpr size_t kHuge = size_t{2} << 20;
constexpr size_t kBlock = size_t{30} << 20;  // below the 32 MB mmap threshold
constexpr int kMaxBlocks = 64;

double ThreadCpuMs() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec * 1e3 + t.tv_nsec * 1e-6;
}
#endif

}  // namespace

void RunHeap::Reserve(size_t bytes) {
#if defined(GEOMFIT_RUN_HEAP)
  if (begin_ != nullptr || bytes == 0) return;
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
  // Blocks below the mmap threshold come from the heap's top, one after the other;
  // freed, they merge into its top chunk, from which later allocations are carved
  // upwards.
  const int blocks = static_cast<int>(std::min<size_t>(kMaxBlocks, (bytes + kHuge + kBlock - 1) / kBlock));
  void* held[kMaxBlocks];
  int n = 0;
  uintptr_t lo = UINTPTR_MAX, hi = 0;
  for (; n < blocks; ++n) {
    if ((held[n] = std::malloc(kBlock)) == nullptr) break;
    lo = std::min(lo, reinterpret_cast<uintptr_t>(held[n]));
    hi = std::max(hi, reinterpret_cast<uintptr_t>(held[n]) + kBlock);
  }
  lo = (lo + kHuge - 1) & ~(kHuge - 1);
  hi &= ~(kHuge - 1);
  // Consecutive (else the heap could not grow in place: keep glibc's behaviour).
  if (n > 0 && hi > lo && hi - lo <= static_cast<size_t>(n) * (kBlock + 4096) &&
      madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_HUGEPAGE) == 0) {
    begin_ = reinterpret_cast<char*>(lo);
    stats_.reserved = hi - lo;
  }
  for (int i = 0; i < n; ++i) std::free(held[i]);
#else
  (void)bytes;
#endif
}

void RunHeap::Commit(size_t bytes) {
#if defined(GEOMFIT_RUN_HEAP)
  const size_t target = std::min((bytes + kHuge - 1) & ~(kHuge - 1), stats_.reserved);
  if (stats_.committed >= target) return;
  const double start = ThreadCpuMs();
  while (stats_.committed < target) {
    char* p = begin_ + stats_.committed;
    if (stats_.small_pages) {
      if (madvise(p, target - stats_.committed, MADV_POPULATE_WRITE) != 0) break;
      stats_.committed = target;
      break;
    }
    const double t = ThreadCpuMs();
    if (madvise(p, kHuge, MADV_POPULATE_WRITE) != 0) break;  // then pages fault in on use
    stats_.committed += kHuge;
    stats_.huge_bytes += kHuge;
    if (ThreadCpuMs() - t > slow_ms_ && stats_.committed < stats_.reserved) {
      stats_.small_pages = true;
      madvise(p + kHuge, stats_.reserved - stats_.committed, MADV_NOHUGEPAGE);
    }
  }
  stats_.commit_ms += ThreadCpuMs() - start;
#else
  (void)bytes;
#endif
}

}  // namespace geomfit::cli
