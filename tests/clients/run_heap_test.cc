// RunHeap (clients/cpp/cli/run_heap.h): what it reserves, backs and advises. Each
// check runs in a fresh process (a death test, "threadsafe" style: the binary run
// again), whose heap nothing has touched yet.
#include "clients/cpp/cli/run_heap.h"

#include <sys/mman.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace geomfit::cli {
namespace {

constexpr size_t kMB = size_t{1} << 20;

/// Runs `check` (returns "" or what failed) in a fresh process; fails with its message.
void InFreshProcess(const std::function<std::string()>& check) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        const std::string failed = check();
        std::fputs(failed.c_str(), stderr);
        std::_Exit(failed.empty() ? 0 : 1);
      },
      ::testing::ExitedWithCode(0), "");
}

/// Pages of [from, to) the kernel has in memory, with `flags` sized for them beforehand.
size_t Resident(const char* from, const char* to, std::vector<unsigned char>* flags) {
  const size_t page = static_cast<size_t>(sysconf(_SC_PAGESIZE));
  const uintptr_t lo = reinterpret_cast<uintptr_t>(from) & ~(page - 1);
  const size_t pages = (reinterpret_cast<uintptr_t>(to) - lo + page - 1) / page;
  if (flags->size() < pages || mincore(reinterpret_cast<void*>(lo), pages * page, flags->data()) != 0) return SIZE_MAX;
  size_t n = 0;
  for (size_t i = 0; i < pages; ++i) n += (*flags)[i] & 1;
  return n;
}

/// The "THPeligible" value of the mapping holding `at` in /proc/self/smaps (-1: none).
int ThpEligible(const char* at) {
  std::ifstream smaps("/proc/self/smaps");
  std::string line;
  bool in = false;
  while (std::getline(smaps, line)) {
    unsigned long lo, hi;
    char dash;
    std::istringstream head(line);
    if (line.find(':') > line.find(' ') && (head >> std::hex >> lo >> dash >> hi) && dash == '-') {
      in = reinterpret_cast<uintptr_t>(at) >= lo && reinterpret_cast<uintptr_t>(at) < hi;
    } else if (in && line.rfind("THPeligible:", 0) == 0) {
      return std::atoi(line.c_str() + 12);
    }
  }
  return -1;
}

