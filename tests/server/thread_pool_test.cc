#include "server/thread_pool.h"

#include <atomic>
#include <chrono>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "tests/server/test_util.h"

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

using testing::Gate;

TEST(ThreadPoolTest, TenantsAreServedInTurn) {
  ThreadPool pool(1, 1000);
  Gate gate;
  ASSERT_TRUE(pool.Submit("a", gate.Task()).ok());
  gate.AwaitStart();
  std::mutex mu;
  std::vector<std::string> order;
  auto task = [&](std::string name) {
    return [&, name] {
      std::lock_guard<std::mutex> lock(mu);
      order.push_back(name);
    };
  };
  // a's backlog of five is queued before b's two, yet b waits for one of a's at most.
  for (int i = 1; i <= 5; ++i) ASSERT_TRUE(pool.Submit("a", task("a" + std::to_string(i))).ok());
  for (int i = 1; i <= 2; ++i) ASSERT_TRUE(pool.Submit("b", task("b" + std::to_string(i))).ok());
  EXPECT_EQ(pool.Active("a"), 6);
  EXPECT_EQ(pool.Active("b"), 2);
  gate.Open();
  pool.Stop();
  EXPECT_EQ(order, (std::vector<std::string>{"a1", "b1", "a2", "b2", "a3", "a4", "a5"}));
  EXPECT_EQ(pool.Active("a"), 0);
  EXPECT_EQ(pool.Active("b"), 0);
}

TEST(ThreadPoolTest, AFullQueueStillAdmitsATenantBelowItsShare) {
  ThreadPool pool(1, 4, microseconds(0), "compute");
  Gate gate;
  ASSERT_TRUE(pool.Submit("a", gate.Task()).ok());
  gate.AwaitStart();
  for (int i = 0; i < 4; ++i) ASSERT_TRUE(pool.Submit("a", [] {}).ok());
  const absl::Status full = pool.Submit("a", [] {});
  EXPECT_EQ(full.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_NE(full.message().find("the compute queue is full (--queue)"), std::string::npos) << full;
  // b's share of the queue, with a and b waiting, is 4 / 2.
  EXPECT_TRUE(pool.Submit("b", [] {}).ok());
  EXPECT_TRUE(pool.Submit("b", [] {}).ok());
  EXPECT_EQ(pool.Submit("b", [] {}).code(), absl::StatusCode::kResourceExhausted);
  gate.Open();
  pool.Stop();
  EXPECT_EQ(pool.Submit("b", [] {}).code(), absl::StatusCode::kUnavailable);
}

}  // namespace
}  // namespace geomfit::server
