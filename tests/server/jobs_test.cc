// Jobs over gRPC: a refine job's lifecycle (start, watch, resume from event k, results
// readable), cancel (CANCELLED, nothing stored), and bad inputs.
#include <set>

#include <google/protobuf/util/message_differencer.h>
#include <gtest/gtest.h>

#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;

using testing::StartRefineJob;
using testing::WatchJob;

std::set<std::string> MeshIds(v1::GeomFit::Stub& stub) {
  grpc::ClientContext ctx;
  v1::ListMeshesResponse list;
  EXPECT_TRUE(stub.ListMeshes(&ctx, v1::ListMeshesRequest(), &list).ok());
  std::set<std::string> ids;
  for (const auto& m : list.meshes()) ids.insert(m.mesh_id());
  return ids;
}

TEST(JobsTest, RefineJobLifecycleAndResume) {
  InProcessServer server;
  const Mesh mesh = testing::TestTorus(8);
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), mesh, "torus");
  ASSERT_TRUE(info.ok()) << info.status();
  absl::StatusOr<v1::Job> job = StartRefineJob(server.stub(), info->mesh_id(), 2);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->kind(), "refine");
  EXPECT_EQ(job->request().refine().levels(), 2);
  EXPECT_EQ(job->request().refine().mesh_id(), info->mesh_id());

  std::vector<v1::JobEvent> all;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), 0, &all).ok());
  ASSERT_GE(all.size(), 7u);  // queued, started, 2 x (refine, stored), final
  for (size_t i = 0; i < all.size(); ++i) {
    EXPECT_EQ(all[i].seq(), static_cast<int64_t>(i + 1));
    EXPECT_EQ(all[i].job_id(), job->job_id());
  }
  EXPECT_EQ(all[0].state(), v1::JOB_STATE_PENDING);
  EXPECT_EQ(all[1].state(), v1::JOB_STATE_RUNNING);
  std::vector<std::string> phases;
  for (const v1::JobEvent& e : all)
    if (e.phase() == "refine" || e.phase() == "stored") phases.push_back(e.phase() + std::to_string(e.step()));
  EXPECT_EQ(phases, (std::vector<std::string>{"refine1", "stored1", "refine2", "stored2"}));
  const v1::JobEvent& last = all.back();
  EXPECT_TRUE(last.final());
  EXPECT_EQ(last.state(), v1::JOB_STATE_SUCCEEDED) << last.message();
  ASSERT_EQ(last.results_size(), 2);
  EXPECT_EQ(last.counts().at("faces"), 16 * mesh.NumFaces());

  // Level k has 4^k times the faces; each is a stored mesh the other RPCs read.
  for (int k = 0; k < 2; ++k) {
    grpc::ClientContext ctx;
    v1::GetMeshRequest get;
    get.set_mesh_id(last.results(k).mesh_id());
    v1::MeshInfo level;
    ASSERT_TRUE(server.stub().GetMesh(&ctx, get, &level).ok());
    EXPECT_EQ(level.num_faces(), (k == 0 ? 4 : 16) * mesh.NumFaces());
    EXPECT_EQ(level.revision(), last.results(k).revision());
  }
  v1::ComputeDifferentialsRequest compute;
  compute.set_mesh_id(last.results(1).mesh_id());
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  ASSERT_TRUE(testing::Compute(server.stub(), compute, &chunks).ok());
  EXPECT_EQ(chunks.front().summary().num_vertices(), 16 * mesh.NumFaces() / 2);  // torus: V = F / 2

  // A watcher reconnecting from event k gets exactly the events >= k.
  for (int64_t k : {int64_t{3}, static_cast<int64_t>(all.size())}) {
    std::vector<v1::JobEvent> rest;
    ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), k, &rest).ok());
    ASSERT_EQ(rest.size(), all.size() - k + 1) << "from " << k;
    for (size_t i = 0; i < rest.size(); ++i) EXPECT_TRUE(google::protobuf::util::MessageDifferencer::Equals(rest[i], all[k - 1 + i]));
  }

  grpc::ClientContext get_ctx;
  v1::GetJobRequest get;
  get.set_job_id(job->job_id());
  v1::Job done;
  ASSERT_TRUE(server.stub().GetJob(&get_ctx, get, &done).ok());
  EXPECT_EQ(done.state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(done.results_size(), 2);
  EXPECT_EQ(done.last_event(), last.seq());
  EXPECT_TRUE(done.latest().final());

  grpc::ClientContext list_ctx;
  v1::ListJobsResponse list;
  ASSERT_TRUE(server.stub().ListJobs(&list_ctx, v1::ListJobsRequest(), &list).ok());
  ASSERT_EQ(list.jobs_size(), 1);
  EXPECT_EQ(list.jobs(0).job_id(), job->job_id());
}

