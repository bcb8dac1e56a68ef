// Membranes over gRPC (chapter 6): ComputeMembrane on the balloon (6.3.4) from sent
// positions and from a stored deformed mesh (same values), chunked; the pressure-load
// solve as a job (Newton events, the stored revision on the closed-form radius, its
// pressure read back with ComputeMembrane from the reference's positions), a new-mesh result, a Newton that does not
// converge (FAILED with its history, nothing stored), a cancelled solve (CANCELLED,
// nothing stored), and bad inputs naming their fields.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/surfaces/analytic.h"
#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;
using testing::WatchJob;

constexpr double kBalloon = 100 / 0.8 * (1.21 - 1) / 1.1;  // (6.3.4): 23.8636
constexpr double kInverseRadius = 1.0080320;                 // unit sphere under [p] = 2

v1::ComputeMembraneRequest Request(const std::string& mesh_id) {
  v1::ComputeMembraneRequest r;
  r.set_mesh_id(mesh_id);
  r.set_young_modulus(100);
  r.set_poisson_ratio(0.2);
  return r;
}

void SetPositions(const Positions& p, v1::ComputeMembraneRequest* r) {
  wire::EncodeDoubles(p.data(), p.rows(), 3, r->mutable_deformed_positions());
}

absl::StatusOr<std::vector<v1::ComputeMembraneResponse>> Compute(v1::GeomFit::Stub& stub,
                                                                 const v1::ComputeMembraneRequest& request) {
  grpc::ClientContext ctx;
  auto reader = stub.ComputeMembrane(&ctx, request);
  std::vector<v1::ComputeMembraneResponse> out;
  v1::ComputeMembraneResponse r;
  while (reader->Read(&r)) out.push_back(r);
  const grpc::Status s = reader->Finish();
  if (!s.ok()) return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
  return out;
}

/// The chunks' `field` arrays concatenated.
std::vector<double> Gather(const std::vector<v1::ComputeMembraneResponse>& chunks,
                           const v1::DoubleArray& (v1::ComputeMembraneResponse::*field)() const) {
  std::vector<double> out;
  for (const auto& c : chunks) {
    const std::string& d = (c.*field)().data();
    const size_t at = out.size();
    out.resize(at + d.size() / 8);
    std::memcpy(out.data() + at, d.data(), d.size());
  }
  return out;
}

absl::StatusOr<v1::Job> StartSolve(v1::GeomFit::Stub& stub, const v1::MembraneSolveJob& spec) {
  grpc::ClientContext ctx;
  v1::Job job;
  const grpc::Status s = stub.StartMembraneSolve(&ctx, spec, &job);
  if (!s.ok()) return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
  return job;
}

v1::MembraneSolveJob Solve(const std::string& mesh_id, double pressure) {
  v1::MembraneSolveJob spec;
  spec.set_mesh_id(mesh_id);
  spec.set_young_modulus(100);
  spec.set_poisson_ratio(0.2);
  spec.set_pressure(pressure);
  return spec;
}

/// The mesh's latest revision (GetMesh); 0 if it fails.
int64_t LatestRevision(v1::GeomFit::Stub& stub, const std::string& mesh_id) {
  grpc::ClientContext ctx;
  v1::GetMeshRequest get;
  get.set_mesh_id(mesh_id);
  v1::MeshInfo info;
  EXPECT_TRUE(stub.GetMesh(&ctx, get, &info).ok());
  return info.revision();
}

