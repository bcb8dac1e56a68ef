// geomfit::Client's job calls against an in-process server: start, blocking watch with
// a per-event callback (from any event, stopping early), get, list, cancel.
#include <gtest/gtest.h>

#include "clients/cpp/client/client.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

TEST(ClientJobsTest, StartWatchGetListCancel) {
  server::testing::InProcessServer server;
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(server.port());
  std::unique_ptr<Client> client = Client::Connect(o);
  const Mesh mesh = server::testing::TestTorus(8);
  absl::StatusOr<RemoteMesh> up = client->Upload(mesh, "torus");
  ASSERT_TRUE(up.ok()) << up.status();
  v1::StartJobRequest request;
  request.mutable_refine()->set_mesh_id(up->mesh_id);
  request.mutable_refine()->set_levels(1);
  absl::StatusOr<v1::Job> job = client->StartJob(request);
  ASSERT_TRUE(job.ok()) << job.status();

  std::vector<v1::JobEvent> all;
  ASSERT_TRUE(client->WatchJob(job->job_id(), 0, [&](const v1::JobEvent& e) {
    all.push_back(e);
    return true;
  }).ok());
  ASSERT_GE(all.size(), 5u);  // queued, started, refine, stored, final
  EXPECT_EQ(all.back().state(), v1::JOB_STATE_SUCCEEDED);
  ASSERT_EQ(all.back().results_size(), 1);

  std::vector<int64_t> tail;
  ASSERT_TRUE(client->WatchJob(job->job_id(), 3, [&](const v1::JobEvent& e) {
    tail.push_back(e.seq());
    return true;
  }).ok());
  std::vector<int64_t> expected;
  for (int64_t k = 3; k <= static_cast<int64_t>(all.size()); ++k) expected.push_back(k);
  EXPECT_EQ(tail, expected);

  int calls = 0;
  EXPECT_TRUE(client->WatchJob(job->job_id(), 0, [&](const v1::JobEvent&) { return ++calls < 2; }).ok());
  EXPECT_EQ(calls, 2);  // stopped by the callback

  absl::StatusOr<v1::Job> got = client->GetJob(job->job_id());
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(got->results(0).mesh_id(), all.back().results(0).mesh_id());
  absl::StatusOr<RemoteMesh> level = client->GetMesh(got->results(0).mesh_id());
  ASSERT_TRUE(level.ok());
  EXPECT_EQ(level->num_faces, 4 * mesh.NumFaces());
  absl::StatusOr<std::vector<v1::Job>> jobs = client->ListJobs();
  ASSERT_TRUE(jobs.ok());
  ASSERT_EQ(jobs->size(), 1u);
  EXPECT_EQ(client->CancelJob(job->job_id())->state(), v1::JOB_STATE_SUCCEEDED);  // finished: unchanged
  EXPECT_TRUE(absl::IsNotFound(client->GetJob("j-nope").status()));
  EXPECT_TRUE(absl::IsNotFound(client->WatchJob("j-nope", 0, [](const v1::JobEvent&) { return true; })));
}

}  // namespace
}  // namespace geomfit
