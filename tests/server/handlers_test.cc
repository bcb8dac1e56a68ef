// Handlers without a network: proto in, StatusOr<proto> out.
#include "server/handlers/handlers.h"

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <set>
#include <thread>

#include <gtest/gtest.h>

#include "core/integration/integrate.h"
#include "core/reconstruction/features.h"
#include "core/surfaces/analytic.h"
#include "core/quantities/differentials.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::TestSphere;
using testing::TestTorus;

v1::ComputeDifferentialsRequest StreamedRequest(const std::string& id);

class HandlersTest : public ::testing::Test {
 protected:
  HandlersTest()
      : store_(NewMemoryStore()), cache_(64 << 20), ws_(store_.get(), &cache_, WorkspaceOptions{.threads = 1}),
        handlers_(&ws_, &stats_, Options()) {}

  static HandlerOptions Options() {
    HandlerOptions o;
    o.chunk_rows = 100;
    return o;
  }

  absl::StatusOr<v1::MeshInfo> Upload(const Mesh& mesh, const std::string& name = "m") {
    UploadAssembler a(1 << 20);
    v1::MeshHeader header;
    header.set_name(name);
    for (const auto& r : wire::UploadChunks(mesh, header, 64)) {
      absl::Status s = a.Add(r);
      if (!s.ok()) return s;
    }
    return handlers_.UploadMesh(a);
  }

  absl::StatusOr<v1::MeshInfo> Update(const std::string& id, const Positions& p, std::optional<int64_t> expected) {
    PositionsAssembler a(1 << 20);
    v1::UpdateHeader header;
    header.set_mesh_id(id);
    if (expected) header.set_expected_revision(*expected);
    for (const auto& r : wire::UpdateChunks(p, header, 50)) {
      absl::Status s = a.Add(r);
      if (!s.ok()) return s;
    }
    return handlers_.UpdatePositions(a);
  }

  absl::StatusOr<Differentials> Compute(const std::string& id, v1::FitSummary* summary, int degree = 2) {
    v1::ComputeDifferentialsRequest request;
    request.set_mesh_id(id);
    request.mutable_options()->set_degree(degree);
    request.set_diagnostics(true);
    wire::AddQuantities(kAllQuantities, &request);
    CancellationToken token;
    auto chunks = handlers_.ComputeDifferentials(request, token);
    if (!chunks.ok()) return chunks.status();
    wire::DifferentialsReader reader;
    for (const auto& c : *chunks) {
      absl::Status s = reader.Add(c);
      if (!s.ok()) return s;
    }
    *summary = reader.summary();
    return reader.Finish();
  }

  /// A time-stepping client's first step: `mesh` uploaded and its differentials asked
  /// for once (the recipe a prefetch repeats). Returns the mesh id ("" on failure).
  std::string FirstStep(const Mesh& mesh) {
    auto info = Upload(mesh);
    EXPECT_TRUE(info.ok()) << info.status();
    if (!info.ok()) return "";
    ChunkCollector<v1::ComputeDifferentialsResponse> first;
    CancellationToken token;
    EXPECT_TRUE(handlers_.ComputeDifferentials(StreamedRequest(info->mesh_id()), token, &first).ok());
    return info->mesh_id();
  }

  std::unique_ptr<MeshStore> store_;
  Cache cache_;
  RequestStats stats_;
  Workspace ws_;
  Handlers handlers_;
};

TEST_F(HandlersTest, UploadReturnsInfoAndIsIdempotent) {
  const Mesh mesh = TestTorus();
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->revision(), 1);
  EXPECT_EQ(info->num_vertices(), mesh.NumVertices());
  EXPECT_EQ(info->num_faces(), mesh.NumFaces());
  EXPECT_EQ(info->face_kind(), v1::FACE_KIND_TRIANGLE);
  EXPECT_EQ(info->content_hash().size(), 32u);
  EXPECT_EQ(info->bounding_box().max(0), mesh.positions.col(0).maxCoeff());
  EXPECT_EQ(info->bounding_box().min(2), mesh.positions.col(2).minCoeff());
  auto again = Upload(mesh);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->mesh_id(), info->mesh_id());
  auto other = Upload(mesh, "another name");
  ASSERT_TRUE(other.ok());
  EXPECT_NE(other->mesh_id(), info->mesh_id());
  EXPECT_EQ(store_->Stats().meshes, 2);
}

TEST_F(HandlersTest, CurvatureMatchesInProcessBitForBit) {
  const Mesh mesh = TestSphere(12);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok()) << info.status();
  v1::FitSummary summary;
  auto remote = Compute(info->mesh_id(), &summary);
  ASSERT_TRUE(remote.ok()) << remote.status();
  FitOptions options;
  auto local = ComputeDifferentials(mesh, options, kAllQuantities, RunContext(nullptr, 1));
  ASSERT_TRUE(local.ok()) << local.status();
  EXPECT_EQ(remote->mean, local->mean);
  EXPECT_EQ(remote->gaussian, local->gaussian);
  EXPECT_EQ(remote->normals, local->normals);
  EXPECT_EQ(remote->tensor, local->tensor);
  // H = +1/R on the unit sphere, normals outward.
  EXPECT_NEAR(remote->mean.mean(), 1.0, 0.05);
  EXPECT_GT(remote->normals.row(0).dot(mesh.positions.row(0)), 0.9);
  EXPECT_EQ(summary.num_vertices(), mesh.NumVertices());
  EXPECT_EQ(summary.degree_requested(), 2);
  EXPECT_FALSE(summary.fit_cache_hit());
  ASSERT_EQ(remote->diagnostics.size(), static_cast<size_t>(mesh.NumVertices()));
  EXPECT_GT(remote->diagnostics[0].points, 6);
}

