// Quotas and fairness over gRPC: over a store quota (--quota-meshes, --quota-bytes) an
// upload, a refinement or a job is RESOURCE_EXHAUSTED naming the quota; over
// --quota-inflight a tenant's next compute request is; and queued compute is served in
// turn across tenants, so one tenant's backlog of 300 calls does not queue another's.
#include <atomic>
#include <condition_variable>
#include <filesystem>
#include <memory>
#include <mutex>
#include <vector>

#include <gtest/gtest.h>

#include "server/thread_pool.h"
#include "server/workspace/workspace.h"
#include "tests/server/tenant_util.h"

namespace geomfit::server::testing {
namespace {

TEST(QuotaClientTest, StoredMeshesOverQuotaAreResourceExhaustedWhateverStoresThem) {
  ServerOptions o = TenantOptions();
  o.quota_meshes = 1;
  InProcessServer server(o);
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  auto torus = a->Upload(TestTorus(6), "torus");
  ASSERT_TRUE(torus.ok()) << torus.status();
  EXPECT_TRUE(IsQuotaError(a->Upload(TestSphere(4), "sphere").status(), "--quota-meshes=1"));
  EXPECT_TRUE(a->Upload(TestTorus(6), "torus").ok()) << "an identical upload is the stored mesh";
  EXPECT_TRUE(b->Upload(TestSphere(4), "sphere").ok()) << "b's quota is b's";
  // Meshes derived on the server count too: a refinement, and a job's results.
  EXPECT_TRUE(IsQuotaError(a->RefineMesh(torus->mesh_id, 2).status(), "--quota-meshes=1"));
  v1::StartJobRequest start;
  start.mutable_refine()->set_mesh_id(torus->mesh_id);
  start.mutable_refine()->set_levels(1);
  auto job = a->StartJob(start);
  ASSERT_TRUE(job.ok()) << job.status();
  v1::JobEvent last;
  ASSERT_TRUE(a->WatchJob(job->job_id(), 0, [&](const v1::JobEvent& e) {
                  last = e;
                  return true;
                }).ok());
  EXPECT_EQ(last.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(last.error_code(), static_cast<int>(absl::StatusCode::kResourceExhausted));
  EXPECT_NE(last.message().find("tenant quota --quota-meshes=1 reached"), std::string::npos) << last.message();
  EXPECT_EQ(a->ListMeshes()->size(), 1u);
  // A delete frees the place.
  ASSERT_TRUE(a->DeleteMesh(torus->mesh_id).ok());
  EXPECT_TRUE(a->Upload(TestSphere(4), "sphere").ok());
}

TEST(QuotaClientTest, UsageSurvivesARestartWithTheSqliteStore) {
  ServerOptions o = TenantOptions();
  o.store = "sqlite";
  o.data_dir = WriteTempFile("geomfit_quota_data", "");
  std::filesystem::remove_all(o.data_dir);
  o.quota_meshes = 2;
  {
    InProcessServer server(o);
    auto a = ClientWith(server.port(), kTokenA);
    ASSERT_TRUE(a->Upload(TestTorus(5), "1").ok());
    ASSERT_TRUE(a->Upload(TestTorus(5), "2").ok());
  }
  InProcessServer server(o);
  auto a = ClientWith(server.port(), kTokenA);
  EXPECT_TRUE(IsQuotaError(a->Upload(TestTorus(5), "3").status(), "--quota-meshes=2"));
  EXPECT_TRUE(ClientWith(server.port(), kTokenB)->Upload(TestTorus(5), "3").ok());
  std::filesystem::remove_all(o.data_dir);
}

TEST(QuotaClientTest, SingleTenantModeAppliesQuotasToTheOneTenant) {
  ServerOptions o = LoopbackOptions();
  o.quota_bytes = MeshBytes(TestTorus(6));
  InProcessServer server(o);
  ASSERT_TRUE(UploadMesh(server.stub(), TestTorus(6), "fits exactly").ok());
  EXPECT_TRUE(IsQuotaError(UploadMesh(server.stub(), TestTorus(4), "one byte too many").status(),
                    "--quota-bytes=" + std::to_string(o.quota_bytes)));
}

/// One ComputeDifferentials call with a bearer token, read to its end on gRPC's
/// threads; `done` runs with its status.
class AsyncCompute final : public grpc::ClientReadReactor<v1::ComputeDifferentialsResponse> {
 public:
  AsyncCompute(v1::GeomFit::Stub& stub, const char* token, v1::ComputeDifferentialsRequest request,
               std::function<void(const grpc::Status&)> done)
      : request_(std::move(request)), done_(std::move(done)) {
    ctx_.AddMetadata("authorization", std::string("Bearer ") + token);
    stub.async()->ComputeDifferentials(&ctx_, &request_, this);
    StartRead(&chunk_);
    StartCall();
  }
  void OnReadDone(bool ok) override {
    if (ok) StartRead(&chunk_);
  }
  void OnDone(const grpc::Status& s) override { done_(s); }
  void Cancel() { ctx_.TryCancel(); }

 private:
  grpc::ClientContext ctx_;
  v1::ComputeDifferentialsRequest request_;
  v1::ComputeDifferentialsResponse chunk_;
  std::function<void(const grpc::Status&)> done_;
};

TEST(QuotaClientTest, InflightQuotaRefusesATenantsNextComputeRequest) {
  ServerOptions o = TenantOptions();
  o.quota_inflight = 1;
  InProcessServer server(o);
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  auto mine = a->Upload(TestTorus(6));
  auto theirs = b->Upload(TestTorus(6));
  ASSERT_TRUE(mine.ok() && theirs.ok());
  // A client waiting for each answer never meets its quota of 1.
  for (int degree = 1; degree <= 4; ++degree) {
    FitOptions fit;
    fit.degree = degree;
    ASSERT_TRUE(a->ComputeDifferentials(mine->mesh_id, fit).ok()) << degree;
    ASSERT_TRUE(a->UpdatePositions(mine->mesh_id, TestTorus(6).positions * (1.0 + degree)).ok()) << degree;
  }
  // Both workers held: one call of alpha's waits in the compute queue, holding alpha's slot.
  ThreadPool& compute = server.server().compute_pool();
  Gate gate;
  ASSERT_TRUE(compute.Submit("x", gate.Task()).ok());
  ASSERT_TRUE(compute.Submit("x", gate.Task()).ok());
  gate.AwaitStart(2);
  std::mutex mu;
  std::condition_variable changed;
  int done = 0;
  std::vector<grpc::Status> status(2);
  auto call = [&](const char* token, const std::string& id, int i) {
    v1::ComputeDifferentialsRequest r;
    r.set_mesh_id(id);
    r.add_quantities(v1::QUANTITY_NORMALS);
    return std::make_unique<AsyncCompute>(server.stub(), token, r, [&, i](const grpc::Status& s) {
      std::lock_guard<std::mutex> lock(mu);
      status[i] = s;
      ++done;
      changed.notify_all();
    });
  };
  auto queued_a = call(kTokenA, mine->mesh_id, 0);
  while (compute.Active("alpha") < 1) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  // Alpha's next compute request is refused at once, naming the quota; its store reads
  // are not compute; beta has a slot of its own.
  EXPECT_TRUE(IsQuotaError(a->ComputeDifferentials(mine->mesh_id, FitOptions()).status(), "--quota-inflight=1"));
  EXPECT_TRUE(IsQuotaError(a->UpdatePositions(mine->mesh_id, TestTorus(6).positions).status(), "--quota-inflight=1"));
  EXPECT_TRUE(IsQuotaError(a->RefineMesh(mine->mesh_id, 2).status(), "--quota-inflight=1"));
  EXPECT_TRUE(a->GetMesh(mine->mesh_id).ok());
  auto queued_b = call(kTokenB, theirs->mesh_id, 1);
  while (compute.Active("beta") < 1) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  gate.Open();
  {
    std::unique_lock<std::mutex> lock(mu);
    changed.wait(lock, [&] { return done == 2; });
  }
  EXPECT_TRUE(status[0].ok()) << status[0].error_message();
  EXPECT_TRUE(status[1].ok()) << status[1].error_message();
  EXPECT_TRUE(a->ComputeDifferentials(mine->mesh_id, FitOptions()).ok()) << "the answered call gave its slot back";
}

TEST(FairnessTest, OneTenantsBacklogDoesNotQueueAnothersCall) {
  ServerOptions o = TenantOptions();
  o.queue = 1000;  // alpha's 300 calls all wait in the queue
  InProcessServer server(o);
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  auto big = a->Upload(TestTorus(40), "mid-size");
  auto small = b->Upload(TestTorus(5), "small");
  ASSERT_TRUE(big.ok() && small.ok());
  // Every computation has a weight of its own, so that none joins another's or the cache's.
  auto request = [](const std::string& id, int i) {
    v1::ComputeDifferentialsRequest r;
    r.set_mesh_id(id);
    r.mutable_options()->set_degree(2);
    r.mutable_options()->set_weight_epsilon(0.01 + 1e-6 * i);
    r.add_quantities(v1::QUANTITY_MEAN_CURVATURE);
    return r;
  };
  // Unloaded, for the record (not asserted): one call of each.
  auto ms_of = [&](const char* token, const v1::ComputeDifferentialsRequest& r) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", std::string("Bearer ") + token);
    const auto start = std::chrono::steady_clock::now();
    auto reader = server.stub().ComputeDifferentials(&ctx, r);
    v1::ComputeDifferentialsResponse chunk;
    while (reader->Read(&chunk)) {
    }
    EXPECT_TRUE(reader->Finish().ok());
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  };
  RecordProperty("alpha_task_ms", std::to_string(ms_of(kTokenA, request(big->mesh_id, -1))));
  RecordProperty("beta_unloaded_ms", std::to_string(ms_of(kTokenB, request(small->mesh_id, -1))));

  // Both workers are held while alpha queues 300 computations, then beta queues one.
  ThreadPool& compute = server.server().compute_pool();
  Gate gate;
  ASSERT_TRUE(compute.Submit("alpha", gate.Task()).ok());
  ASSERT_TRUE(compute.Submit("alpha", gate.Task()).ok());
  gate.AwaitStart(2);
  constexpr int kFlood = 300;
  std::mutex mu;
  std::condition_variable changed;
  int a_done = 0, a_ok = 0, a_done_when_b_done = -1;
  grpc::Status b_status;
  std::vector<std::unique_ptr<AsyncCompute>> flood;
  for (int i = 0; i < kFlood; ++i) {
    flood.push_back(std::make_unique<AsyncCompute>(server.stub(), kTokenA, request(big->mesh_id, i), [&](const grpc::Status& s) {
      std::lock_guard<std::mutex> lock(mu);
      ++a_done;
      a_ok += s.ok();
      changed.notify_all();
    }));
  }
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (compute.Active("alpha") < kFlood + 2 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  EXPECT_EQ(compute.Active("alpha"), kFlood + 2) << "alpha's calls were not all queued";
  std::chrono::steady_clock::time_point opened;
  double b_loaded_ms = 0;
  AsyncCompute b_call(server.stub(), kTokenB, request(small->mesh_id, 0), [&](const grpc::Status& s) {
    std::lock_guard<std::mutex> lock(mu);
    b_loaded_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - opened).count();
    a_done_when_b_done = a_done;
    b_status = s;
    changed.notify_all();
  });
  while (compute.Active("beta") < 1) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  {
    std::lock_guard<std::mutex> lock(mu);
    opened = std::chrono::steady_clock::now();
  }
  gate.Open();
  {
    std::unique_lock<std::mutex> lock(mu);
    changed.wait(lock, [&] { return a_done_when_b_done >= 0; });
  }
  // Served in turn, beta's call starts as soon as a worker is free: it waits for at most
  // one of alpha's calls, and the other worker finishes a few more meanwhile. Served in
  // order of arrival it would have waited for all 300.
  EXPECT_TRUE(b_status.ok()) << b_status.error_message();
  EXPECT_LE(a_done_when_b_done, 8) << "alpha's calls finished before beta's";
  RecordProperty("alpha_calls_done_before_beta", a_done_when_b_done);
  RecordProperty("beta_loaded_ms", std::to_string(b_loaded_ms));
  for (auto& call : flood) call->Cancel();  // the rest need not run
  std::unique_lock<std::mutex> lock(mu);
  changed.wait(lock, [&] { return a_done == kFlood; });
  EXPECT_GE(a_ok, a_done_when_b_done);
}

}  // namespace
}  // namespace geomfit::server::testing
