// Progress in response streams: the throttle, ProjectPoints, ComputeDifferentials and
// ComputeMembrane with `progress`, and the streaming variants HighOrderNodesStream, IntegrateStream, RefineMeshStream.
#include "server/handlers/progress.h"

#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;

struct Seen {
  std::string phase;
  int64_t done, total;
};

std::vector<Seen> Throttled(std::chrono::milliseconds interval, const std::vector<Progress>& reports) {
  std::vector<Seen> out;
  ProgressThrottle throttle([&](const Progress& p) { out.push_back({std::string(p.phase), p.done, p.total}); },
                            interval);
  for (const Progress& p : reports) throttle.Report(p);
  return out;
}

TEST(ProgressThrottleTest, KeepsEachPhasesFirstAndLastAndDropsReportsBehind) {
  // Threads finish out of order: 3 after 4, 6 (the last) before 5.
  const std::vector<Progress> reports = {{"fit", 1, 6}, {"fit", 2, 6}, {"fit", 4, 6}, {"fit", 3, 6},
                                         {"fit", 6, 6}, {"fit", 5, 6}, {"project", 10, 100},
                                         {"project", 50, 100}, {"project", 100, 100}};
  // An interval nothing reaches: per phase the first and the last report only.
  const std::vector<Seen> slow = Throttled(std::chrono::hours(1), reports);
  ASSERT_EQ(slow.size(), 4u);
  EXPECT_EQ(slow[0].phase, "fit");
  EXPECT_EQ(slow[0].done, 1);
  EXPECT_EQ(slow[1].done, 6);
  EXPECT_EQ(slow[2].phase, "project");
  EXPECT_EQ(slow[2].done, 10);
  EXPECT_EQ(slow[3].done, 100);
  EXPECT_EQ(slow[3].total, 100);
  // No interval: every report ahead of the latest, none behind it.
  const std::vector<Seen> all = Throttled(std::chrono::milliseconds(0), reports);
  std::vector<int64_t> done;
  for (const Seen& s : all) done.push_back(s.done);
  EXPECT_EQ(done, (std::vector<int64_t>{1, 2, 4, 6, 10, 50, 100}));
}

TEST(ProgressThrottleTest, UnknownTotalsAreThrottledButNeverEnd) {
  const std::vector<Seen> out = Throttled(std::chrono::hours(1), {{"read", 1, 0}, {"read", 2, 0}, {"read", 3, 0}});
  ASSERT_EQ(out.size(), 1u);
  EXPECT_EQ(out[0].done, 1);
  EXPECT_EQ(out[0].total, 0);
}

/// Checks a stream's progress messages and returns its other messages: every progress
/// message comes before the first result (except those of phase `among`, which may come
/// among the results), phases come in the order `phases` (each once), and within a phase
/// done increases strictly up to total.
template <typename Response>
std::vector<Response> ResultsAfterProgress(const std::vector<Response>& messages,
                                           const std::vector<std::string>& phases, const std::string& among = "") {
  std::vector<Response> results;
  std::vector<std::string> seen;
  int64_t last_done = -1, last_total = 0;
  for (const Response& m : messages) {
    if (!m.has_progress()) {
      results.push_back(m);
      continue;
    }
    if (m.progress().phase() != among) EXPECT_TRUE(results.empty()) << "a progress message after a result";
    const v1::Progress& p = m.progress();
    if (seen.empty() || seen.back() != p.phase()) {
      if (!seen.empty()) EXPECT_EQ(last_done, last_total) << seen.back() << " ended before done = total";
      seen.push_back(p.phase());
      last_done = -1;
    }
    EXPECT_GT(p.done(), last_done) << p.phase();
    EXPECT_LE(p.done(), p.total()) << p.phase();
    last_done = p.done();
    last_total = p.total();
  }
  EXPECT_EQ(last_done, last_total) << "the last phase ended before done = total";
  EXPECT_EQ(seen, phases);
  return results;
}

