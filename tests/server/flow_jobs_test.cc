// Flows as jobs over gRPC: a semi-implicit MCF on a small sphere (per-step events,
// snapshot revisions readable by ComputeDifferentials, the radius against
// sqrt(R0^2 - 2t)), cancel, an explicit blow-up naming the step, a concurrent update,
// and bad inputs naming their fields.
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "absl/strings/str_cat.h"

#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;
using testing::WatchJob;

v1::FlowJob Spec(const std::string& mesh_id, const std::string& scheme, double dt, int steps) {
  v1::FlowJob spec;
  spec.set_mesh_id(mesh_id);
  spec.set_kind("mcf");
  spec.set_scheme(scheme);
  spec.set_dt(dt);
  spec.set_steps(steps);
  return spec;
}

absl::StatusOr<v1::Job> StartFlow(v1::GeomFit::Stub& stub, const v1::FlowJob& spec) {
  grpc::ClientContext ctx;
  v1::Job job;
  const grpc::Status s = stub.StartFlow(&ctx, spec, &job);
  if (!s.ok()) return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
  return job;
}

double MaxRadiusError(const Mesh& m, double radius) {
  return (m.positions.rowwise().norm().array() - radius).abs().maxCoeff();
}

TEST(FlowJobsTest, SemiImplicitMcfShrinksTheSphere) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(8);  // 386 vertices, unit radius
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(info.ok()) << info.status();
  v1::FlowJob spec = Spec(info->mesh_id(), "semi_implicit", 1e-3, 50);
  spec.set_snapshot_every(20);
  spec.set_send_positions(true);
  absl::StatusOr<v1::Job> job = StartFlow(server.stub(), spec);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->kind(), "flow");
  EXPECT_EQ(job->request().flow().steps(), 50);

  std::vector<v1::JobEvent> all;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &all).ok());
  ASSERT_GE(all.size(), 2u);
  ASSERT_TRUE(all.back().final());
  ASSERT_EQ(all.back().state(), v1::JOB_STATE_SUCCEEDED) << all.back().message();
  std::vector<int64_t> steps, snapshot_steps, revisions;
  for (const v1::JobEvent& e : all) {
    if (e.phase() == "step") {
      steps.push_back(e.step());
      EXPECT_NEAR(e.time(), 1e-3 * e.step(), 1e-12);
      for (const char* name : {"area", "volume", "max_speed", "fit_ms", "assemble_ms", "solve_ms", "step_ms"})
        EXPECT_EQ(e.values().count(name), 1u) << name;
      EXPECT_GT(e.counts().at("solver_iterations"), 0);
      EXPECT_NEAR(e.values().at("max_speed"), 1.0, 0.1);  // |H| ~ 1/R
    }
    if (e.phase() == "snapshot") {
      snapshot_steps.push_back(e.step());
      ASSERT_EQ(e.results_size(), 1);
      EXPECT_EQ(e.results(0).mesh_id(), info->mesh_id());
      revisions.push_back(e.results(0).revision());
      ASSERT_EQ(e.arrays_size(), 1);
      EXPECT_EQ(e.arrays(0).name(), "positions");
      EXPECT_EQ(e.arrays(0).array().data().size(), 8u * 3 * sphere.NumVertices());
    }
  }
  ASSERT_EQ(steps.size(), 50u);
  for (int i = 0; i < 50; ++i) EXPECT_EQ(steps[i], i + 1);
  EXPECT_EQ(snapshot_steps, (std::vector<int64_t>{20, 40, 50}));
  EXPECT_EQ(revisions, (std::vector<int64_t>{info->revision() + 1, info->revision() + 2, info->revision() + 3}));
  ASSERT_EQ(all.back().results_size(), 1);
  ASSERT_FALSE(revisions.empty());
  EXPECT_EQ(all.back().results(0).revision(), revisions.back());

  // The final revision is the mesh now: R(0.05) = sqrt(1 - 2t) (the Table 5.1 protocol;
  // 1.8e-4 on this cubed sphere with the flow's compact stencils, bench/README.md).
  absl::StatusOr<Mesh> now = testing::Download(server.stub(), info->mesh_id());
  ASSERT_TRUE(now.ok()) << now.status();
  const double err = MaxRadiusError(*now, std::sqrt(1 - 2 * 0.05));
  std::printf("flow job, sphere n=8, 50 semi-implicit steps: Linf radius error %.3e\n", err);
  EXPECT_LE(err, 3.3e-4);
  // The positions sent with the last snapshot event are exactly the stored revision.
  const v1::JobEvent* last_snapshot = nullptr;
  for (const v1::JobEvent& e : all)
    if (e.phase() == "snapshot") last_snapshot = &e;
  ASSERT_NE(last_snapshot, nullptr);
  ASSERT_EQ(last_snapshot->arrays_size(), 1);
  const std::string& bytes = last_snapshot->arrays(0).array().data();
  ASSERT_EQ(bytes.size(), 8u * now->positions.size());
  EXPECT_EQ(std::memcmp(bytes.data(), now->positions.data(), bytes.size()), 0);

  // Other RPCs read the snapshot revision: H ~ 1/R at R = sqrt(0.9).
  v1::ComputeDifferentialsRequest compute;
  compute.set_mesh_id(info->mesh_id());
  compute.set_revision(revisions.back());
  compute.add_quantities(v1::QUANTITY_MEAN_CURVATURE);
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  ASSERT_TRUE(testing::Compute(server.stub(), compute, &chunks).ok());
  EXPECT_EQ(chunks.front().summary().revision(), revisions.back());
}

