// The engine through the service: every long RPC stops computing once the client
// cancels (the server's CPU time, not the client's wall time), a request finishes on the
// revision it started with, and shutdown honours the drain time.
#include <functional>
#include <thread>

#include <gtest/gtest.h>

#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;

int64_t StoredMeshes(v1::GeomFit::Stub& stub) {
  grpc::ClientContext ctx;
  v1::ListMeshesResponse r;
  EXPECT_TRUE(stub.ListMeshes(&ctx, v1::ListMeshesRequest(), &r).ok());
  return r.meshes_size();
}

v1::ReconstructionOptions Surface(int degree) {
  v1::ReconstructionOptions o;
  o.mutable_fit()->set_degree(degree);
  return o;
}

/// A long RPC started with `ctx`; returns its status.
using LongCall = std::function<grpc::Status(grpc::ClientContext* ctx)>;

struct CancelOutcome {
  grpc::Status status;
  double cpu_after_grace = 0;  ///< CPU seconds spent from 100 ms to 700 ms after the cancel
};

/// Starts `call`, cancels it after `run_ms`, and measures the CPU the process spends
/// once 100 ms have passed since the cancel.
CancelOutcome CancelAfter(const LongCall& call, int run_ms) {
  grpc::ClientContext ctx;
  CancelOutcome out;
  std::thread t([&] { out.status = call(&ctx); });
  std::this_thread::sleep_for(std::chrono::milliseconds(run_ms));
  out.cpu_after_grace = testing::CpuSecondsAfterCancel([&] { ctx.TryCancel(); });
  t.join();
  return out;
}

class EngineTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto info = testing::UploadMesh(server_.stub(), testing::TestTorus(100), "long", 20000);
    ASSERT_TRUE(info.ok()) << info.status();
    id_ = info->mesh_id();
  }
  /// Caches the reconstruction fits with a quick request of the same surface, so that a
  /// cancel lands in the RPC's own long phase (integration, refinement, ...).
  void WarmSurface() {
    grpc::ClientContext ctx;
    v1::IntegrateRequest r;
    r.set_mesh_id(id_);
    *r.mutable_options() = Surface(4);
    r.set_quadrature_degree(1);
    v1::IntegrateResponse out;
    ASSERT_TRUE(server_.stub().Integrate(&ctx, r, &out).ok());
  }
  v1::IntegrateRequest LongIntegrateRequest() const {
    v1::IntegrateRequest r;
    r.set_mesh_id(id_);
    *r.mutable_options() = Surface(4);
    r.set_quadrature_degree(30);
    return r;
  }
  grpc::Status LongIntegrate(grpc::ClientContext* ctx, v1::IntegrateResponse* out) {
    return server_.stub().Integrate(ctx, LongIntegrateRequest(), out);
  }
  /// The long integration as IntegrateStream on `*thread` (its response in *out): the
  /// future is ready once the integration's own phase began, on the revision it took
  /// (an event, not a sleep that a loaded machine outlasts).
  std::future<void> LongIntegrateInBackground(v1::IntegrateResponse* out, grpc::Status* status, std::thread* thread) {
    return testing::StreamInBackground<v1::IntegrateResponse>(
        [this, r = LongIntegrateRequest()](grpc::ClientContext* ctx) { return server_.stub().IntegrateStream(ctx, r); },
        "integrate", out, status, thread);
  }

  InProcessServer server_;
  std::string id_;
};

void ExpectStopped(const CancelOutcome& c, const char* rpc) {
  EXPECT_EQ(c.status.error_code(), grpc::StatusCode::CANCELLED) << rpc << ": " << c.status.error_message();
  EXPECT_LT(c.cpu_after_grace, testing::kStoppedCpuSeconds) << rpc << " kept computing after the client cancelled";
}

TEST_F(EngineTest, CancelledIntegrateStopsComputing) {
  WarmSurface();
  ExpectStopped(CancelAfter([&](grpc::ClientContext* ctx) {
                  v1::IntegrateResponse out;
                  return LongIntegrate(ctx, &out);
                }, 300),
                "Integrate");
}