template <typename Response>
std::vector<Response> ReadAll(std::unique_ptr<grpc::ClientReader<Response>> reader) {
  std::vector<Response> out;
  Response m;
  while (reader->Read(&m)) out.push_back(m);
  const grpc::Status s = reader->Finish();
  EXPECT_TRUE(s.ok()) << s.error_message();
  return out;
}

class ProgressStreamTest : public ::testing::Test {
 protected:
  ProgressStreamTest() : mesh_(testing::TestTorus(40)) {
    auto info = testing::UploadMesh(server_.stub(), mesh_);
    EXPECT_TRUE(info.ok()) << info.status();
    id_ = info->mesh_id();
  }
  v1::ReconstructionOptions Surface() const {
    v1::ReconstructionOptions o;
    o.mutable_fit()->set_degree(4);
    return o;
  }

  /// Reads the streaming variant `stream` of the unary `call`: progress in `phases`,
  /// then one result (*streamed); *unary: `call`'s response to the same request.
  template <typename Request, typename Response, typename Unary>
  void StreamAndUnary(std::unique_ptr<grpc::ClientReader<Response>> (v1::GeomFit::Stub::*stream)(
                          grpc::ClientContext*, const Request&),
                      grpc::Status (v1::GeomFit::Stub::*call)(grpc::ClientContext*, const Request&, Unary*),
                      const Request& request, const std::vector<std::string>& phases, Response* streamed,
                      Unary* unary) {
    grpc::ClientContext ctx;
    const std::vector<Response> results =
        ResultsAfterProgress(ReadAll((server_.stub().*stream)(&ctx, request)), phases);
    ASSERT_EQ(results.size(), 1u);
    *streamed = results[0];
    grpc::ClientContext once;
    ASSERT_TRUE((server_.stub().*call)(&once, request, unary).ok());
  }

  InProcessServer server_;
  Mesh mesh_;
  std::string id_;
};

TEST_F(ProgressStreamTest, ProjectPointsSendsProgressBeforeTheSameResults) {
  ASSERT_GT(mesh_.NumVertices(), 1000);
  v1::ProjectPointsRequest request;
  request.set_mesh_id(id_);
  *request.mutable_options() = Surface();
  const Positions points = mesh_.positions * 1.01;
  wire::EncodeDoubles(points.data(), points.rows(), 3, request.mutable_points());
  request.set_chunk_rows(300);
  request.set_progress(true);
  grpc::ClientContext ctx;
  // The first request fits (phase "fit"), then projects.
  const std::vector<v1::ProjectPointsResponse> with =
      ResultsAfterProgress(ReadAll(server_.stub().ProjectPoints(&ctx, request)), {"fit", "project"});
  request.set_progress(false);
  grpc::ClientContext again;
  const std::vector<v1::ProjectPointsResponse> without = ReadAll(server_.stub().ProjectPoints(&again, request));
  ASSERT_EQ(with.size(), without.size());
  ASSERT_EQ(with.size(), static_cast<size_t>((mesh_.NumVertices() + 299) / 300));
  for (size_t i = 0; i < with.size(); ++i) {
    EXPECT_FALSE(without[i].has_progress());
    EXPECT_EQ(with[i].SerializeAsString(), without[i].SerializeAsString()) << "chunk " << i;
  }
}

TEST_F(ProgressStreamTest, FacePointsReportEvaluation) {
  v1::ProjectPointsRequest request;
  request.set_mesh_id(id_);
  *request.mutable_options() = Surface();
  const int n = mesh_.NumFaces();
  std::vector<int32_t> faces(n);
  wire::RowsXd natural(n, 2);
  for (int f = 0; f < n; ++f) faces[f] = f, natural.row(f) << 0.25, 0.25;
  wire::EncodeInts(faces.data(), n, 0, request.mutable_faces());
  wire::EncodeDoubles(natural.data(), n, 2, request.mutable_natural());
  request.set_progress(true);
  grpc::ClientContext ctx;
  const auto results =
      ResultsAfterProgress(ReadAll(server_.stub().ProjectPoints(&ctx, request)), {"fit", "evaluate points"});
  EXPECT_FALSE(results.empty());
}