TEST(FlowJobsTest, CancelStopsTheFlow) {
  InProcessServer server;
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), testing::TestSphere(8), "sphere");
  ASSERT_TRUE(info.ok());
  absl::StatusOr<v1::Job> job = StartFlow(server.stub(), Spec(info->mesh_id(), "semi_implicit", 1e-5, 100000));
  ASSERT_TRUE(job.ok()) << job.status();
  std::vector<v1::JobEvent> all;
  bool cancelled = false;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &all, [&](const v1::JobEvent& e) {
                if (!cancelled && e.phase() == "step" && e.step() == 3) {
                  EXPECT_TRUE(testing::CancelJob(server.stub(), e.job_id()).ok());
                  cancelled = true;
                }
                return false;
              }).ok());
  ASSERT_TRUE(cancelled);
  ASSERT_FALSE(all.empty());
  EXPECT_EQ(all.back().state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(all.back().error_code(), static_cast<int>(absl::StatusCode::kCancelled));
  EXPECT_LT(all.back().seq(), 1000);  // stopped within a few steps of 100000
}

TEST(FlowJobsTest, ExplicitBlowUpFailsNamingTheStep) {
  InProcessServer server;
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), testing::TestSphere(8), "sphere");
  ASSERT_TRUE(info.ok());
  v1::FlowJob spec = Spec(info->mesh_id(), "explicit", 0.05, 15);  // many times the explicit limit
  spec.set_snapshot_every(1);
  absl::StatusOr<v1::Job> job = StartFlow(server.stub(), spec);
  ASSERT_TRUE(job.ok()) << job.status();
  std::vector<v1::JobEvent> all;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &all).ok());
  ASSERT_FALSE(all.empty());
  const v1::JobEvent& last = all.back();
  ASSERT_EQ(last.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(last.error_code(), static_cast<int>(absl::StatusCode::kFailedPrecondition));
  int good = 0;
  for (const v1::JobEvent& e : all) good += e.phase() == "step";
  EXPECT_LT(good, 15);
  std::printf("explicit dt = 0.05: %d good steps; %s\n", good, last.message().c_str());
  EXPECT_NE(last.message().find("step " + std::to_string(good + 1) + " "), std::string::npos) << last.message();
  EXPECT_NE(last.message().find("explicit"), std::string::npos) << last.message();
  // The last good snapshot is the mesh's latest revision, named in the message.
  grpc::ClientContext ctx;
  v1::GetMeshRequest get;
  get.set_mesh_id(info->mesh_id());
  v1::MeshInfo now;
  ASSERT_TRUE(server.stub().GetMesh(&ctx, get, &now).ok());
  EXPECT_EQ(now.revision(), info->revision() + good);
  EXPECT_NE(last.message().find("last good snapshot: revision " + std::to_string(now.revision())),
            std::string::npos)
      << last.message();
  absl::StatusOr<Mesh> mesh = testing::Download(server.stub(), info->mesh_id());
  ASSERT_TRUE(mesh.ok());
  EXPECT_TRUE(mesh->positions.allFinite());
}

