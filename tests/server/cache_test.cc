#include "server/workspace/cache.h"

#include <atomic>
#include <cctype>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

Cache::ComputeFn Value(int v, int64_t bytes, std::atomic<int>* calls = nullptr, int sleep_ms = 0) {
  return [=]() -> absl::StatusOr<Cache::Computed> {
    if (calls) ++*calls;
    if (sleep_ms) std::this_thread::sleep_for(std::chrono::milliseconds(sleep_ms));
    return Cache::Computed{std::make_shared<const int>(v), bytes};
  };
}

/// A key of tier `t` named like "<mesh>/r<N>/<rest>" (test shorthand; the engine builds
/// keys with keys.h and never parses them).
CacheKey K(Tier t, const std::string& name) {
  CacheKey k;
  const size_t slash = name.find('/');
  k.mesh_id = name.substr(0, slash);
  std::string rest = slash == std::string::npos ? "" : name.substr(slash + 1);
  if (rest.size() > 1 && rest[0] == 'r' && isdigit(rest[1])) {
    k.revision = std::stoll(rest.substr(1));
    rest = rest.substr(rest.find('/') == std::string::npos ? rest.size() : rest.find('/'));
  }
  k.kind = t == Tier::kTopology ? EntryKind::kTopology : t == Tier::kGeometry ? EntryKind::kGeometry : EntryKind::kFits;
  k.params.push_back(std::hash<std::string>()(rest));
  return k;
}

int Get(Cache& c, Tier t, const std::string& key, int v, int64_t bytes, bool* hit = nullptr) {
  auto r = c.GetOrCompute(K(t, key), Value(v, bytes), nullptr, hit);
  return r.ok() ? *std::static_pointer_cast<const int>(*r) : -1;
}