TEST_F(EngineTest, CancelledRefineStopsComputingAndStoresNothing) {
  WarmSurface();
  const int64_t before = StoredMeshes(server_.stub());
  ExpectStopped(CancelAfter([&](grpc::ClientContext* ctx) {
                  v1::RefineMeshRequest r;
                  r.set_mesh_id(id_);
                  *r.mutable_options() = Surface(4);
                  r.set_factor(8);
                  v1::MeshInfo out;
                  return server_.stub().RefineMesh(ctx, r, &out);
                }, 300),
                "RefineMesh");
  EXPECT_EQ(StoredMeshes(server_.stub()), before) << "a cancelled refinement stored its mesh";
}

TEST_F(EngineTest, CancelledProjectionStopsComputing) {
  WarmSurface();
  Positions points(400000, 3);
  const Mesh torus = testing::TestTorus(100);
  for (Eigen::Index i = 0; i < points.rows(); ++i)
    points.row(i) = torus.positions.row(i % torus.NumVertices()) * (1 + 1e-3 * static_cast<double>(i % 7));
  v1::ProjectPointsRequest r;
  r.set_mesh_id(id_);
  *r.mutable_options() = Surface(4);
  wire::EncodeDoubles(points.data(), points.rows(), 3, r.mutable_points());
  ExpectStopped(CancelAfter([&](grpc::ClientContext* ctx) {
                  auto reader = server_.stub().ProjectPoints(ctx, r);
                  v1::ProjectPointsResponse chunk;
                  while (reader->Read(&chunk)) {
                  }
                  return reader->Finish();
                }, 300),
                "ProjectPoints");
}

TEST_F(EngineTest, CancelledFitStopsComputing) {
  // No warm-up: the cancel lands in the fit of a degree-6 LOP reconstruction.
  ExpectStopped(CancelAfter([&](grpc::ClientContext* ctx) {
                  v1::HighOrderNodesRequest r;
                  r.set_mesh_id(id_);
                  *r.mutable_options() = Surface(6);
                  r.mutable_options()->mutable_fit()->set_method(v1::FIT_METHOD_LOP);
                  r.set_order(3);
                  v1::HighOrderNodesResponse out;
                  return server_.stub().HighOrderNodes(ctx, r, &out);
                }, 150),
                "HighOrderNodes");
}

TEST_F(EngineTest, RequestFinishesOnTheRevisionItStartedWith) {
  WarmSurface();
  v1::IntegrateResponse out;
  grpc::Status status;
  std::thread t;
  LongIntegrateInBackground(&out, &status, &t).wait();  // integrating revision 1
  Mesh moved = testing::TestTorus(100);
  moved.positions *= 1.5;
  v1::SetPositionsRequest update;
  update.mutable_header()->set_mesh_id(id_);
  wire::EncodeDoubles(moved.positions.data(), moved.NumVertices(), 3, update.mutable_positions()->mutable_positions());
  grpc::ClientContext ctx;
  v1::MeshInfo info;
  ASSERT_TRUE(server_.stub().SetPositions(&ctx, update, &info).ok());
  EXPECT_EQ(info.revision(), 2);
  t.join();
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(out.revision(), 1);
  EXPECT_NEAR(out.area(), 4 * M_PI * M_PI * 1.0 * 0.3, 1e-4) << "the area of revision 1 (R = 1, r = 0.3), not 1.5^2 times it";
}

TEST_F(EngineTest, DrainCancelsLongWorkAtTheDeadline) {
  WarmSurface();
  v1::IntegrateResponse out;
  grpc::Status status;
  std::thread t;
  LongIntegrateInBackground(&out, &status, &t).wait();  // in its long phase
  // CPU, not wall time, after the drain deadline: a loaded machine slows the stop down.
  const double cpu = testing::CpuSecondsAfterCancel([&] { server_.server().Shutdown(0.5); },
                                                    std::chrono::milliseconds(500));
  t.join();
  EXPECT_LT(cpu, testing::kStoppedCpuSeconds) << "the integration went on after the drain deadline";
  EXPECT_FALSE(status.ok()) << "the integration ended before the drain deadline: too short to test draining";
}

}  // namespace
}  // namespace geomfit::server