TEST(FlowJobsTest, StopConditionEndsEarly) {
  InProcessServer server;
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), testing::TestSphere(6), "sphere");
  ASSERT_TRUE(info.ok());
  v1::FlowJob spec = Spec(info->mesh_id(), "semi_implicit", 1e-2, 40);
  spec.set_max_area_change(0.05);  // A(t)/A0 = 1 - 2t: crossed after step 3
  absl::StatusOr<v1::Job> job = StartFlow(server.stub(), spec);
  ASSERT_TRUE(job.ok()) << job.status();
  std::vector<v1::JobEvent> all;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &all).ok());
  ASSERT_FALSE(all.empty());
  ASSERT_EQ(all.back().state(), v1::JOB_STATE_SUCCEEDED) << all.back().message();
  ASSERT_EQ(all.back().results_size(), 1);
  EXPECT_NE(all.back().message().find("max_area_change"), std::string::npos) << all.back().message();
  EXPECT_EQ(all.back().counts().at("steps"), 3);
  EXPECT_EQ(all.back().results(0).revision(), info->revision() + 1);
}

// FlowJob.time_tolerance reaches the stepper: unset is the core default 1e-3 (the same
// positions as 1e-3 given), 0 solves every step to 1e-12 (more iterations), and the two
// agree well below one step's local error dt^2 = 1e-6.
TEST(FlowJobsTest, TimeToleranceReachesTheSolves) {
  InProcessServer server;
  const double dt = 1e-3;
  int uploads = 0;
  const auto run = [&](std::optional<double> tolerance, int64_t* iterations) -> absl::StatusOr<Mesh> {
    // A fresh mesh per run (the name keeps the content-addressed ids apart).
    absl::StatusOr<v1::MeshInfo> info =
        testing::UploadMesh(server.stub(), testing::TestSphere(8), absl::StrCat("sphere ", ++uploads));
    if (!info.ok()) return info.status();
    v1::FlowJob spec = Spec(info->mesh_id(), "semi_implicit", dt, 10);
    if (tolerance) spec.set_time_tolerance(*tolerance);
    absl::StatusOr<v1::Job> job = StartFlow(server.stub(), spec);
    if (!job.ok()) return job.status();
    std::vector<v1::JobEvent> all;
    if (const grpc::Status s = WatchJob(server.stub(), job->job_id(), 0, &all); !s.ok())
      return absl::InternalError(s.error_message());
    if (all.empty() || all.back().state() != v1::JOB_STATE_SUCCEEDED)
      return absl::InternalError(all.empty() ? "no events" : all.back().message());
    *iterations = 0;
    for (const v1::JobEvent& e : all)
      if (e.phase() == "step" && e.step() > 3) *iterations += e.counts().at("solver_iterations");
    return testing::Download(server.stub(), info->mesh_id());  // the job's last revision
  };
  int64_t fixed_iterations = 0, default_iterations = 0, given_iterations = 0;
  absl::StatusOr<Mesh> fixed = run(0.0, &fixed_iterations);
  absl::StatusOr<Mesh> unset = run(std::nullopt, &default_iterations);
  absl::StatusOr<Mesh> given = run(1e-3, &given_iterations);
  ASSERT_TRUE(fixed.ok()) << fixed.status();
  ASSERT_TRUE(unset.ok()) << unset.status();
  ASSERT_TRUE(given.ok()) << given.status();
  const double diff = (unset->positions - fixed->positions).cwiseAbs().maxCoeff();
  std::printf("time_tolerance 0 vs unset: iterations of steps 4..10 %lld vs %lld, max position difference %.2e\n",
              static_cast<long long>(fixed_iterations), static_cast<long long>(default_iterations), diff);
  EXPECT_LT(default_iterations, fixed_iterations);
  EXPECT_LT(diff, 0.1 * dt * dt);  // 10% of one step's local error (6.1e-9 here)
  EXPECT_EQ(given_iterations, default_iterations);
  EXPECT_EQ((given->positions - unset->positions).cwiseAbs().maxCoeff(), 0.0);
}

