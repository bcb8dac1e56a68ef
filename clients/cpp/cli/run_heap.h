#pragma once
// The process heap prepared for one in-process CLI run (`curvature --local`): freed
// memory stays with the process and the run's arrays come from memory backed ahead of
// use, in 2 MB pages while fresh ones come cheap, else in 4 KB pages.
#include <cstddef>

namespace geomfit::cli {

/// What a RunHeap did (tests, --verbose).
struct RunHeapStats {
  size_t reserved = 0;       ///< bytes of address space kept at the heap's top
  size_t committed = 0;      ///< bytes of it backed by memory, from its start
  size_t huge_bytes = 0;     ///< of `committed`, asked for as 2 MB pages
  bool small_pages = false;  ///< a 2 MB page came slowly: the rest in 4 KB pages
  double commit_ms = 0;      ///< thread CPU time spent backing memory
};

/// glibc on Linux; elsewhere every call does nothing. One per process at a time: it
/// sets malloc's process-wide options.
///
/// Why: a run allocates ~40-80 MB in phases; with glibc's defaults each phase's large
/// arrays are mmapped, unmapped when freed and faulted in again by the next phase
/// (tens of thousands of 4 KB faults). Reserve() keeps such arrays on the heap, never
/// trims it, and marks a span at its top for transparent huge pages (THP in `madvise`
/// mode). A fresh 2 MB page costs ~0.2 ms when the kernel has recently freed ones, but
/// ~4.5 ms on a VM whose host has taken back the guest's free memory (virtio-balloon
/// free page reporting returns free 2 MB blocks after ~2 s): the same binary then ran
/// 82 or 170 ms. Commit() backs the span ahead of use (MADV_POPULATE_WRITE), timing
/// each 2 MB page; once one takes longer than `slow_huge_page_ms` of thread CPU time
/// the rest of the span gets 4 KB pages (~0.7 ms per 2 MB, which the kernel takes from
/// its smaller free blocks).
class RunHeap {
 public:
  explicit RunHeap(double slow_huge_page_ms = 1.0) : slow_ms_(slow_huge_page_ms) {}
  RunHeap(const RunHeap&) = delete;
  RunHeap& operator=(const RunHeap&) = delete;

  /// Makes malloc take every array from the heap (none mmapped) and never trim it, and
  /// reserves at least `bytes` (at most 4 GB) of address space at its top, from its
  /// first 2 MB boundary on for 2 MB pages: nothing is touched. Once per RunHeap.
  void Reserve(size_t bytes);
  /// Backs the reservation's first `bytes` (clamped to it; beyond the 2 MB boundary,
  /// whole 2 MB pages) with memory; what is already backed is skipped. Allocations made after Reserve() are carved from the span's
  /// start upwards, so this is "the next `bytes` the run allocates".
  void Commit(size_t bytes);

  const RunHeapStats& stats() const { return stats_; }
  /// The reserved span [begin, end) (null when nothing was reserved) and its first
  /// 2 MB boundary.
  const char* begin() const { return begin_; }
  const char* end() const { return begin_ + stats_.reserved; }
  const char* huge_begin() const { return huge_; }

 private:
  const double slow_ms_;
  char* begin_ = nullptr;  ///< the span: from the top chunk's first page
  char* huge_ = nullptr;   ///< its first 2 MB boundary (2 MB pages from there)
  char* next_ = nullptr;   ///< the first byte not committed
  bool ok_ = true;         ///< MADV_POPULATE_WRITE works (Linux 5.14+)
  RunHeapStats stats_;
};

}  // namespace geomfit::cli