TEST(MembraneRpcTest, BalloonPressureFromPositionsAndFromAStoredMesh) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(8);
  absl::StatusOr<v1::MeshInfo> ref = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(ref.ok()) << ref.status();
  Mesh balloon = sphere;
  balloon.positions *= 1.1;

  v1::ComputeMembraneRequest sent = Request(ref->mesh_id());
  SetPositions(balloon.positions, &sent);
  sent.set_chunk_rows(100);
  for (int q = 1; q <= 6; ++q) sent.add_quantities(static_cast<v1::MembraneQuantity>(q));
  absl::StatusOr<std::vector<v1::ComputeMembraneResponse>> a = Compute(server.stub(), sent);
  ASSERT_TRUE(a.ok()) << a.status();
  const int n = sphere.NumVertices();
  EXPECT_EQ(static_cast<int>(a->size()), (n + 99) / 100);
  EXPECT_EQ(a->front().total_vertices(), n);
  EXPECT_EQ(a->front().revision(), 1);
  EXPECT_EQ(a->front().deformed_revision(), 0);
  const std::vector<double> p = Gather(*a, &v1::ComputeMembraneResponse::pressure);
  const std::vector<double> t = Gather(*a, &v1::ComputeMembraneResponse::traction);
  const std::vector<double> l = Gather(*a, &v1::ComputeMembraneResponse::stretches);
  ASSERT_EQ(static_cast<int>(p.size()), n);
  ASSERT_EQ(static_cast<int>(l.size()), 2 * n);
  EXPECT_EQ(static_cast<int>(Gather(*a, &v1::ComputeMembraneResponse::stress).size()), 9 * n);
  EXPECT_EQ(static_cast<int>(Gather(*a, &v1::ComputeMembraneResponse::strain).size()), 9 * n);
  EXPECT_EQ(static_cast<int>(Gather(*a, &v1::ComputeMembraneResponse::von_mises).size()), n);
  double perr = 0, terr = 0, lerr = 0;
  for (int i = 0; i < n; ++i) {
    perr = std::max(perr, std::abs(p[i] / kBalloon - 1));
    terr = std::max(terr, std::abs(t[i] / kBalloon + 1));
    lerr = std::max({lerr, std::abs(l[2 * i] - 1.1), std::abs(l[2 * i + 1] - 1.1)});
  }
  std::printf("balloon over gRPC, %d vertices: max rel. error p %.2e, traction %.2e, stretch %.2e\n", n, perr, terr,
              lerr);
  EXPECT_LT(perr, 1e-2);  // degree 4 on 386 jittered vertices (orders: tests/mechanics)
  EXPECT_LT(terr, 1e-2);
  EXPECT_LT(lerr, 1e-6);

  // The same deformation as a stored mesh of the same topology: the same values.
  absl::StatusOr<v1::MeshInfo> def = testing::UploadMesh(server.stub(), balloon, "balloon");
  ASSERT_TRUE(def.ok()) << def.status();
  v1::ComputeMembraneRequest stored = Request(ref->mesh_id());
  stored.mutable_deformed()->set_mesh_id(def->mesh_id());
  absl::StatusOr<std::vector<v1::ComputeMembraneResponse>> b = Compute(server.stub(), stored);
  ASSERT_TRUE(b.ok()) << b.status();
  EXPECT_EQ(b->front().deformed_revision(), 1);
  EXPECT_EQ(Gather(*b, &v1::ComputeMembraneResponse::pressure), p);
  EXPECT_EQ(Gather(*b, &v1::ComputeMembraneResponse::traction).size(), 0u);  // not asked for
}

TEST(MembraneRpcTest, BadInputsNameTheirFields) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(4);
  absl::StatusOr<v1::MeshInfo> ref = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(ref.ok()) << ref.status();
  absl::StatusOr<v1::MeshInfo> torus = testing::UploadMesh(server.stub(), testing::TestTorus(4), "torus");
  ASSERT_TRUE(torus.ok()) << torus.status();
  GeneratorOptions g;
  g.n = 4;
  absl::StatusOr<v1::MeshInfo> open = testing::UploadMesh(server.stub(), GenerateHemisphereMesh(g), "half");
  ASSERT_TRUE(open.ok()) << open.status();

  auto expect = [&](const v1::ComputeMembraneRequest& r, const std::string& field) {
    absl::StatusOr<std::vector<v1::ComputeMembraneResponse>> out = Compute(server.stub(), r);
    EXPECT_EQ(out.status().code(), absl::StatusCode::kInvalidArgument) << field << ": " << out.status();
    EXPECT_NE(out.status().message().find(field), std::string::npos) << out.status();
  };
  Positions short_y = sphere.positions.topRows(sphere.NumVertices() - 1);
  v1::ComputeMembraneRequest r = Request(ref->mesh_id());
  SetPositions(short_y, &r);
  expect(r, "deformed_positions");
  r = Request(ref->mesh_id());
  expect(r, "deformed");  // neither positions nor a mesh
  r.mutable_deformed()->set_mesh_id(torus->mesh_id());
  expect(r, "deformed.mesh_id");  // another topology
  SetPositions(sphere.positions, &r);
  expect(r, "deformed");  // both
  r = Request(ref->mesh_id());
  SetPositions(sphere.positions, &r);
  wire::EncodeDoubles(short_y.data(), short_y.rows(), 3, r.mutable_reference_positions());
  expect(r, "reference_positions");
  r = Request(ref->mesh_id());
  SetPositions(sphere.positions, &r);
  r.set_poisson_ratio(0.5);
  expect(r, "poisson_ratio");
  r.set_poisson_ratio(-1);
  expect(r, "poisson_ratio");
  r.set_poisson_ratio(0.2);
  r.set_young_modulus(0);
  expect(r, "young_modulus");
  r.set_young_modulus(100);
  r.mutable_options()->set_degree(7);
  expect(r, "options.degree");

  auto expect_job = [&](const v1::MembraneSolveJob& spec, const std::string& field) {
    absl::StatusOr<v1::Job> job = StartSolve(server.stub(), spec);
    EXPECT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << field << ": " << job.status();
    EXPECT_NE(job.status().message().find(field), std::string::npos) << job.status();
  };
  v1::MembraneSolveJob spec = Solve(ref->mesh_id(), std::nan(""));
  expect_job(spec, "membrane.pressure");
  spec = Solve(ref->mesh_id(), 2);
  spec.set_poisson_ratio(0.5);
  expect_job(spec, "membrane.poisson_ratio");
  spec = Solve(ref->mesh_id(), 2);
  spec.set_young_modulus(-1);
  expect_job(spec, "membrane.young_modulus");
  spec = Solve(ref->mesh_id(), 2);
  spec.clear_pressure();
  expect_job(spec, "membrane.pressure");
  std::vector<double> field(sphere.NumVertices() + 1, 2.0);
  wire::EncodeDoubles(field.data(), field.size(), 0, spec.mutable_pressure_field());
  expect_job(spec, "membrane.pressure_field");
  spec = Solve(open->mesh_id(), 2);
  expect_job(spec, "membrane.boundary");  // an open mesh without a boundary condition
  spec = Solve(ref->mesh_id(), 2);
  spec.mutable_fit()->set_degree(1);
  expect_job(spec, "membrane.fit.degree");
  spec = Solve(ref->mesh_id(), 2);
  spec.set_solver("cholesky");
  expect_job(spec, "membrane.solver");
}