TEST(FlowJobsTest, BadInputsNameTheirFields) {
  InProcessServer server;
  v1::GeomFit::Stub& stub = server.stub();
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(stub, testing::TestSphere(4), "sphere");
  ASSERT_TRUE(info.ok());
  const std::string id = info->mesh_id();
  struct Case {
    v1::FlowJob spec;
    std::string field;
  };
  std::vector<Case> cases;
  cases.push_back({Spec(id, "semi_implicit", 0, 5), "flow.dt"});
  cases.push_back({Spec(id, "semi_implicit", -1, 5), "flow.dt"});
  cases.push_back({Spec(id, "semi_implicit", std::nan(""), 5), "flow.dt"});
  cases.push_back({Spec(id, "semi_implicit", 1e-3, 0), "flow.steps"});
  cases.push_back({Spec(id, "crank_nicolson", 1e-3, 5), "flow.scheme"});
  {
    v1::FlowJob s = Spec(id, "semi_implicit", 1e-3, 5);
    s.set_kind("willmore");
    cases.push_back({s, "flow.kind"});
    s = Spec(id, "semi_implicit", 1e-3, 5);
    s.mutable_fit()->set_degree(0);
    s.mutable_fit()->set_rings(2);
    cases.push_back({s, "flow.fit.degree"});
    s.mutable_fit()->set_degree(7);
    cases.push_back({s, "flow.fit"});
    s = Spec(id, "semi_implicit", 1e-3, 5);
    s.set_max_volume_change(std::nan(""));
    cases.push_back({s, "flow.max_volume_change"});
    for (double tol : {-1e-3, std::nan(""), HUGE_VAL}) {
      s = Spec(id, "semi_implicit", 1e-3, 5);
      s.set_time_tolerance(tol);
      cases.push_back({s, "flow.time_tolerance"});
    }
    s = Spec(id, "semi_implicit", 1e-3, 5);
    s.set_solver("cholesky");
    cases.push_back({s, "flow.solver"});
    s = Spec("", "semi_implicit", 1e-3, 5);
    cases.push_back({s, "flow.mesh_id"});
  }
  for (const Case& c : cases) {
    absl::StatusOr<v1::Job> job = StartFlow(stub, c.spec);
    EXPECT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument) << c.field << ": " << job.status();
    EXPECT_NE(job.status().message().find(c.field), std::string::npos) << job.status();
  }
  EXPECT_EQ(StartFlow(stub, Spec("m-nope", "semi_implicit", 1e-3, 5)).status().code(), absl::StatusCode::kNotFound);

  // An open surface: flows take no boundary conditions.
  Mesh open = testing::TestSphere(4);
  open.faces.Mutable().conservativeResize(open.faces.rows() - 1, Eigen::NoChange);
  absl::StatusOr<v1::MeshInfo> cap = testing::UploadMesh(stub, open, "open");
  ASSERT_TRUE(cap.ok()) << cap.status();
  absl::StatusOr<v1::Job> job = StartFlow(stub, Spec(cap->mesh_id(), "semi_implicit", 1e-3, 5));
  EXPECT_EQ(job.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(job.status().message().find("open surface"), std::string::npos) << job.status();
}

}  // namespace
}  // namespace geomfit::server
