#include "server/thread_pool.h"

#include <atomic>
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

namespace geomfit::server {
namespace {

using std::chrono::microseconds;

TEST(ThreadPoolTest, EveryTaskRunsWhetherWorkersSpinOrSleep) {
  for (const int spin_us : {0, 200, 1'000'000}) {
    SCOPED_TRACE(spin_us);
    ThreadPool pool(2, 100'000, microseconds(spin_us));
    std::atomic<int> ran{0};
    // Two submitters, with pauses so that submissions meet spinning, parked and busy workers.
    auto submit = [&] {
      for (int i = 0; i < 2000; ++i) {
        ASSERT_TRUE(pool.TrySubmit([&] { ran.fetch_add(1); }));
        if (i % 200 == 0) std::this_thread::sleep_for(microseconds(300));
      }
    };
    std::thread a(submit), b(submit);
    a.join();
    b.join();
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (ran.load() < 4000 && std::chrono::steady_clock::now() < deadline) std::this_thread::yield();
    EXPECT_EQ(ran.load(), 4000);
    // A worker spinning (for up to a second) stops spinning when the pool stops.
    const auto stop_start = std::chrono::steady_clock::now();
    pool.Stop();
    EXPECT_LT(std::chrono::steady_clock::now() - stop_start, std::chrono::milliseconds(500));
    EXPECT_FALSE(pool.TrySubmit([] {})) << "a stopped pool takes no task";
  }
}

TEST(ThreadPoolTest, AFullQueueRefuses) {
  ThreadPool pool(1, 1, microseconds(1000));
  std::atomic<bool> release{false};
  ASSERT_TRUE(pool.TrySubmit([&] {
    while (!release) std::this_thread::yield();
  }));
  // The worker is busy: one task waits in the queue, the next is refused.
  while (!pool.TrySubmit([] {})) std::this_thread::yield();
  EXPECT_FALSE(pool.TrySubmit([] {}));
  release = true;
}

}  // namespace
}  // namespace geomfit::server