TEST_F(ProgressStreamTest, HighOrderNodesStreamEndsWithTheUnaryResponse) {
  v1::HighOrderNodesRequest request;
  request.set_mesh_id(id_);
  request.set_order(3);
  *request.mutable_options() = Surface();
  v1::HighOrderNodesResponse streamed, unary;
  ASSERT_NO_FATAL_FAILURE(StreamAndUnary(&v1::GeomFit::Stub::HighOrderNodesStream, &v1::GeomFit::Stub::HighOrderNodes,
                                         request, {"fit", "evaluate points"}, &streamed, &unary));
  EXPECT_EQ(streamed.SerializeAsString(), unary.SerializeAsString());
  EXPECT_GT(unary.nodes().shape(0), mesh_.NumVertices());
}

TEST_F(ProgressStreamTest, IntegrateStreamEndsWithTheUnaryResponse) {
  v1::IntegrateRequest request;
  request.set_mesh_id(id_);
  *request.mutable_options() = Surface();
  const Eigen::VectorXd ones = Eigen::VectorXd::Ones(mesh_.NumVertices());
  wire::EncodeDoubles(ones.data(), ones.size(), 0, request.mutable_scalars());
  v1::IntegrateResponse streamed, unary;
  ASSERT_NO_FATAL_FAILURE(StreamAndUnary(&v1::GeomFit::Stub::IntegrateStream, &v1::GeomFit::Stub::Integrate, request,
                                         {"fit", "integrate: fields", "integrate"}, &streamed, &unary));
  EXPECT_EQ(streamed.SerializeAsString(), unary.SerializeAsString());
  EXPECT_NEAR(unary.scalars(0), unary.area(), 1e-12 * unary.area());
}

TEST_F(ProgressStreamTest, RefineMeshStreamStoresTheSameMesh) {
  v1::RefineMeshRequest request;
  request.set_mesh_id(id_);
  *request.mutable_options() = Surface();
  v1::RefineMeshResponse streamed;
  v1::MeshInfo unary;
  ASSERT_NO_FATAL_FAILURE(StreamAndUnary(&v1::GeomFit::Stub::RefineMeshStream, &v1::GeomFit::Stub::RefineMesh, request,
                                         {"fit", "evaluate points"}, &streamed, &unary));
  EXPECT_EQ(streamed.mesh().content_hash(), unary.content_hash());
  EXPECT_EQ(streamed.mesh().num_faces(), 4 * mesh_.NumFaces());
}

/// A ComputeDifferentials response without what depends on timing.
std::vector<std::string> Untimed(std::vector<v1::ComputeDifferentialsResponse> chunks) {
  std::vector<std::string> out;
  for (v1::ComputeDifferentialsResponse& c : chunks) {
    c.mutable_summary()->clear_fit_ms();
    c.mutable_summary()->clear_evaluate_ms();
    out.push_back(c.SerializeAsString());
  }
  return out;
}