TEST_F(HandlersTest, NormalDegreeRefinesNormalsAsInProcessAndIsValidated) {
  const Mesh mesh = TestSphere(12);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok()) << info.status();
  auto compute = [&](int normal_degree) -> absl::StatusOr<Differentials> {
    v1::ComputeDifferentialsRequest request;
    request.set_mesh_id(info->mesh_id());
    request.mutable_options()->set_degree(2);
    request.mutable_options()->set_normal_degree(normal_degree);
    wire::AddQuantities(kAllQuantities, &request);
    CancellationToken token;
    GF_ASSIGN_OR_RETURN(auto chunks, handlers_.ComputeDifferentials(request, token));
    wire::DifferentialsReader reader;
    for (const auto& c : chunks) GF_RETURN_IF_ERROR(reader.Add(c));
    return reader.Finish();
  };
  auto plain = compute(0), refined = compute(3);
  ASSERT_TRUE(plain.ok()) << plain.status();
  ASSERT_TRUE(refined.ok()) << refined.status();
  FitOptions options;
  options.normal_degree = 3;
  auto local = ComputeDifferentials(mesh, options, kAllQuantities, RunContext(nullptr, 1));
  ASSERT_TRUE(local.ok()) << local.status();
  EXPECT_EQ(refined->normals, local->normals);
  EXPECT_EQ(refined->mean, local->mean);
  EXPECT_EQ(refined->tensor, local->tensor);
  // Other normals than the plain degree-2 fit's (the convergence gain is in bench/README.md).
  EXPECT_GT((refined->normals - plain->normals).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_NE(plain->normals, local->normals);
  auto low = compute(1);  // below the degree: named, not silently off
  EXPECT_EQ(low.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(low.status().message().find("options: fit option normal_degree = 1"), std::string::npos)
      << low.status();
}

TEST_F(HandlersTest, SecondRequestHitsTheFittingCache) {
  auto info = Upload(TestTorus());
  ASSERT_TRUE(info.ok());
  v1::FitSummary first, second;
  ASSERT_TRUE(Compute(info->mesh_id(), &first).ok());
  ASSERT_TRUE(Compute(info->mesh_id(), &second).ok());
  EXPECT_FALSE(first.fit_cache_hit());
  EXPECT_FALSE(first.quantities_cache_hit());
  EXPECT_TRUE(second.fit_cache_hit());
  EXPECT_TRUE(second.quantities_cache_hit());
  EXPECT_EQ(second.evaluate_ms(), 0);
  v1::FitSummary other_degree;
  ASSERT_TRUE(Compute(info->mesh_id(), &other_degree, 3).ok());
  EXPECT_FALSE(other_degree.fit_cache_hit());
}

TEST_F(HandlersTest, PrefetchComputesTheNextStepOfATimeSteppingClient) {
  const Mesh mesh = TestTorus();
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  const std::string id = info->mesh_id();
  CancellationToken token;
  v1::FitSummary s;
  // Nothing was computed on revision 1: nothing to prefetch for revision 2.
  ASSERT_TRUE(Update(id, 1.5 * mesh.positions, 1).ok());
  handlers_.Prefetch(id, 2, token);
  ASSERT_TRUE(Compute(id, &s, 3).ok());
  EXPECT_FALSE(s.fit_cache_hit());

  // Revision 2 had a request: revision 3 gets the same fits and quantities ahead.
  ASSERT_TRUE(Update(id, 2.0 * mesh.positions, 2).ok());
  handlers_.Prefetch(id, 3, token);
  auto prefetched = Compute(id, &s, 3);
  ASSERT_TRUE(prefetched.ok()) << prefetched.status();
  EXPECT_EQ(s.revision(), 3);
  EXPECT_TRUE(s.fit_cache_hit());
  EXPECT_TRUE(s.quantities_cache_hit());
  Mesh moved = mesh;
  moved.positions = 2.0 * mesh.positions;
  FitOptions options;
  options.degree = 3;
  auto local = ComputeDifferentials(moved, options, kAllQuantities, RunContext(nullptr, 1));
  ASSERT_TRUE(local.ok());
  EXPECT_EQ(prefetched->mean, local->mean) << "the prefetched values are revision 3's";
  EXPECT_EQ(prefetched->normals, local->normals);

  // A step without a request ends it: revision 4 is prefetched (3 had a request),
  // revision 5 is not (4 had none).
  ASSERT_TRUE(Update(id, 2.5 * mesh.positions, 3).ok());
  handlers_.Prefetch(id, 4, token);
  ASSERT_TRUE(Update(id, 3.0 * mesh.positions, 4).ok());
  handlers_.Prefetch(id, 5, token);
  ASSERT_TRUE(Compute(id, &s, 3).ok());
  EXPECT_EQ(s.revision(), 5);
  EXPECT_FALSE(s.fit_cache_hit());
}

/// Collects chunks; `on_push` (optional) runs on the pushing thread before each is kept.
struct RecordingSink final : ChunkSink<v1::ComputeDifferentialsResponse> {
  std::function<void(const v1::ComputeDifferentialsResponse&)> on_push;
  std::mutex mu;
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  std::vector<bool> last;
  void Push(v1::ComputeDifferentialsResponse chunk, bool is_last) override {
    if (on_push) on_push(chunk);
    std::lock_guard<std::mutex> lock(mu);
    chunks.push_back(std::move(chunk));
    last.push_back(is_last);
  }
  absl::StatusOr<Differentials> Assemble(v1::FitSummary* summary) {
    wire::DifferentialsReader reader;
    for (const auto& c : chunks) GF_RETURN_IF_ERROR(reader.Add(c));
    *summary = reader.summary();
    return reader.Finish();
  }
};

v1::ComputeDifferentialsRequest StreamedRequest(const std::string& id) {
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(id);
  request.mutable_options()->set_degree(3);
  request.set_chunk_rows(512);  // the fit reports blocks of 512 vertices
  request.set_diagnostics(true);
  wire::AddQuantities(kAllQuantities, &request);
  return request;
}

void ExpectSameAsInProcess(const Differentials& d, const Mesh& mesh, const FitOptions& options) {
  auto local = ComputeDifferentials(mesh, options, kAllQuantities, RunContext(nullptr, 1));
  ASSERT_TRUE(local.ok());
  EXPECT_EQ(d.normals, local->normals);
  EXPECT_EQ(d.mean, local->mean);
  EXPECT_EQ(d.k2, local->k2);
  EXPECT_EQ(d.dir1, local->dir1);
  EXPECT_EQ(d.tensor, local->tensor);
  ASSERT_EQ(d.diagnostics.size(), local->diagnostics.size());
  for (size_t v = 0; v < d.diagnostics.size(); ++v) EXPECT_EQ(d.diagnostics[v].degree_used, local->diagnostics[v].degree_used);
}
void ExpectSameAsInProcess(const Differentials& d, const Mesh& mesh, int degree = 3,
                           JetHermiteMode jets = JetHermiteMode::kAuto) {
  FitOptions options;
  options.degree = degree;
  options.jet_hermite = jets;
  ExpectSameAsInProcess(d, mesh, options);
}

TEST_F(HandlersTest, AFreshFitStreamsChunksWhileItRuns) {
  const Mesh mesh = TestTorus(40);
  ASSERT_GT(mesh.NumVertices(), 4 * 512);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  RecordingSink sink;
  std::vector<int64_t> fits_cached_at_push;
  sink.on_push = [&](const v1::ComputeDifferentialsResponse&) {
    fits_cached_at_push.push_back(cache_.Stats(Tier::kFitting).entries);
  };
  CancellationToken token;
  ASSERT_TRUE(handlers_.ComputeDifferentials(StreamedRequest(info->mesh_id()), token, &sink).ok());

  const size_t expected_chunks = (mesh.NumVertices() + 511) / 512;
  ASSERT_EQ(sink.chunks.size(), expected_chunks);
  // Every chunk but the last went out before the fit was finished (and cached).
  for (size_t i = 0; i + 1 < expected_chunks; ++i) EXPECT_EQ(fits_cached_at_push[i], 0) << "chunk " << i;
  EXPECT_EQ(std::count(sink.last.begin(), sink.last.end(), true), 1);
  EXPECT_TRUE(sink.last.back());
  // The first chunk names what is coming; the last one has the complete summary.
  const v1::FitSummary& head = sink.chunks.front().summary();
  EXPECT_EQ(head.num_vertices(), mesh.NumVertices());
  EXPECT_EQ(head.revision(), 1);
  EXPECT_EQ(head.vertices_by_degree_size(), 0);
  for (size_t i = 1; i + 1 < expected_chunks; ++i) EXPECT_FALSE(sink.chunks[i].has_summary());
  v1::FitSummary summary;
  auto d = sink.Assemble(&summary);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(summary.vertices_by_degree(3), mesh.NumVertices());
  EXPECT_FALSE(summary.fit_cache_hit());
  EXPECT_GT(summary.fit_ms(), 0);
  ExpectSameAsInProcess(*d, mesh);

  // Again, from the cache: the same chunks, and the values were cached once.
  RecordingSink again;
  ASSERT_TRUE(handlers_.ComputeDifferentials(StreamedRequest(info->mesh_id()), token, &again).ok());
  ASSERT_EQ(again.chunks.size(), expected_chunks);
  for (size_t i = 0; i + 1 < expected_chunks; ++i) {
    EXPECT_EQ(again.chunks[i].SerializeAsString(), sink.chunks[i].SerializeAsString()) << "chunk " << i;
  }
  EXPECT_TRUE(again.chunks.back().summary().fit_cache_hit());
  EXPECT_TRUE(again.chunks.back().summary().quantities_cache_hit());
}

// Degree 5: the Hermite jets (on by default, FitOptions::jet_hermite) refit the whole mesh
// after the fit, then its blocks are reported, as at degree 3: every chunk once, the values
// the in-process ones.
TEST_F(HandlersTest, AStreamedDegreeFiveFitReportsAfterItsHermiteJets) {
  const Mesh mesh = TestTorus(40);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  v1::ComputeDifferentialsRequest request = StreamedRequest(info->mesh_id());
  request.mutable_options()->set_degree(5);
  RecordingSink sink;
  CancellationToken token;
  ASSERT_TRUE(handlers_.ComputeDifferentials(request, token, &sink).ok());
  ASSERT_EQ(sink.chunks.size(), static_cast<size_t>((mesh.NumVertices() + 511) / 512));
  EXPECT_EQ(std::count(sink.last.begin(), sink.last.end(), true), 1);
  v1::FitSummary summary;
  auto d = sink.Assemble(&summary);
  ASSERT_TRUE(d.ok()) << d.status();
  ExpectSameAsInProcess(*d, mesh, 5);
  FitOptions plain;
  plain.degree = 5;
  plain.jet_hermite = JetHermiteMode::kOff;
  auto p = ComputeDifferentials(mesh, plain, kAllQuantities, RunContext(nullptr, 1));
  ASSERT_TRUE(p.ok());
  EXPECT_NE(d->mean, p->mean) << "the Hermite jets did not run at degree 5";
}

// Degree 2 with quadratic_hermite (off by default; proto field 25): the request's option
// reaches the fit (the values are the in-process ones with it, not the plain fit's), and a
// plain degree-2 request afterwards is not served from its cached fit.
TEST_F(HandlersTest, AStreamedDegreeTwoFitRunsQuadraticHermiteWhenAsked) {
  const Mesh mesh = TestTorus(40);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  v1::ComputeDifferentialsRequest request = StreamedRequest(info->mesh_id());
  request.mutable_options()->set_degree(2);
  request.mutable_options()->set_quadratic_hermite(true);
  RecordingSink sink;
  CancellationToken token;
  ASSERT_TRUE(handlers_.ComputeDifferentials(request, token, &sink).ok());
  ASSERT_EQ(sink.chunks.size(), static_cast<size_t>((mesh.NumVertices() + 511) / 512));
  EXPECT_EQ(std::count(sink.last.begin(), sink.last.end(), true), 1);
  v1::FitSummary summary;
  auto d = sink.Assemble(&summary);
  ASSERT_TRUE(d.ok()) << d.status();
  FitOptions refined;
  refined.degree = 2;
  refined.quadratic_hermite = true;
  ExpectSameAsInProcess(*d, mesh, refined);

  request.mutable_options()->clear_quadratic_hermite();
  RecordingSink plain_sink;
  ASSERT_TRUE(handlers_.ComputeDifferentials(request, token, &plain_sink).ok());
  v1::FitSummary plain_summary;
  auto p = plain_sink.Assemble(&plain_summary);
  ASSERT_TRUE(p.ok()) << p.status();
  EXPECT_FALSE(plain_summary.fit_cache_hit());
  ExpectSameAsInProcess(*p, mesh, 2);
  EXPECT_NE(d->normals, p->normals) << "quadratic_hermite did not change the degree-2 normals";
  EXPECT_NE(d->mean, p->mean) << "quadratic_hermite did not change the degree-2 mean curvatures";
}

TEST(HandlersStreamTest, FittingThreadsStreamEveryChunkOnceInOrder) {
  auto store = NewMemoryStore();
  Cache cache(64 << 20);
  RequestStats stats;
  Workspace ws(store.get(), &cache, WorkspaceOptions{.threads = 2});  // blocks reported concurrently and out of order
  Handlers handlers(&ws, &stats, HandlerOptions());
  const Mesh mesh = TestTorus(40);
  UploadAssembler a(1 << 20);
  for (const auto& r : wire::UploadChunks(mesh, v1::MeshHeader(), 1000)) ASSERT_TRUE(a.Add(r).ok());
  auto info = handlers.UploadMesh(a);
  ASSERT_TRUE(info.ok()) << info.status();
  for (int round = 0; round < 3; ++round) {
    cache.EraseMesh(info->mesh_id());  // a fresh fit every round
    RecordingSink sink;
    CancellationToken token;
    ASSERT_TRUE(handlers.ComputeDifferentials(StreamedRequest(info->mesh_id()), token, &sink).ok());
    ASSERT_EQ(sink.chunks.size(), static_cast<size_t>((mesh.NumVertices() + 511) / 512));
    v1::FitSummary summary;
    auto d = sink.Assemble(&summary);  // rejects gaps, repeats and disorder
    ASSERT_TRUE(d.ok()) << d.status();
    ExpectSameAsInProcess(*d, mesh);
  }
}

TEST_F(HandlersTest, AFollowerFinishesTheFitWhenItsOwnerIsCancelledEvenAfterAnUpdate) {
  const Mesh mesh = TestTorus(40);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  const v1::ComputeDifferentialsRequest request = StreamedRequest(info->mesh_id());
  CancellationToken owner_token, follower_token;
  RecordingSink owner, follower;
  std::mutex mu;
  std::condition_variable cv;
  bool follower_started = false;
  follower.on_push = [&](const v1::ComputeDifferentialsResponse&) {
    std::lock_guard<std::mutex> lock(mu);
    follower_started = true;
    cv.notify_all();
  };
  std::thread second;
  absl::Status follower_status;
  owner.on_push = [&](const v1::ComputeDifferentialsResponse& chunk) {
    if (chunk.vertex_offset() != 0) return;
    // The owner has sent its first rows: a second request joins, streams them, and
    // then the owner's caller goes away.
    second = std::thread([&] { follower_status = handlers_.ComputeDifferentials(request, follower_token, &follower); });
    std::unique_lock<std::mutex> lock(mu);
    ASSERT_TRUE(cv.wait_for(lock, std::chrono::seconds(30), [&] { return follower_started; }));
    // Meanwhile the simulation moves on: the follower must still finish revision 1.
    ASSERT_TRUE(Update(info->mesh_id(), 1.5 * mesh.positions, 1).ok());
    owner_token.Cancel();
  };
  const absl::Status owner_status = handlers_.ComputeDifferentials(request, owner_token, &owner);
  second.join();
  EXPECT_EQ(owner_status.code(), absl::StatusCode::kCancelled) << owner_status;
  EXPECT_LT(owner.chunks.size(), (mesh.NumVertices() + 511) / 512) << "the owner stopped early";
  ASSERT_TRUE(follower_status.ok()) << follower_status;
  v1::FitSummary summary;
  auto d = follower.Assemble(&summary);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(summary.vertices_by_degree(3), mesh.NumVertices());
  EXPECT_EQ(summary.revision(), 1);
  EXPECT_FALSE(summary.fit_cache_hit()) << "the follower computed the fit itself";
  ExpectSameAsInProcess(*d, mesh);
}

TEST_F(HandlersTest, TheOwnerSendsAFollowersLastChunkAsSoonAsItEnds) {
  const Mesh mesh = TestTorus(40);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  const int64_t n = mesh.NumVertices();
  constexpr int64_t kRows = 1800;  // the follower's chunks: 3.5 fitted blocks
  const int64_t last_start = (n - 1) / kRows * kRows;
  ASSERT_GT(n - last_start, 2 * 512) << "the last chunk should span several fitted blocks";
  v1::ComputeDifferentialsRequest request = StreamedRequest(info->mesh_id());  // a chunk per fitted block
  // Degree 4: degree 3's (and 5's) fits are reported once their Hermite curvatures are
  // refitted, in one block (FitOptions::cubic_hermite, jet_hermite, as the degree-2 slope
  // refinement's); degree 4's Hermite jets are off by default.
  request.mutable_options()->set_degree(4);
  v1::ComputeDifferentialsRequest follower_request = request;
  follower_request.set_chunk_rows(kRows);
  CancellationToken token;
  RecordingSink owner, follower;
  std::mutex mu;
  std::condition_variable cv;
  int64_t follower_sent = 0;
  std::vector<std::thread::id> pushed_by;  // the follower's chunks
  follower.on_push = [&](const v1::ComputeDifferentialsResponse& chunk) {
    std::lock_guard<std::mutex> lock(mu);
    pushed_by.push_back(std::this_thread::get_id());
    follower_sent = chunk.vertex_offset() + chunk.num_vertices();
    cv.notify_all();
  };
  std::thread second;
  absl::Status follower_status;
  // The owner's fitting thread pushes its own chunk after each fitted block: there it
  // waits for the follower to stream what it may (whole chunks, then within the last
  // chunk every block), so that the test does not depend on thread timing.
  owner.on_push = [&](const v1::ComputeDifferentialsResponse& chunk) {
    if (chunk.vertex_offset() == 0) {
      second = std::thread(
          [&] { follower_status = handlers_.ComputeDifferentials(follower_request, token, &follower); });
    }
    const int64_t filled = chunk.vertex_offset() + chunk.num_vertices();
    if (filled == n) return;  // the owner's own last chunk goes out before the followers'
    const int64_t expected = filled >= last_start ? filled : filled / kRows * kRows;
    std::unique_lock<std::mutex> lock(mu);
    ASSERT_TRUE(cv.wait_for(lock, std::chrono::seconds(30), [&] { return follower_sent >= expected; }))
        << "the follower did not stream rows " << follower_sent << ".." << expected;
  };
  const std::thread::id owner_thread = std::this_thread::get_id();
  ASSERT_TRUE(handlers_.ComputeDifferentials(request, token, &owner).ok());
  second.join();
  ASSERT_TRUE(follower_status.ok()) << follower_status;

  ASSERT_GE(follower.chunks.size(), 3u);
  EXPECT_TRUE(follower.last.back());
  EXPECT_EQ(pushed_by.back(), owner_thread) << "the follower's last chunk waited for the follower to wake";
  for (size_t i = 0; i + 1 < pushed_by.size(); ++i) EXPECT_NE(pushed_by[i], owner_thread) << "chunk " << i;
  // Before the last chunk's rows, whole chunks only; within them every fitted block,
  // so the owner was left one block.
  for (size_t i = 0; i + 1 < follower.chunks.size(); ++i) {
    const auto& c = follower.chunks[i];
    if (c.vertex_offset() < last_start) EXPECT_EQ(c.num_vertices(), kRows) << "chunk " << i;
  }
  const v1::ComputeDifferentialsResponse& last = follower.chunks.back();
  EXPECT_EQ(last.vertex_offset(), (n - 1) / 512 * 512);
  EXPECT_EQ(last.vertex_offset() + last.num_vertices(), n);
  v1::FitSummary summary;
  auto d = follower.Assemble(&summary);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_TRUE(summary.fit_cache_hit()) << "shared, not computed for the follower";
  EXPECT_EQ(summary.fit_ms(), 0);
  v1::FitSummary owner_summary;
  ASSERT_TRUE(owner.Assemble(&owner_summary).ok());
  EXPECT_GT(owner_summary.fit_ms(), 0);
  EXPECT_EQ(owner_summary.joined_compute_ms(), 0);
  EXPECT_EQ(summary.joined_compute_ms(), owner_summary.fit_ms() + owner_summary.evaluate_ms())
      << "the follower reports the computation it joined";
  EXPECT_EQ(summary.vertices_by_degree(4), n);
  ExpectSameAsInProcess(*d, mesh, 4, JetHermiteMode::kOff);
}

TEST_F(HandlersTest, ARequestDuringAPrefetchStreamsFromIt) {
  const Mesh mesh = TestTorus(40);
  const std::string id = FirstStep(mesh);
  ASSERT_FALSE(id.empty());
  const v1::ComputeDifferentialsRequest request = StreamedRequest(id);
  CancellationToken token;
  Mesh moved = mesh;
  moved.positions = 1.25 * mesh.positions;
  ASSERT_TRUE(Update(id, moved.positions, 1).ok());
  std::thread prefetch([&] { handlers_.Prefetch(id, 2, token); });
  RecordingSink sink;
  const absl::Status s = handlers_.ComputeDifferentials(request, token, &sink);
  prefetch.join();
  ASSERT_TRUE(s.ok()) << s;
  v1::FitSummary summary;
  auto d = sink.Assemble(&summary);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(summary.revision(), 2);
  ExpectSameAsInProcess(*d, moved);
  EXPECT_EQ(cache_.Stats(Tier::kFitting).misses, 4) << "two fits and two evaluations: the step's was shared";
}

TEST_F(HandlersTest, APlannedPrefetchIsJoinedByRequestsBeforeItRuns) {
  const Mesh mesh = TestTorus(40);
  const std::string id = FirstStep(mesh);
  ASSERT_FALSE(id.empty());
  const v1::ComputeDifferentialsRequest request = StreamedRequest(id);
  CancellationToken token;
  for (const bool run : {true, false}) {
    SCOPED_TRACE(run ? "run" : "dropped unrun");
    Mesh moved = mesh;
    moved.positions = (run ? 1.25 : 1.5) * mesh.positions;
    auto updated = Update(id, moved.positions, std::nullopt);
    ASSERT_TRUE(updated.ok());
    // Registered when the update is stored, before it is acknowledged: a request that
    // comes before the prefetch runs waits for it instead of fitting on its own.
    auto pending = handlers_.PlanPrefetch(id, updated->revision());
    ASSERT_NE(pending, nullptr);
    RecordingSink sink;
    std::atomic<bool> done{false};
    absl::Status status;
    std::thread step([&] {
      status = handlers_.ComputeDifferentials(request, token, &sink);
      done = true;
    });
    std::this_thread::sleep_for(std::chrono::milliseconds(100));  // a fit takes ~10 ms
    EXPECT_FALSE(done) << "the request did not wait for the planned prefetch";
    if (run) {
      pending->Run(token);
    } else {
      pending.reset();  // ends it as cancelled: the request computes for itself
    }
    step.join();
    ASSERT_TRUE(status.ok()) << status;
    v1::FitSummary summary;
    auto d = sink.Assemble(&summary);
    ASSERT_TRUE(d.ok()) << d.status();
    EXPECT_EQ(summary.revision(), updated->revision());
    EXPECT_EQ(summary.fit_cache_hit(), run) << "shared with the prefetch only if it ran";
    EXPECT_EQ(summary.joined_compute_ms() > 0, run);
    EXPECT_EQ(summary.fit_ms() > 0, !run);
    ExpectSameAsInProcess(*d, moved);
  }
}

TEST_F(HandlersTest, AFailedRequestLeavesThePrefetchRecipe) {
  const Mesh mesh = TestTorus(24);
  const std::string id = FirstStep(mesh);  // degree 3 on revision 1
  ASSERT_FALSE(id.empty());
  ASSERT_TRUE(Update(id, 1.25 * mesh.positions, 1).ok());
  v1::ComputeDifferentialsRequest other = StreamedRequest(id);
  other.mutable_options()->set_degree(4);
  CancellationToken cancelled;
  cancelled.Cancel();
  RecordingSink sink;
  EXPECT_EQ(handlers_.ComputeDifferentials(other, cancelled, &sink).code(), absl::StatusCode::kCancelled);
  // The next step still prefetches what revision 1 was asked for.
  auto pending = handlers_.PlanPrefetch(id, 2);
  ASSERT_NE(pending, nullptr) << "the cancelled request replaced the recipe";
  CancellationToken token;
  pending->Run(token);
  RecordingSink step;
  ASSERT_TRUE(handlers_.ComputeDifferentials(StreamedRequest(id), token, &step).ok());
  v1::FitSummary summary;
  ASSERT_TRUE(step.Assemble(&summary).ok());
  EXPECT_TRUE(summary.fit_cache_hit()) << "the prefetch computed the degree-3 fit";
}

TEST_F(HandlersTest, UpdatePositionsKeepsTopologyAndMakesNewRevision) {
  const Mesh mesh = TestTorus();
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  v1::FitSummary s;
  ASSERT_TRUE(Compute(info->mesh_id(), &s).ok());
  const TierStats topo_before = cache_.Stats(Tier::kTopology);

  const Positions scaled = 2.0 * mesh.positions;
  auto updated = Update(info->mesh_id(), scaled, 1);
  ASSERT_TRUE(updated.ok()) << updated.status();
  EXPECT_EQ(updated->revision(), 2);
  EXPECT_EQ(updated->bounding_box().max(0), scaled.col(0).maxCoeff());
  auto d = Compute(info->mesh_id(), &s);
  ASSERT_TRUE(d.ok());
  EXPECT_EQ(s.revision(), 2);
  EXPECT_FALSE(s.fit_cache_hit());
  const TierStats topo_after = cache_.Stats(Tier::kTopology);
  EXPECT_EQ(topo_after.misses, topo_before.misses) << "topology and neighbourhoods must survive UpdatePositions";
  EXPECT_GT(topo_after.hits, topo_before.hits);

  auto stale = Update(info->mesh_id(), mesh.positions, 1);
  EXPECT_EQ(stale.status().code(), absl::StatusCode::kAborted) << stale.status();
  EXPECT_NE(stale.status().message().find("revision 2"), std::string::npos) << stale.status();
  auto unconditional = Update(info->mesh_id(), mesh.positions, std::nullopt);
  ASSERT_TRUE(unconditional.ok());
  EXPECT_EQ(unconditional->revision(), 3);
}

TEST_F(HandlersTest, ConcurrentUnconditionalUpdatesAllApply) {
  const Mesh mesh = TestTorus();
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  std::vector<std::thread> threads;
  std::mutex mu;
  std::set<int64_t> revisions;
  for (int i = 0; i < 4; ++i) {
    threads.emplace_back([&, i] {
      auto r = Update(info->mesh_id(), mesh.positions * (1.0 + i), std::nullopt);
      ASSERT_TRUE(r.ok()) << r.status();
      std::lock_guard<std::mutex> lock(mu);
      revisions.insert(r->revision());
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(revisions, (std::set<int64_t>{2, 3, 4, 5}));
}

TEST_F(HandlersTest, UpdateWithNaNNamesTheVertexAndKeepsTheMesh) {
  const Mesh mesh = TestTorus();
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  Positions bad = mesh.positions;
  bad(17, 1) = std::nan("");
  auto r = Update(info->mesh_id(), bad, std::nullopt);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("vertex 17"), std::string::npos) << r.status();
  auto still = handlers_.GetMesh([&] { v1::GetMeshRequest q; q.set_mesh_id(info->mesh_id()); return q; }());
  ASSERT_TRUE(still.ok());
  EXPECT_EQ(still->revision(), 1);
}

TEST_F(HandlersTest, ListPagesAndDeleteForgets) {
  std::vector<std::string> ids;
  for (int i = 0; i < 5; ++i) {
    auto info = Upload(TestTorus(), "mesh" + std::to_string(i));
    ASSERT_TRUE(info.ok());
    ids.push_back(info->mesh_id());
  }
  v1::ListMeshesRequest list;
  list.set_page_size(2);
  std::vector<std::string> seen;
  for (int page = 0; page < 10; ++page) {
    auto r = handlers_.ListMeshes(list);
    ASSERT_TRUE(r.ok());
    for (const auto& m : r->meshes()) seen.push_back(m.mesh_id());
    if (r->next_page_token().empty()) break;
    list.set_page_token(r->next_page_token());
  }
  std::sort(ids.begin(), ids.end());
  EXPECT_EQ(seen, ids);

  v1::DeleteMeshRequest del;
  del.set_mesh_id(ids[0]);
  ASSERT_TRUE(handlers_.DeleteMesh(del).ok());
  EXPECT_EQ(handlers_.DeleteMesh(del).status().code(), absl::StatusCode::kNotFound);
  v1::FitSummary s;
  EXPECT_EQ(Compute(ids[0], &s).status().code(), absl::StatusCode::kNotFound);
}

TEST_F(HandlersTest, CancelledComputationReportsCancelled) {
  auto info = Upload(TestTorus(24));
  ASSERT_TRUE(info.ok());
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  CancellationToken token;
  token.Cancel();
  auto r = handlers_.ComputeDifferentials(request, token);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kCancelled) << r.status();
  CancellationToken fresh;
  EXPECT_TRUE(handlers_.ComputeDifferentials(request, fresh).ok()) << "a cancelled fit must not be cached";
}

TEST(HandlersBudgetTest, FittingThatCanNeverFitIsResourceExhausted) {
  auto store = NewMemoryStore();
  Cache cache(600 << 10);  // room for the mesh, not for a degree-6 LOP fitting
  RequestStats stats;
  Workspace ws(store.get(), &cache, WorkspaceOptions());
  Handlers handlers(&ws, &stats, HandlerOptions());
  UploadAssembler a(1 << 20);
  for (const auto& r : wire::UploadChunks(TestTorus(20), v1::MeshHeader(), 1000)) ASSERT_TRUE(a.Add(r).ok());
  auto info = handlers.UploadMesh(a);
  ASSERT_TRUE(info.ok()) << info.status();
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  request.mutable_options()->set_degree(6);
  request.mutable_options()->set_method(v1::FIT_METHOD_LOP);
  CancellationToken token;
  auto r = handlers.ComputeDifferentials(request, token);
  EXPECT_EQ(r.status().code(), absl::StatusCode::kResourceExhausted) << r.status();
  EXPECT_NE(r.status().message().find("--cache-bytes"), std::string::npos);
}

TEST_F(HandlersTest, ServerInfoAndStatistics) {
  const v1::ServerInfo info = handlers_.GetServerInfo();
  EXPECT_EQ(info.api_version(), "geomfit.v1");
  EXPECT_EQ(info.store(), "memory");
  EXPECT_GE(info.max_message_bytes(), 64 << 20);
  stats_.Record("GetMesh", "OK", true, 1.5);
  stats_.Record("GetMesh", "NOT_FOUND", false, 0.2);
  const v1::Statistics s = handlers_.GetStatistics();
  ASSERT_EQ(s.methods_size(), 1);
  EXPECT_EQ(s.methods(0).count(), 2);
  EXPECT_EQ(s.methods(0).errors(), 1);
  EXPECT_EQ(s.methods(0).bucket_count(s.methods(0).bucket_count_size() - 1), 2);
  EXPECT_EQ(s.caches_size(), 3);
}

// ---- Chapter 4 RPCs --------------------------------------------------------------

v1::ReconstructionOptions Recon(int degree, v1::Reconstruction method = v1::RECONSTRUCTION_WALF) {
  v1::ReconstructionOptions o;
  o.mutable_fit()->set_degree(degree);
  o.mutable_fit()->set_oscillation_safeguard(false);
  o.set_method(method);
  return o;
}

TEST_F(HandlersTest, SummaryCountsOscillationDowngradesByDegree) {
  const Mesh mesh = TestTorus(8);  // coarse: the safeguard (4.1.3) fires (Table 4.1)
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  request.mutable_options()->set_degree(6);
  request.mutable_options()->set_oscillation_safeguard(true);
  CancellationToken token;
  auto r = handlers_.ComputeDifferentials(request, token);
  ASSERT_TRUE(r.ok()) << r.status();
  const v1::FitSummary& s = r->back().summary();  // the complete one
  EXPECT_GT(s.num_oscillation_downgraded(), 0);
  ASSERT_EQ(s.vertices_by_degree_size(), 7);
  int64_t total = 0, below = 0;
  for (int d = 0; d <= 6; ++d) total += s.vertices_by_degree(d), below += d < 6 ? s.vertices_by_degree(d) : 0;
  EXPECT_EQ(total, mesh.NumVertices());
  EXPECT_GE(below, s.num_oscillation_downgraded());
}

TEST_F(HandlersTest, IntegrateMatchesCoreAndTheSphere) {
  const Mesh mesh = TestSphere(12);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  v1::IntegrateRequest q;
  q.set_mesh_id(info->mesh_id());
  *q.mutable_options() = Recon(4);
  Eigen::VectorXd x2 = mesh.positions.col(0).array().square();
  wire::EncodeDoubles(x2.data(), x2.size(), 0, q.mutable_scalars());
  wire::RowsXd vec = mesh.positions;
  wire::EncodeDoubles(vec.data(), vec.rows(), 3, q.mutable_vectors());
  CancellationToken token;
  auto r = handlers_.Integrate(q, token);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_NEAR(r->area(), 4 * M_PI, 1e-5 * 4 * M_PI);
  EXPECT_NEAR(r->volume(), 4 * M_PI / 3, 1e-5 * 4 * M_PI);
  ASSERT_EQ(r->scalars_size(), 1);
  EXPECT_NEAR(r->scalars(0), 4 * M_PI / 3, 1e-4);
  EXPECT_NEAR(r->flux(), 4 * M_PI, 1e-4);  // div x = 3
  // The same numbers as the core computes in process.
  FitOptions o;
  o.degree = 4;
  auto fits = FitSurface(mesh, BuildTopology(mesh).value(), o, nullptr, FitRequest{.stencils = true}).value();
  IntegrationInput in;
  in.scalars = x2;
  in.vectors = mesh.positions;
  const Integrals core = geomfit::Integrate(WalfSurface(mesh, fits), in, RunContext(nullptr, 1)).value();
  EXPECT_DOUBLE_EQ(r->area(), core.area);
  EXPECT_DOUBLE_EQ(r->flux(), core.flux);
  // The flat baseline is far less accurate.
  *q.mutable_options() = Recon(4, v1::RECONSTRUCTION_LINEAR);
  auto flat = handlers_.Integrate(q, token);
  ASSERT_TRUE(flat.ok());
  EXPECT_GT(std::abs(flat->area() - 4 * M_PI), 100 * std::abs(r->area() - 4 * M_PI));
}

// Sharp features in integration (4.1.4, 4.3): the feature surface's integrals, equal to
// the core's, beat the flat mesh and plain WALF on a cylinder with flat caps.
TEST_F(HandlersTest, IntegrateOverSharpFeatures) {
  const Mesh mesh = GenerateCylinderMesh(8);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  CancellationToken token;
  v1::IntegrateRequest q;
  q.set_mesh_id(info->mesh_id());
  *q.mutable_options() = Recon(3);
  q.mutable_options()->set_feature_angle_deg(45);
  auto feature = handlers_.Integrate(q, token);
  ASSERT_TRUE(feature.ok()) << feature.status();
  q.mutable_options()->set_feature_angle_deg(0);
  auto walf = handlers_.Integrate(q, token);
  *q.mutable_options() = Recon(3, v1::RECONSTRUCTION_LINEAR);
  auto flat = handlers_.Integrate(q, token);
  ASSERT_TRUE(walf.ok() && flat.ok());
  const double area = 6 * M_PI;
  EXPECT_LT(std::abs(feature->area() - area), std::abs(walf->area() - area) / 5);
  EXPECT_LT(std::abs(feature->area() - area), std::abs(flat->area() - area) / 5);
  // The same number as the core in process.
  const Topology topo = BuildTopology(mesh).value();
  FeatureOptions fo;
  fo.angle_deg = 45;
  auto features = std::make_shared<const Features>(DetectFeatures(mesh, topo, fo).value());
  FitOptions o;
  o.degree = 3;
  auto fits = FitSurface(features->split, BuildTopology(features->split).value(), o).value();
  const FeatureSurface surface(mesh, features, MakeSurface(ReconstructionMethod::kWalf, features->split, fits), 3);
  EXPECT_DOUBLE_EQ(feature->area(), geomfit::Integrate(surface, {}, RunContext(nullptr, 1)).value().area);
}

TEST_F(HandlersTest, ProjectPointsEvaluatesFacePointsAndProjectsXyz) {
  const Mesh mesh = TestSphere(8);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  CancellationToken token;
  v1::ProjectPointsRequest q;
  q.set_mesh_id(info->mesh_id());
  *q.mutable_options() = Recon(3);
  q.set_chunk_rows(7);
  std::vector<int32_t> faces;
  wire::RowsXd natural(20, 2);
  for (int i = 0; i < 20; ++i) faces.push_back(i * 13 % mesh.NumFaces()), natural.row(i) << 0.2, 0.3;
  wire::EncodeInts(faces.data(), 20, 0, q.mutable_faces());
  wire::EncodeDoubles(natural.data(), 20, 2, q.mutable_natural());
  auto r = handlers_.ProjectPoints(q, token);
  ASSERT_TRUE(r.ok()) << r.status();
  ASSERT_EQ(r->size(), 3u);  // 20 rows in chunks of 7
  int seen = 0;
  for (const auto& chunk : *r) {
    auto pos = wire::DecodeDoubles(chunk.positions(), "positions", {3}).value();
    for (int i = 0; i < pos.rows(); ++i, ++seen) EXPECT_NEAR(pos.row(i).norm(), 1.0, 5e-4);
  }
  EXPECT_EQ(seen, 20);
  // xyz points off the sphere land on it.
  v1::ProjectPointsRequest p;
  p.set_mesh_id(info->mesh_id());
  *p.mutable_options() = Recon(3);
  wire::RowsXd xyz(2, 3);
  xyz << 0, 0, 1.1, 0.5, 0.5, 0.6;
  wire::EncodeDoubles(xyz.data(), 2, 3, p.mutable_points());
  auto proj = handlers_.ProjectPoints(p, token);
  ASSERT_TRUE(proj.ok()) << proj.status();
  auto pos = wire::DecodeDoubles((*proj)[0].positions(), "positions", {3}).value();
  for (int i = 0; i < 2; ++i) EXPECT_NEAR(pos.row(i).norm(), 1.0, 5e-4);
}

TEST_F(HandlersTest, HighOrderNodesAndRefineMesh) {
  const Mesh mesh = TestSphere(6);
  auto info = Upload(mesh, "ball");
  ASSERT_TRUE(info.ok());
  CancellationToken token;
  v1::HighOrderNodesRequest h;
  h.set_mesh_id(info->mesh_id());
  *h.mutable_options() = Recon(3);
  h.set_order(3);
  auto nodes = handlers_.HighOrderNodes(h, token);
  ASSERT_TRUE(nodes.ok()) << nodes.status();
  auto offsets = wire::DecodeInts(nodes->offsets(), "offsets", {0}).value();
  EXPECT_EQ(offsets.size(), mesh.NumFaces() + 1);
  EXPECT_EQ(offsets(1) - offsets(0), 10);  // cubic triangle
  v1::RefineMeshRequest q;
  q.set_mesh_id(info->mesh_id());
  *q.mutable_options() = Recon(3);
  auto refined = handlers_.RefineMesh(q, token);
  ASSERT_TRUE(refined.ok()) << refined.status();
  EXPECT_EQ(refined->num_faces(), 4 * mesh.NumFaces());
  EXPECT_EQ(refined->name(), "ball refined x2");
  EXPECT_EQ(refined->labels().at("refined_from"), info->mesh_id());
  v1::GetMeshRequest g;
  g.set_mesh_id(refined->mesh_id());
  EXPECT_TRUE(handlers_.GetMesh(g).ok());
}

TEST_F(HandlersTest, ReconstructionRpcsRejectBadInputAndKeepTheMesh) {
  const Mesh mesh = TestSphere(4);
  auto info = Upload(mesh);
  ASSERT_TRUE(info.ok());
  CancellationToken token;
  auto code = [](const absl::Status& s) { return s.code(); };
  v1::ProjectPointsRequest p;
  p.set_mesh_id("m-missing");
  wire::RowsXd xyz(1, 3);
  xyz << 0, 0, 1;
  wire::EncodeDoubles(xyz.data(), 1, 3, p.mutable_points());
  EXPECT_EQ(code(handlers_.ProjectPoints(p, token).status()), absl::StatusCode::kNotFound);
  p.set_mesh_id(info->mesh_id());
  std::vector<int32_t> faces = {mesh.NumFaces()};
  wire::RowsXd natural(1, 2);
  natural << 0.1, 0.1;
  wire::EncodeInts(faces.data(), 1, 0, p.mutable_faces());
  wire::EncodeDoubles(natural.data(), 1, 2, p.mutable_natural());
  EXPECT_EQ(code(handlers_.ProjectPoints(p, token).status()), absl::StatusCode::kInvalidArgument);  // both kinds
  p.clear_points();
  auto bad_face = handlers_.ProjectPoints(p, token);
  EXPECT_EQ(code(bad_face.status()), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad_face.status().message().find("out of range"), std::string::npos) << bad_face.status();
  faces = {0};
  natural << 0.9, 0.5;
  wire::EncodeInts(faces.data(), 1, 0, p.mutable_faces());
  wire::EncodeDoubles(natural.data(), 1, 2, p.mutable_natural());
  auto outside = handlers_.ProjectPoints(p, token);
  EXPECT_NE(outside.status().message().find("outside"), std::string::npos) << outside.status();
  p.mutable_natural()->set_data("short");
  EXPECT_EQ(code(handlers_.ProjectPoints(p, token).status()), absl::StatusCode::kInvalidArgument);

  v1::IntegrateRequest q;
  q.set_mesh_id(info->mesh_id());
  Eigen::VectorXd wrong(mesh.NumVertices() - 1);
  wrong.setOnes();
  wire::EncodeDoubles(wrong.data(), wrong.size(), 0, q.mutable_scalars());
  auto integ = handlers_.Integrate(q, token);
  EXPECT_EQ(code(integ.status()), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(integ.status().message().find("scalar field"), std::string::npos) << integ.status();
  q.clear_scalars();
  *q.mutable_options() = Recon(2, v1::RECONSTRUCTION_CMF);
  EXPECT_EQ(code(handlers_.Integrate(q, token).status()), absl::StatusCode::kInvalidArgument);
  q.mutable_options()->set_method(v1::RECONSTRUCTION_WALF);
  q.mutable_options()->mutable_fit()->set_degree(9);
  EXPECT_EQ(code(handlers_.Integrate(q, token).status()), absl::StatusCode::kInvalidArgument);

  v1::HighOrderNodesRequest h;
  h.set_mesh_id(info->mesh_id());
  h.set_order(4);
  EXPECT_EQ(code(handlers_.HighOrderNodes(h, token).status()), absl::StatusCode::kInvalidArgument);
  v1::RefineMeshRequest r;
  r.set_mesh_id(info->mesh_id());
  r.set_factor(1);
  EXPECT_EQ(code(handlers_.RefineMesh(r, token).status()), absl::StatusCode::kInvalidArgument);
  r.set_factor(2);
  r.mutable_options()->set_feature_angle_deg(500);
  EXPECT_EQ(code(handlers_.RefineMesh(r, token).status()), absl::StatusCode::kInvalidArgument);

  v1::GetMeshRequest g;
  g.set_mesh_id(info->mesh_id());
  auto still = handlers_.GetMesh(g);
  ASSERT_TRUE(still.ok());
  EXPECT_EQ(still->revision(), 1);
  EXPECT_EQ(still->content_hash(), info->content_hash());
}

}  // namespace
}  // namespace geomfit::server