TEST(MembraneRpcTest, SolveStoresTheInflatedSphereAndItsPressureReadsBack) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(8);
  absl::StatusOr<v1::MeshInfo> ref = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(ref.ok()) << ref.status();
  v1::MembraneSolveJob spec = Solve(ref->mesh_id(), 2);
  spec.set_send_displacement(true);
  absl::StatusOr<v1::Job> job = StartSolve(server.stub(), spec);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->kind(), "membrane");
  std::vector<v1::JobEvent> events;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &events).ok());
  ASSERT_EQ(events.back().state(), v1::JOB_STATE_SUCCEEDED) << events.back().message();
  std::vector<double> residuals;
  bool stored = false;
  for (const v1::JobEvent& e : events) {
    if (e.phase() == "newton") {
      residuals.push_back(e.values().at("residual"));
      EXPECT_EQ(e.values().count("step"), 1u);
      EXPECT_EQ(e.counts().count("iteration"), 1u);
      EXPECT_EQ(e.counts().at("krylov_iterations"), 0);  // the direct solve
    }
    if (e.phase() == "stored") {
      stored = true;
      ASSERT_EQ(e.arrays_size(), 1);
      EXPECT_EQ(e.arrays(0).name(), "displacement");
      EXPECT_EQ(e.arrays(0).array().data().size(), 8u * 3 * sphere.NumVertices());
    }
  }
  ASSERT_GE(residuals.size(), 1u);
  EXPECT_TRUE(stored);
  EXPECT_LE(residuals.back(), 1e-10);
  EXPECT_LE(events.back().values().at("residual"), 1e-10);
  ASSERT_EQ(events.back().results_size(), 1);
  EXPECT_EQ(events.back().results(0).mesh_id(), ref->mesh_id());
  EXPECT_EQ(events.back().results(0).revision(), 2);

  absl::StatusOr<Mesh> deformed = testing::Download(server.stub(), ref->mesh_id());
  ASSERT_TRUE(deformed.ok()) << deformed.status();
  const double rerr = (deformed->positions.rowwise().norm().array() - kInverseRadius).abs().maxCoeff();
  const Eigen::Vector3d centroid = (deformed->positions - sphere.positions).colwise().mean().transpose();
  std::printf("solve over gRPC: %zu Newton iterations, max |r - r1| %.2e, centroid shift %.1e\n", residuals.size(), rerr,
              centroid.norm());
  EXPECT_LT(rerr, 1e-3);
  EXPECT_LT(centroid.norm(), 1e-12);

  // Its pressure with ComputeMembrane: revision 1 is no longer kept, so the reference's
  // positions go with the request and the deformed surface is the stored revision 2.
  v1::ComputeMembraneRequest r = Request(ref->mesh_id());
  r.set_revision(1);
  r.mutable_deformed()->set_revision(2);
  absl::StatusOr<std::vector<v1::ComputeMembraneResponse>> gone = Compute(server.stub(), r);
  EXPECT_EQ(gone.status().code(), absl::StatusCode::kNotFound) << gone.status();
  r.set_revision(0);
  wire::EncodeDoubles(sphere.positions.data(), sphere.NumVertices(), 3, r.mutable_reference_positions());
  r.add_quantities(v1::MEMBRANE_QUANTITY_PRESSURE);
  absl::StatusOr<std::vector<v1::ComputeMembraneResponse>> chunks = Compute(server.stub(), r);
  ASSERT_TRUE(chunks.ok()) << chunks.status();
  double perr = 0;
  for (double p : Gather(*chunks, &v1::ComputeMembraneResponse::pressure)) perr = std::max(perr, std::abs(p - 2));
  EXPECT_LT(perr, 1e-2);

  // new_mesh: the result is another mesh; the reference stays the latest revision.
  spec.set_new_mesh(true);
  spec.set_send_displacement(false);
  spec.set_revision(0);
  spec.set_mesh_id(ref->mesh_id());
  job = StartSolve(server.stub(), spec);  // solves revision 2 under 2 more
  ASSERT_TRUE(job.ok()) << job.status();
  events.clear();
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &events).ok());
  ASSERT_EQ(events.back().state(), v1::JOB_STATE_SUCCEEDED) << events.back().message();
  ASSERT_EQ(events.back().results_size(), 1);
  EXPECT_NE(events.back().results(0).mesh_id(), ref->mesh_id());
  EXPECT_EQ(LatestRevision(server.stub(), ref->mesh_id()), 2);
}

