// The fit's and the quantities' scheduler (core/util/parallel.h, ChunkShares and
// ParallelForShares): every chunk handed out once, shares taken in order by their owner
// and from the far end by the others, results equal bit for bit for any thread count.
#include <atomic>
#include <cstring>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "core/fitting/fit.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "core/util/cancel.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

// Two threads, 10 chunks: shares [0, 5) and [5, 10). Thread 1 takes its own in order,
// then thread 0's from the back; thread 0's next is then the front chunk left to it.
TEST(ChunkSharesTest, OwnersGoForwardOthersTakeFromTheBack) {
  ChunkShares s(10, 2);
  EXPECT_EQ(s.Next(0), 0);
  std::vector<int64_t> one;
  for (int k = 0; k < 8; ++k) one.push_back(s.Next(1));
  EXPECT_EQ(one, (std::vector<int64_t>{5, 6, 7, 8, 9, 4, 3, 2}));
  EXPECT_EQ(s.Next(0), 1);
  EXPECT_EQ(s.Next(0), -1);
  EXPECT_EQ(s.Next(1), -1);
}

// Any interleaving of any number of threads over any number of chunks (fewer chunks than
// threads included) hands out every chunk exactly once, then -1 to everyone.
TEST(ChunkSharesTest, EveryChunkExactlyOnce) {
  for (int threads : {1, 2, 3, 7}) {
    for (int64_t chunks : {0, 1, 2, 5, 7, 64, 1001}) {
      for (int pattern = 0; pattern < 3; ++pattern) {  // round robin; thread 0 slow; thread 0 alone
        SCOPED_TRACE(::testing::Message() << threads << " threads, " << chunks << " chunks, pattern " << pattern);
        ChunkShares s(chunks, threads);
        std::vector<int> seen(chunks, 0);
        std::vector<int64_t> last(threads, -1);  // each owner's own chunks come in increasing order
        int64_t handed = 0;
        for (int64_t step = 0;; ++step) {  // Next gives -1 only once no share has a chunk left
          const int t = pattern == 2 ? 0 : pattern == 1 && step % 5 != 0 ? 1 % threads : step % threads;
          const int64_t c = s.Next(t);
          if (c < 0) break;
          ASSERT_LT(c, chunks);
          ++seen[c], ++handed;
          if (c >= chunks * t / threads && c < chunks * (t + 1) / threads) {
            EXPECT_GT(c, last[t]);
            last[t] = c;
          }
        }
        EXPECT_EQ(handed, chunks);
        for (int64_t c = 0; c < chunks; ++c) EXPECT_EQ(seen[c], 1) << "chunk " << c;
        for (int t = 0; t < threads; ++t) EXPECT_EQ(s.Next(t), -1);
      }
    }
  }
}

// Real threads: each item once; the first range blocks until every other one is done,
// so its owner's share can only be finished by the other threads taking it.
TEST(ChunkSharesTest, ParallelForSharesCoversEveryItemOnce) {
  for (int threads : {1, 2, 3, 7}) {
    for (int64_t n : {0, 1, 100, 1000, 4099}) {
      SCOPED_TRACE(::testing::Message() << threads << " threads, " << n << " items");
      std::vector<std::atomic<int>> count(n);
      std::atomic<int64_t> done{0};
      const absl::Status s = ParallelForShares(n, 64, RunContext(nullptr, threads), [&](int64_t begin, int64_t end) {
        if (begin == 0 && omp_get_num_threads() > 1)
          while (done.load() < n - end) std::this_thread::yield();
        for (int64_t i = begin; i < end; ++i) ++count[i];
        done += end - begin;
      });
      EXPECT_TRUE(s.ok());
      for (int64_t i = 0; i < n; ++i) ASSERT_EQ(count[i].load(), 1) << "item " << i;
    }
  }
  CancellationToken cancel;
  cancel.Cancel();
  int ran = 0;
  const absl::Status s = ParallelForShares(1000, 64, RunContext(&cancel, 2), [&](int64_t, int64_t) { ++ran; });
  EXPECT_EQ(s.code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(ran, 0);
}

// Fit and quantities on shares of blocks: equal bit for bit at 1, 2, 3 and 7 threads
// (degree 2, the lane set-up path; 4,624 vertices: 10 blocks of the fit, 10 ranges).
TEST(ChunkSharesTest, FitAndQuantitiesBitIdenticalForAnyThreadCount) {
  GeneratorOptions g;
  g.n = 68;
  const Mesh m = GenerateTorusMesh(g);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 2;
  const auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(t, m, RingSpecFor(o), 1));
  const auto one = FitSurface(m, t, o, nb, {}, RunContext(nullptr, 1)).value();
  const Differentials d1 = ComputeDifferentials(*one, kAllQuantities, 1);
  const size_t ncoef = static_cast<size_t>(one->dims()) * one->num_coefficients();
  for (int threads : {2, 3, 7}) {
    SCOPED_TRACE(::testing::Message() << threads << " threads");
    const auto fits = FitSurface(m, t, o, nb, {}, RunContext(nullptr, threads)).value();
    for (int v = 0; v < m.NumVertices(); ++v) {
      ASSERT_EQ(0, std::memcmp(&fits->frame(v), &one->frame(v), sizeof(LocalFrame))) << "vertex " << v;
      ASSERT_EQ(0, std::memcmp(fits->coefficients(v), one->coefficients(v), ncoef * 8)) << "vertex " << v;
    }
    const Differentials d = ComputeDifferentials(*fits, kAllQuantities, threads);
    EXPECT_EQ(0, std::memcmp(d.normals.data(), d1.normals.data(), d1.normals.size() * 8));
    EXPECT_EQ(0, std::memcmp(d.mean.data(), d1.mean.data(), d1.mean.size() * 8));
    EXPECT_EQ(0, std::memcmp(d.gaussian.data(), d1.gaussian.data(), d1.gaussian.size() * 8));
    EXPECT_EQ(0, std::memcmp(d.k1.data(), d1.k1.data(), d1.k1.size() * 8));
    EXPECT_EQ(0, std::memcmp(d.k2.data(), d1.k2.data(), d1.k2.size() * 8));
    EXPECT_EQ(0, std::memcmp(d.dir1.data(), d1.dir1.data(), d1.dir1.size() * 8));
    EXPECT_EQ(0, std::memcmp(d.tensor.data(), d1.tensor.data(), d1.tensor.size() * 8));
    for (int v = 0; v < m.NumVertices(); ++v) ASSERT_EQ(d.diagnostics[v].degree_used, d1.diagnostics[v].degree_used);
  }
}

}  // namespace
}  // namespace geomfit