/// Whether this kernel gives 2 MB pages to memory advised MADV_HUGEPAGE.
bool ThpOnAdvice() {
  std::ifstream f("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string mode;
  std::getline(f, mode);
  return !mode.empty() && mode.find("[never]") == std::string::npos;
}

std::string Fail(const std::string& what) { return what + "\n"; }

TEST(RunHeapTest, ReserveTouchesNothingAndKeepsEveryArrayOnTheHeap) {
  InFreshProcess([] {
    std::vector<unsigned char> flags(80 * kMB / 4096 + 2);
    RunHeap heap;
    heap.Reserve(64 * kMB);
    const size_t touched = Resident(heap.huge_begin(), heap.end(), &flags);  // before any allocation
    std::string failed;
    if (heap.stats().reserved < 64 * kMB) failed += Fail("reserved " + std::to_string(heap.stats().reserved));
    // The span starts at the page of the block's malloc header, its 2 MB part at the first
    // boundary past the block: exactly 2 MB apart when the (randomised) heap top sits in
    // the first page after a 2 MB boundary (about 1 run in 512).
    if (heap.begin() == nullptr || heap.huge_begin() < heap.begin() || heap.huge_begin() > heap.begin() + 2 * kMB ||
        reinterpret_cast<uintptr_t>(heap.huge_begin()) % (2 * kMB) != 0)
      failed += Fail("span not from the heap's top to a 2 MB boundary");
    if (touched != 0) failed += Fail(std::to_string(touched) + " pages of the span in memory before any use");
    if (heap.stats().committed != 0 || heap.stats().huge_bytes != 0) failed += Fail("committed without Commit");
    // 40 MB is above glibc's largest mmap threshold (32 MB): from the heap all the same,
    // and freed, the same memory again.
    char* a = static_cast<char*>(std::malloc(40 * kMB));
    std::memset(a, 1, 40 * kMB);
    if (a < heap.begin() || a + 40 * kMB > heap.end()) failed += Fail("a 40 MB array outside the span");
    std::free(a);
    char* b = static_cast<char*>(std::malloc(40 * kMB));
    if (b != a) failed += Fail("a freed array's memory was not reused");
    std::free(b);
    return failed;
  });
}

TEST(RunHeapTest, CommitBacksTheSpanFromItsStartOnce) {
  InFreshProcess([] {
    std::vector<unsigned char> flags(40 * kMB / 4096 + 2);
    std::string failed;
    RunHeap unreserved;
    unreserved.Commit(8 * kMB);
    if (unreserved.stats().committed != 0) failed += Fail("committed without a reservation");
    RunHeap heap(/*slow_huge_page_ms=*/1e9);  // no page counts as slow
    heap.Reserve(32 * kMB);
    heap.Commit(9 * kMB);
    const RunHeapStats s = heap.stats();
    if (s.committed < 9 * kMB || s.committed > 11 * kMB) failed += Fail("committed " + std::to_string(s.committed));
    const char* to = heap.begin() + s.committed;
    if ((to - heap.huge_begin()) % (2 * kMB) != 0) failed += Fail("not whole 2 MB pages beyond the boundary");
    if (s.huge_bytes != static_cast<size_t>(to - heap.huge_begin()) || s.small_pages)
      failed += Fail("not all in 2 MB pages: " + std::to_string(s.huge_bytes));
    const size_t pages = (to - heap.begin()) / 4096;
    if (Resident(heap.begin(), to, &flags) != pages) failed += Fail("committed pages not in memory");
    if (Resident(to, heap.end(), &flags) != 0) failed += Fail("pages beyond the committed part in memory");
    heap.Commit(4 * kMB);  // already backed
    if (heap.stats().committed != s.committed) failed += Fail("a smaller Commit changed the committed part");
    heap.Commit(size_t{1} << 40);
    if (heap.stats().committed != heap.stats().reserved) failed += Fail("Commit beyond the span not clamped");
    if (ThpEligible(heap.huge_begin()) != (ThpOnAdvice() ? 1 : 0)) failed += Fail("span not advised for 2 MB pages");
    return failed;
  });
}

TEST(RunHeapTest, ASlowHugePageTurnsTheRestToSmallPages) {
  InFreshProcess([] {
    std::vector<unsigned char> flags(40 * kMB / 4096 + 2);
    std::string failed;
    RunHeap heap(/*slow_huge_page_ms=*/-1);  // every 2 MB page counts as slow
    heap.Reserve(32 * kMB);
    heap.Commit(16 * kMB);
    const RunHeapStats s = heap.stats();
    if (!s.small_pages) failed += Fail("still 2 MB pages after a slow one");
    if (s.huge_bytes != 2 * kMB) failed += Fail("2 MB pages: " + std::to_string(s.huge_bytes));
    if (s.committed < 16 * kMB || s.committed > 18 * kMB) failed += Fail("committed " + std::to_string(s.committed));
    const char* to = heap.begin() + s.committed;
    if (Resident(heap.begin(), to, &flags) != static_cast<size_t>(to - heap.begin()) / 4096)
      failed += Fail("committed pages not in memory");
    // The first 2 MB page keeps the advice, the rest of the span has lost it.
    if (ThpEligible(heap.huge_begin()) != (ThpOnAdvice() ? 1 : 0)) failed += Fail("first 2 MB page not advised");
    if (ThpEligible(to - 1) != 0 || ThpEligible(heap.end() - 1) != 0) failed += Fail("rest still eligible for 2 MB pages");
    heap.Commit(24 * kMB);
    if (heap.stats().huge_bytes != 2 * kMB || heap.stats().committed < 24 * kMB) failed += Fail("second Commit");
    return failed;
  });
}

}  // namespace
}  // namespace geomfit::cli
