#include "clients/cpp/cli/run_heap.h"

#include <algorithm>
#include <climits>
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

constexpr size_t kHuge = size_t{2} << 20, kSmall = 4096;
constexpr size_t kMaxReserve = size_t{4} << 30;

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
  // Every allocation from the heap (none mmapped, whatever its size); nothing given back.
  mallopt(M_MMAP_MAX, 0);
  mallopt(M_TRIM_THRESHOLD, INT_MAX);
  // One block from the heap's top: malloc writes headers just below and above it, so
  // no page from its first 2 MB boundary on is touched (a touched 4 KB page would keep
  // its 2 MB page from being huge). Freed, it merges into the top chunk, from which
  // later allocations are carved upwards: from its header's page on.
  bytes = std::min(bytes, kMaxReserve);
  char* block = static_cast<char*>(std::malloc(bytes + 2 * kHuge));
  if (block == nullptr) return;
  const uintptr_t at = reinterpret_cast<uintptr_t>(block);
  const uintptr_t lo = (at + kHuge - 1) & ~(kHuge - 1), hi = (at + bytes + 2 * kHuge) & ~(kHuge - 1);
  if (madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_HUGEPAGE) == 0) {
    begin_ = next_ = reinterpret_cast<char*>((at - 2 * sizeof(size_t)) & ~(kSmall - 1));
    huge_ = reinterpret_cast<char*>(lo);
    stats_.reserved = hi - reinterpret_cast<uintptr_t>(begin_);
  }
  std::free(block);
#else
  (void)bytes;
#endif
}

void RunHeap::Commit(size_t bytes) {
#if defined(GEOMFIT_RUN_HEAP)
  char* const end = begin_ + stats_.reserved;
  char* target = begin_ + std::min(bytes, stats_.reserved);
  if (target > huge_) target = huge_ + ((target - huge_ + kHuge - 1) & ~(kHuge - 1));
  if (next_ >= target || !ok_) return;
  const double start = ThreadCpuMs();
  // Below the first 2 MB boundary: the heap's older part, small pages.
  if (next_ < huge_) {
    char* const to = std::min(huge_, target);
    ok_ = madvise(next_, to - next_, MADV_POPULATE_WRITE) == 0;
    if (ok_) next_ = to;
  }
  while (ok_ && next_ < target) {
    if (stats_.small_pages) {
      ok_ = madvise(next_, target - next_, MADV_POPULATE_WRITE) == 0;
      if (ok_) next_ = target;
      break;
    }
    const double t = ThreadCpuMs();
    ok_ = madvise(next_, kHuge, MADV_POPULATE_WRITE) == 0;  // else pages fault in on use
    if (!ok_) break;
    next_ += kHuge;
    stats_.huge_bytes += kHuge;
    if (ThreadCpuMs() - t > slow_ms_ && next_ < end) {
      stats_.small_pages = true;
      madvise(next_, end - next_, MADV_NOHUGEPAGE);
    }
  }
  stats_.committed = next_ - begin_;
  stats_.commit_ms += ThreadCpuMs() - start;
#else
  (void)bytes;
#endif
}

}  // namespace geomfit::cli