TEST(MembraneRpcTest, NewtonThatDoesNotConvergeFailsAndStoresNothing) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(6);
  absl::StatusOr<v1::MeshInfo> ref = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(ref.ok()) << ref.status();
  v1::MembraneSolveJob spec = Solve(ref->mesh_id(), 2);
  spec.set_max_iterations(1);
  spec.set_max_load_cuts(0);
  spec.set_tolerance(1e-15);
  absl::StatusOr<v1::Job> job = StartSolve(server.stub(), spec);
  ASSERT_TRUE(job.ok()) << job.status();
  std::vector<v1::JobEvent> events;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &events).ok());
  const v1::JobEvent& last = events.back();
  EXPECT_EQ(last.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(last.error_code(), static_cast<int>(absl::StatusCode::kFailedPrecondition));
  EXPECT_NE(last.message().find("residual history"), std::string::npos) << last.message();
  EXPECT_EQ(last.results_size(), 0);
  int newton = 0;
  for (const v1::JobEvent& e : events) newton += e.phase() == "newton";
  EXPECT_EQ(newton, 1);
  EXPECT_EQ(LatestRevision(server.stub(), ref->mesh_id()), 1);  // nothing stored
}

// CancelJob during a long solve (an unreachable tolerance keeps Newton and its load cuts
// going: up to 12 x 7 iterations) stops it at the next poll, within 100 ms (the server's
// CPU time from then on): CANCELLED, nothing stored.
TEST(MembraneRpcTest, CancelStopsTheSolveAndStoresNothing) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(8);
  absl::StatusOr<v1::MeshInfo> ref = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(ref.ok()) << ref.status();
  v1::MembraneSolveJob spec = Solve(ref->mesh_id(), 2);
  spec.set_solver("gmres");
  spec.set_tolerance(1e-15);
  spec.set_max_iterations(12);
  spec.set_max_load_cuts(6);
  absl::StatusOr<v1::Job> job = StartSolve(server.stub(), spec);
  ASSERT_TRUE(job.ok()) << job.status();
  std::vector<v1::JobEvent> events;
  bool cancelled = false;
  double cpu_after_cancel = 0;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &events, [&](const v1::JobEvent& e) {
                if (!cancelled && e.phase() == "newton") {
                  EXPECT_GE(e.counts().at("krylov_iterations"), 1);  // GMRES's, streamed per iteration
                  cpu_after_cancel = testing::CpuSecondsAfterCancel(
                      [&] { EXPECT_TRUE(testing::CancelJob(server.stub(), e.job_id()).ok()); });
                  cancelled = true;
                }
                return false;
              }).ok());
  ASSERT_TRUE(cancelled);
  EXPECT_LT(cpu_after_cancel, testing::kStoppedCpuSeconds) << "the solve kept computing after CancelJob";
  const v1::JobEvent& last = events.back();
  EXPECT_EQ(last.state(), v1::JOB_STATE_CANCELLED) << last.message();
  EXPECT_EQ(last.error_code(), static_cast<int>(absl::StatusCode::kCancelled));
  EXPECT_EQ(last.results_size(), 0);
  int newton = 0;
  for (const v1::JobEvent& e : events) {
    newton += e.phase() == "newton";
    EXPECT_NE(e.phase(), "stored");
  }
  EXPECT_LT(newton, 12);  // stopped within a few iterations of the 84 it could run
  EXPECT_EQ(LatestRevision(server.stub(), ref->mesh_id()), 1);  // nothing stored
}

}  // namespace
}  // namespace geomfit::server