TEST(JobsTest, ReconnectThenCancelStoresNothing) {
  InProcessServer server;
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), testing::TestTorus(16), "torus");
  ASSERT_TRUE(info.ok());
  const std::set<std::string> before = MeshIds(server.stub());
  // Six levels would take minutes: it is cancelled during level 2.
  absl::StatusOr<v1::Job> job = StartRefineJob(server.stub(), info->mesh_id(), 6);
  ASSERT_TRUE(job.ok()) << job.status();

  // Watch until level 1 is stored, then drop the stream (a client that disconnects).
  std::vector<v1::JobEvent> first;
  WatchJob(server.stub(), job->job_id(), 0, &first,
        [](const v1::JobEvent& e) { return e.phase() == "stored" && e.step() == 1; });
  ASSERT_FALSE(first.empty());
  ASSERT_EQ(first.back().phase(), "stored");
  EXPECT_EQ(MeshIds(server.stub()).size(), before.size() + 1);  // level 1 is stored
  const int64_t k = first.back().seq() + 1;

  // Reconnect from k: the stream resumes exactly there; cancel once it has.
  std::vector<v1::JobEvent> rest;
  bool cancelled = false;
  ASSERT_TRUE(WatchJob(server.stub(), job->job_id(), k, &rest, [&](const v1::JobEvent& e) {
                if (!cancelled) {
                  EXPECT_TRUE(testing::CancelJob(server.stub(), e.job_id()).ok());
                  cancelled = true;
                }
                return false;
              }).ok());
  ASSERT_FALSE(rest.empty());
  EXPECT_EQ(rest.front().seq(), k);
  EXPECT_EQ(rest.front().phase(), "refine");
  EXPECT_EQ(rest.front().step(), 2);
  const v1::JobEvent& last = rest.back();
  EXPECT_TRUE(last.final());
  EXPECT_EQ(last.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(last.error_code(), grpc::StatusCode::CANCELLED);
  EXPECT_EQ(last.results_size(), 0);
  EXPECT_EQ(MeshIds(server.stub()), before);  // level 1 was rolled back

  grpc::ClientContext ctx;
  v1::GetJobRequest get;
  get.set_job_id(job->job_id());
  v1::Job j;
  ASSERT_TRUE(server.stub().GetJob(&ctx, get, &j).ok());
  EXPECT_EQ(j.state(), v1::JOB_STATE_CANCELLED);
  EXPECT_EQ(j.results_size(), 0);
}

TEST(JobsTest, BadInputs) {
  InProcessServer server;
  auto& stub = server.stub();
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(stub, testing::TestTorus(8), "torus");
  ASSERT_TRUE(info.ok());

  absl::StatusOr<v1::Job> zero = StartRefineJob(stub, info->mesh_id(), 0);
  EXPECT_EQ(zero.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(zero.status().message().find("refine.levels"), std::string::npos) << zero.status();
  absl::StatusOr<v1::Job> factor = StartRefineJob(stub, info->mesh_id(), 1, 5);
  EXPECT_EQ(factor.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(factor.status().message().find("refine.factor"), std::string::npos) << factor.status();
  EXPECT_EQ(StartRefineJob(stub, "m-nope", 1).status().code(), absl::StatusCode::kNotFound);
  grpc::ClientContext none_ctx;
  v1::Job none_job;
  const grpc::Status none = stub.StartJob(&none_ctx, v1::StartJobRequest(), &none_job);
  EXPECT_EQ(none.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(none.error_message().find("spec"), std::string::npos);

  grpc::ClientContext c1, c2;
  v1::Job j;
  v1::GetJobRequest get;
  get.set_job_id("j-nope");
  EXPECT_EQ(stub.GetJob(&c1, get, &j).error_code(), grpc::StatusCode::NOT_FOUND);
  v1::CancelJobRequest cancel;
  cancel.set_job_id("j-nope");
  EXPECT_EQ(stub.CancelJob(&c2, cancel, &j).error_code(), grpc::StatusCode::NOT_FOUND);
  std::vector<v1::JobEvent> events;
  EXPECT_EQ(WatchJob(stub, "j-nope", 0, &events).error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_TRUE(events.empty());
  EXPECT_EQ(MeshIds(stub).size(), 1u);  // no job ran
}

}  // namespace
}  // namespace geomfit::server