TEST_F(ProgressStreamTest, DifferentialsReportEachSmoothingPassThenTheSameRows) {
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(id_);
  request.mutable_options()->set_degree(4);
  request.mutable_options()->set_noise(v1::NOISE_MODE_ON);  // light noise at degree 4: two smoothing
                                                            // and two local passes, then the fit
  request.set_diagnostics(true);
  request.set_chunk_rows(250);
  request.set_progress(true);
  grpc::ClientContext ctx;
  // The smoothing passes' progress before any row; the last pass's among the rows.
  const std::vector<v1::ComputeDifferentialsResponse> with = ResultsAfterProgress(
      ReadAll(server_.stub().ComputeDifferentials(&ctx, request)), {"smooth 1/4", "smooth 2/4", "smooth 3/4", "smooth 4/4", "fit"},
      "fit");
  ASSERT_EQ(with.size(), static_cast<size_t>((mesh_.NumVertices() + 249) / 250));
  EXPECT_FALSE(with.back().summary().fit_cache_hit());
  // The same computation on a server of its own (not cached), without progress.
  InProcessServer other;
  ASSERT_TRUE(testing::UploadMesh(other.stub(), mesh_).ok());
  request.set_progress(false);
  grpc::ClientContext again;
  const std::vector<v1::ComputeDifferentialsResponse> without = ReadAll(other.stub().ComputeDifferentials(&again, request));
  for (const auto& c : without) EXPECT_FALSE(c.has_progress());
  EXPECT_FALSE(without.back().summary().fit_cache_hit());
  EXPECT_EQ(Untimed(with), Untimed(without));
  // Cached: no pass runs, so no progress message; the rows are the same.
  grpc::ClientContext cached;
  request.set_progress(true);
  const auto hit = ReadAll(server_.stub().ComputeDifferentials(&cached, request));
  for (const auto& c : hit) EXPECT_FALSE(c.has_progress());
  ASSERT_EQ(hit.size(), with.size());
  EXPECT_TRUE(hit.back().summary().fit_cache_hit());
  for (size_t i = 0; i < hit.size(); ++i) EXPECT_EQ(hit[i].normals().data(), with[i].normals().data()) << i;
}

TEST_F(ProgressStreamTest, NoiseAutoAndTwoPassNameTheirPasses) {
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(id_);
  request.mutable_options()->set_degree(3);
  request.mutable_options()->set_noise(v1::NOISE_MODE_AUTO);  // a clean torus: the test, then one fit
  request.mutable_options()->set_two_pass(true);
  request.set_progress(true);
  grpc::ClientContext ctx;
  const auto rows = ResultsAfterProgress(ReadAll(server_.stub().ComputeDifferentials(&ctx, request)),
                                         {"noise test", "frames", "fit"}, "fit");
  EXPECT_FALSE(rows.empty());
}

TEST_F(ProgressStreamTest, MembraneReportsTheFitAndTheEvaluationBeforeTheSameRows) {
  v1::ComputeMembraneRequest request;
  request.set_mesh_id(id_);
  request.set_young_modulus(1.0);
  request.set_poisson_ratio(0.3);
  request.add_quantities(v1::MEMBRANE_QUANTITY_PRESSURE);
  request.add_quantities(v1::MEMBRANE_QUANTITY_STRESS);
  const Positions deformed = mesh_.positions * 1.05;
  wire::EncodeDoubles(deformed.data(), deformed.rows(), 3, request.mutable_deformed_positions());
  request.set_chunk_rows(400);
  request.set_progress(true);
  grpc::ClientContext ctx;
  std::vector<v1::ComputeMembraneResponse> with =
      ResultsAfterProgress(ReadAll(server_.stub().ComputeMembrane(&ctx, request)), {"fit", "membrane"});
  ASSERT_EQ(with.size(), static_cast<size_t>((mesh_.NumVertices() + 399) / 400));
  EXPECT_GT(with[0].fit_ms(), 0);  // fitted by this request
  request.set_progress(false);
  grpc::ClientContext again;
  std::vector<v1::ComputeMembraneResponse> without = ReadAll(server_.stub().ComputeMembrane(&again, request));
  ASSERT_EQ(with.size(), without.size());
  for (auto* r : {&with, &without}) (*r)[0].clear_fit_ms(), (*r)[0].clear_evaluate_ms();
  for (size_t i = 0; i < with.size(); ++i) {
    EXPECT_FALSE(without[i].has_progress());
    EXPECT_EQ(with[i].SerializeAsString(), without[i].SerializeAsString()) << "chunk " << i;
  }
}

TEST_F(ProgressStreamTest, StreamingVariantsReportErrorsLikeTheUnaryCalls) {
  v1::IntegrateRequest request;
  request.set_mesh_id("m-missing");
  grpc::ClientContext ctx;
  auto reader = server_.stub().IntegrateStream(&ctx, request);
  v1::IntegrateResponse m;
  EXPECT_FALSE(reader->Read(&m));
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
}

}  // namespace
}  // namespace geomfit::server