TEST(CacheTest, ConcurrentRequestsComputeOnce) {
  Cache cache(1 << 20);
  std::atomic<int> calls{0};
  std::vector<std::thread> threads;
  std::atomic<int> sum{0};
  for (int i = 0; i < 8; ++i) {
    threads.emplace_back([&] {
      auto r = cache.GetOrCompute(K(Tier::kFitting, "m/r1/fit/x"), Value(7, 10, &calls, 100));
      if (r.ok()) sum += *std::static_pointer_cast<const int>(*r);
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(calls.load(), 1);
  EXPECT_EQ(sum.load(), 56);
  EXPECT_EQ(cache.Stats(Tier::kFitting).misses, 1);
  EXPECT_EQ(cache.Stats(Tier::kFitting).hits, 7);
}

TEST(CacheTest, FittingsAreEvictedBeforeMeshes) {
  Cache cache(100);
  Get(cache, Tier::kTopology, "a/topo", 1, 30);
  Get(cache, Tier::kGeometry, "a/r1/geom", 2, 30);
  Get(cache, Tier::kFitting, "a/r1/fit/1", 3, 30);
  Get(cache, Tier::kFitting, "a/r1/fit/2", 4, 30);  // over budget: oldest fitting goes
  EXPECT_EQ(cache.bytes(), 90);
  EXPECT_EQ(cache.Stats(Tier::kFitting).evictions, 1);
  EXPECT_EQ(cache.Stats(Tier::kGeometry).evictions, 0);
  bool hit = false;
  Get(cache, Tier::kFitting, "a/r1/fit/2", 4, 30, &hit);
  EXPECT_TRUE(hit);
  Get(cache, Tier::kFitting, "a/r1/fit/1", 3, 30, &hit);
  EXPECT_FALSE(hit);
  Get(cache, Tier::kGeometry, "b/r1/geom", 5, 60);  // needs both fittings gone, then a mesh
  EXPECT_LE(cache.bytes(), 100);
  EXPECT_EQ(cache.Stats(Tier::kFitting).entries, 0);
  EXPECT_EQ(cache.Stats(Tier::kTopology).entries, 1);
}

TEST(CacheTest, LeastRecentlyUsedGoesFirst) {
  Cache cache(100);
  Get(cache, Tier::kFitting, "f1", 1, 40);
  Get(cache, Tier::kFitting, "f2", 2, 40);
  bool hit = false;
  Get(cache, Tier::kFitting, "f1", 1, 40, &hit);  // touch f1
  ASSERT_TRUE(hit);
  Get(cache, Tier::kFitting, "f3", 3, 40);
  Get(cache, Tier::kFitting, "f1", 1, 40, &hit);
  EXPECT_TRUE(hit);
  Get(cache, Tier::kFitting, "f2", 2, 40, &hit);
  EXPECT_FALSE(hit);
}

TEST(CacheTest, ValueLargerThanBudgetIsReturnedNotKept) {
  Cache cache(100);
  EXPECT_EQ(Get(cache, Tier::kFitting, "big", 9, 1000), 9);
  EXPECT_EQ(cache.bytes(), 0);
}

/// A computation that holds until `gate` opens, then returns `result`.
Cache::ComputeFn HeldUntil(testing::Gate* gate, absl::StatusOr<Cache::Computed> result, std::atomic<int>* calls) {
  return [=]() {
    ++*calls;
    gate->Task()();
    return result;
  };
}

// Synchronised on events, not sleeps: the leader computes until the waiter is waiting
// (its token is polled in the wait loop), whatever the load.
TEST(CacheTest, ErrorsAreNotCachedAndCancelledLeaderDoesNotFailWaiters) {
  Cache cache(1 << 20);
  std::atomic<int> calls{0};
  testing::Gate gate;
  std::thread leader([&] {
    EXPECT_FALSE(
        cache.GetOrCompute(K(Tier::kFitting, "k"), HeldUntil(&gate, absl::CancelledError("leader cancelled"), &calls))
            .ok());
  });
  gate.AwaitStart();
  CancellationToken waiting;  // never trips: its poll says the waiter waits
  waiting.SetPoll([&] {
    gate.Open();
    return false;
  });
  auto r = cache.GetOrCompute(K(Tier::kFitting, "k"), Value(5, 1, &calls), &waiting);
  leader.join();
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ(*std::static_pointer_cast<const int>(*r), 5);
  EXPECT_EQ(calls.load(), 2);
}

TEST(CacheTest, WaiterGivesUpWithItsOwnToken) {
  Cache cache(1 << 20);
  std::atomic<int> calls{0};
  testing::Gate gate;  // the leader computes until the waiter gave up
  const Cache::Computed one{std::make_shared<const int>(1), 1};
  std::thread leader(
      [&] { EXPECT_TRUE(cache.GetOrCompute(K(Tier::kFitting, "slow"), HeldUntil(&gate, one, &calls)).ok()); });
  gate.AwaitStart();
  CancellationToken token(CancellationToken::Clock::now() + std::chrono::milliseconds(30));
  auto r = cache.GetOrCompute(K(Tier::kFitting, "slow"), Value(2, 1, &calls), &token);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kDeadlineExceeded);
  gate.Open();
  leader.join();
  EXPECT_EQ(calls.load(), 1) << "the waiter did not compute";
}

TEST(CacheTest, RetiredRevisionsAreDroppedAndKeptOut) {
  Cache cache(1 << 20);
  for (const char* key : {"m/r1/fit/a", "m/r2/fit/a", "m/r2/fit/a/q3", "m/r3/fit/a", "m/topo", "n/r1/fit/a"})
    cache.Put(K(Tier::kFitting, key), std::make_shared<const int>(1), 10);
  cache.RetireRevisionsBelow("m", 3);
  bool hit = false;
  EXPECT_EQ(Get(cache, Tier::kFitting, "m/r3/fit/a", 2, 10, &hit), 1);
  EXPECT_TRUE(hit) << "the live revision stays";
  EXPECT_EQ(Get(cache, Tier::kFitting, "m/topo", 2, 10, &hit), 1);
  EXPECT_TRUE(hit) << "revision-free entries stay";
  EXPECT_EQ(Get(cache, Tier::kFitting, "n/r1/fit/a", 2, 10, &hit), 1);
  EXPECT_TRUE(hit) << "other meshes stay";
  EXPECT_EQ(cache.Stats(Tier::kFitting).entries, 3);
  // A computation for a retired revision still answers its caller, but is not kept.
  EXPECT_EQ(Get(cache, Tier::kFitting, "m/r2/fit/a", 5, 10, &hit), 5);
  EXPECT_FALSE(hit);
  EXPECT_EQ(Get(cache, Tier::kFitting, "m/r2/fit/a", 6, 10, &hit), 6);
  EXPECT_FALSE(hit);
  EXPECT_EQ(cache.bytes(), 30);
  // A deleted mesh may come back at revision 1.
  cache.EraseMesh("m");
  EXPECT_EQ(cache.Stats(Tier::kFitting).entries, 1);
  cache.Put(K(Tier::kFitting, "m/r1/fit/a"), std::make_shared<const int>(7), 10);
  EXPECT_EQ(Get(cache, Tier::kFitting, "m/r1/fit/a", 2, 10, &hit), 7);
  EXPECT_TRUE(hit);
}

TEST(CacheTest, EraseMeshDropsOneMesh) {
  Cache cache(1000);
  Get(cache, Tier::kTopology, "a/topo", 1, 10);
  Get(cache, Tier::kGeometry, "a/r1/geom", 1, 10);
  Get(cache, Tier::kGeometry, "ab/r1/geom", 1, 10);
  cache.EraseMesh("a");
  EXPECT_EQ(cache.bytes(), 10);
  bool hit = false;
  Get(cache, Tier::kGeometry, "ab/r1/geom", 1, 10, &hit);
  EXPECT_TRUE(hit);
}

// A value Put while the same key is being computed (a prefetch racing a request): the
// computed value replaces it and the accounting holds one entry; eviction later walks a
// consistent LRU list (it used to meet a node whose entry was gone and crash).
TEST(CacheTest, ValuePutDuringItsComputationIsReplacedOnce) {
  Cache cache(100);
  const CacheKey key = K(Tier::kFitting, "a/r1/fit");
  auto r = cache.GetOrCompute(key, [&]() -> absl::StatusOr<Cache::Computed> {
    cache.Put(key, std::make_shared<const int>(1), 30);
    return Cache::Computed{std::make_shared<const int>(2), 40};
  });
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(cache.bytes(), 40);
  EXPECT_EQ(cache.Stats(Tier::kFitting).entries, 1);
  for (int i = 0; i < 5; ++i) Get(cache, Tier::kFitting, "b/r1/fit" + std::to_string(i), i, 40);
  EXPECT_LE(cache.bytes(), 100);
  EXPECT_EQ(cache.Stats(Tier::kFitting).entries, 2);
}

TEST(CacheKeyTest, TypedKeysDoNotAlias) {
  // The case: min_points_factor 1.5000001 must not share the default 1.5's fits.
  FitOptions a, b;
  a.min_points_factor = 1.5;
  b.min_points_factor = 1.5000001;
  EXPECT_NE(FitKey("m", 1, a, false), FitKey("m", 1, b, false));
  b = a;
  b.weight_epsilon = 0.01 * (1 + 1e-15);
  EXPECT_NE(FitKey("m", 1, a, false), FitKey("m", 1, b, false));
  EXPECT_NE(FitKey("m", 1, a, false), FitKey("m", 1, a, true));
  EXPECT_NE(FitKey("m", 1, a, false), FitKey("m", 2, a, false));
  // Automatic values resolve: rings 0 at degree 2 is rings 1.5.
  FitOptions c = a;
  c.rings = a.StartRings();
  EXPECT_EQ(FitKey("m", 1, a, false), FitKey("m", 1, c, false));
  EXPECT_NE(DifferentialsKey(FitKey("m", 1, a, false), 1), DifferentialsKey(FitKey("m", 1, a, false), 3));
  EXPECT_EQ(FitKey("m", 1, a, false).tier(), Tier::kFitting);
  EXPECT_EQ(NeighborhoodsKey("m", RingSpec()).tier(), Tier::kTopology);
  EXPECT_EQ(GeometryKey("m", 4).tier(), Tier::kGeometry);
}

}  // namespace
}  // namespace geomfit::server
