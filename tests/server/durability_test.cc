// The geomfit-server binary with its SQLite store: acknowledged uploads and updates
// survive kill -9; a half-sent upload never appears; SIGTERM drains and exits 0.
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <string>
#include <thread>

#include <gtest/gtest.h>

#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

/// A geomfit-server child process on a free loopback port (--port=0; the port is
/// read from its first stdout line), draining for at most `drain_seconds` on SIGTERM.
/// Killed on destruction.
class ServerProcess {
 public:
  explicit ServerProcess(const std::string& data_dir, int drain_seconds = 5) {
    int out[2];
    EXPECT_EQ(pipe(out), 0);
    pid_ = fork();
    if (pid_ == 0) {
      dup2(out[1], STDOUT_FILENO);
      close(out[0]);
      const std::string dir = "--data-dir=" + data_dir;
      const std::string drain = "--drain-seconds=" + std::to_string(drain_seconds);
      execl(GEOMFIT_SERVER_BINARY, GEOMFIT_SERVER_BINARY, "--host=127.0.0.1", "--port=0", "--store=sqlite",
            dir.c_str(), "--log-level=warn", drain.c_str(), static_cast<char*>(nullptr));
      _exit(127);
    }
    close(out[1]);
    FILE* f = fdopen(out[0], "r");
    char line[256] = {0};
    if (f != nullptr && fgets(line, sizeof(line), f) != nullptr) sscanf(line, "geomfit-server listening on port %d", &port_);
    if (f != nullptr) fclose(f);
    EXPECT_GT(port_, 0) << "server did not report its port: '" << line << "'";
    channel_ = testing::LoopbackChannel(port_);
    stub_ = v1::GeomFit::NewStub(channel_);
  }
  ~ServerProcess() {
    if (pid_ > 0) Signal(SIGKILL);
  }
  /// Sends `sig` and waits (at most 30 s); returns the exit status.
  int Signal(int sig) {
    kill(pid_, sig);
    int status = -1;
    for (int i = 0; i < 3000; ++i) {
      if (waitpid(pid_, &status, WNOHANG) == pid_) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    pid_ = -1;
    return status;
  }
  v1::GeomFit::Stub& stub() { return *stub_; }
  std::shared_ptr<grpc::Channel> channel() { return channel_; }

 private:
  pid_t pid_ = -1;
  int port_ = 0;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::GeomFit::Stub> stub_;
};

class DurabilityTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = (std::filesystem::temp_directory_path() / ("geomfit_durability_" + std::to_string(getpid()))).string();
    std::filesystem::remove_all(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  std::string dir_;
};

TEST_F(DurabilityTest, AcknowledgedWritesSurviveKill9) {
  const Mesh mesh = testing::TestTorus(30);
  std::string id;
  Positions moved;
  {
    ServerProcess server(dir_);
    auto info = testing::UploadMesh(server.stub(), mesh, "durable", 500);
    ASSERT_TRUE(info.ok()) << info.status();
    id = info->mesh_id();
    moved = mesh.positions * 1.5;
    moved(0, 0) = 0.123456789012345678;
    v1::UpdateHeader h;
    h.set_mesh_id(id);
    h.set_expected_revision(1);
    v1::MeshInfo updated;
    ASSERT_TRUE(testing::SendUpdate(server.stub(), wire::UpdateChunks(moved, h, 500), &updated).ok());
    ASSERT_EQ(updated.revision(), 2);

    // A second upload, half sent when the server dies.
    grpc::ClientContext ctx;
    v1::MeshInfo never;
    auto writer = server.stub().UploadMesh(&ctx, &never);
    auto chunks = wire::UploadChunks(testing::TestSphere(10), v1::MeshHeader(), 100);
    for (size_t i = 0; i < chunks.size() / 2; ++i) writer->Write(chunks[i]);
    const int status = server.Signal(SIGKILL);  // right after the acknowledgement
    EXPECT_TRUE(WIFSIGNALED(status));
  }
  ServerProcess restarted(dir_);
  auto back = testing::Download(restarted.stub(), id);
  ASSERT_TRUE(back.ok()) << back.status();
  Mesh expected = mesh;
  expected.positions = moved;
  EXPECT_TRUE(testing::SameMesh(*back, expected)) << "the mesh is not bit-identical after kill -9";
  grpc::ClientContext ctx;
  v1::ListMeshesResponse list;
  ASSERT_TRUE(restarted.stub().ListMeshes(&ctx, v1::ListMeshesRequest(), &list).ok());
  ASSERT_EQ(list.meshes_size(), 1) << "a half-sent upload became visible";
  EXPECT_EQ(list.meshes(0).revision(), 2);
  EXPECT_EQ(list.meshes(0).name(), "durable");
  EXPECT_EQ(testing::HealthCheck(restarted.channel()), "SERVING");
}

TEST_F(DurabilityTest, KillDuringAStreamOfUpdatesLosesNoAcknowledgedRevision) {
  const Mesh mesh = testing::TestTorus(20);
  auto positions_of = [&](int64_t revision) { return Positions(mesh.positions * (1.0 + 0.01 * revision)); };
  std::string id;
  std::atomic<int64_t> acknowledged{1};
  {
    ServerProcess server(dir_);
    auto info = testing::UploadMesh(server.stub(), mesh, "stream", 1000);
    ASSERT_TRUE(info.ok()) << info.status();
    id = info->mesh_id();
    std::atomic<bool> stop{false};
    std::thread writer([&] {
      for (int64_t next = 2; !stop && next < 100000; ++next) {
        v1::UpdateHeader h;
        h.set_mesh_id(id);
        h.set_expected_revision(next - 1);
        v1::MeshInfo updated;
        if (!testing::SendUpdate(server.stub(), wire::UpdateChunks(positions_of(next), h, 1000), &updated).ok()) break;
        acknowledged = updated.revision();
      }
    });
    // Killed once a few updates are acknowledged, while the writer goes on (not after a
    // fixed time, in which a loaded machine may acknowledge none).
    for (int i = 0; i < 6000 && acknowledged.load() < 5; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    server.Signal(SIGKILL);
    stop = true;
    writer.join();
  }
  ASSERT_GT(acknowledged.load(), 2) << "too few updates before the kill to mean anything";
  ServerProcess restarted(dir_);
  grpc::ClientContext ctx;
  v1::GetMeshRequest get;
  get.set_mesh_id(id);
  v1::MeshInfo info;
  ASSERT_TRUE(restarted.stub().GetMesh(&ctx, get, &info).ok());
  // The last acknowledged update is there; at most the one in flight went further.
  EXPECT_GE(info.revision(), acknowledged.load());
  EXPECT_LE(info.revision(), acknowledged.load() + 1);
  auto back = testing::Download(restarted.stub(), id);
  ASSERT_TRUE(back.ok()) << back.status();
  Mesh expected = mesh;
  expected.positions = positions_of(info.revision());
  EXPECT_TRUE(testing::SameMesh(*back, expected)) << "positions do not match revision " << info.revision();
}

TEST_F(DurabilityTest, SigtermDrainsAndExitsCleanly) {
  ServerProcess server(dir_, 60);  // a drain time far above what a loaded machine takes to stop
  ASSERT_TRUE(testing::UploadMesh(server.stub(), testing::TestSphere(), "x").ok());
  const auto start = std::chrono::steady_clock::now();
  const int status = server.Signal(SIGTERM);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSERT_TRUE(WIFEXITED(status)) << "status " << status;
  EXPECT_EQ(WEXITSTATUS(status), 0);
  EXPECT_LT(seconds, 30.0) << "an idle server should stop at once, not after its drain time";
}

TEST_F(DurabilityTest, JobsSurviveARestart) {
  // A finished job stays SUCCEEDED with readable results; one killed mid-run is FAILED.
  /// Watches until `until` holds for an event (or the stream ends); returns the last event.
  auto watch = [](v1::GeomFit::Stub& stub, const std::string& job_id,
                  const std::function<bool(const v1::JobEvent&)>& until) {
    std::vector<v1::JobEvent> events;
    testing::WatchJob(stub, job_id, 0, &events, until);
    return events.empty() ? v1::JobEvent() : events.back();
  };
  auto start_refine = [](v1::GeomFit::Stub& stub, const std::string& mesh_id, int levels) {
    absl::StatusOr<v1::Job> job = testing::StartRefineJob(stub, mesh_id, levels);
    EXPECT_TRUE(job.ok()) << job.status();
    return job.ok() ? job->job_id() : std::string();
  };
  std::string done, killed, level;
  {
    ServerProcess server(dir_);
    auto small = testing::UploadMesh(server.stub(), testing::TestTorus(8), "small");
    auto large = testing::UploadMesh(server.stub(), testing::TestTorus(16), "large");
    ASSERT_TRUE(small.ok() && large.ok());
    done = start_refine(server.stub(), small->mesh_id(), 1);
    const v1::JobEvent last = watch(server.stub(), done, [](const v1::JobEvent&) { return false; });
    ASSERT_EQ(last.state(), v1::JOB_STATE_SUCCEEDED) << last.message();
    ASSERT_EQ(last.results_size(), 1);
    level = last.results(0).mesh_id();
    killed = start_refine(server.stub(), large->mesh_id(), 6);  // minutes of work
    const v1::JobEvent running =
        watch(server.stub(), killed, [](const v1::JobEvent& e) { return e.phase() == "refine" && e.step() == 2; });
    ASSERT_EQ(running.state(), v1::JOB_STATE_RUNNING);
    server.Signal(SIGKILL);
  }
  ServerProcess restarted(dir_);
  auto& stub = restarted.stub();
  grpc::ClientContext list_ctx;
  v1::ListJobsResponse list;
  ASSERT_TRUE(stub.ListJobs(&list_ctx, v1::ListJobsRequest(), &list).ok());
  ASSERT_EQ(list.jobs_size(), 2);
  EXPECT_EQ(list.jobs(0).job_id(), done);
  EXPECT_EQ(list.jobs(0).state(), v1::JOB_STATE_SUCCEEDED);
  ASSERT_EQ(list.jobs(0).results_size(), 1);
  EXPECT_EQ(list.jobs(0).results(0).mesh_id(), level);
  EXPECT_EQ(list.jobs(1).job_id(), killed);
  EXPECT_EQ(list.jobs(1).state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(list.jobs(1).error(), "interrupted by restart");
  EXPECT_EQ(list.jobs(1).request().refine().levels(), 6);
  ASSERT_EQ(list.jobs(1).results_size(), 1);  // level 1 was stored before the kill: it is named
  {
    grpc::ClientContext ctx;
    v1::GetMeshRequest get;
    get.set_mesh_id(list.jobs(1).results(0).mesh_id());
    v1::MeshInfo left;
    EXPECT_TRUE(stub.GetMesh(&ctx, get, &left).ok());
  }
  // The interrupted job's watchers learn its end.
  const v1::JobEvent end = watch(stub, killed, [](const v1::JobEvent&) { return false; });
  EXPECT_TRUE(end.final());
  EXPECT_EQ(end.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(end.message(), "interrupted by restart");
  // The finished job's result is a stored mesh like any other.
  grpc::ClientContext get_ctx;
  v1::GetMeshRequest get;
  get.set_mesh_id(level);
  v1::MeshInfo info;
  ASSERT_TRUE(stub.GetMesh(&get_ctx, get, &info).ok());
  EXPECT_EQ(info.num_faces(), 4 * testing::TestTorus(8).NumFaces());
  v1::ComputeDifferentialsRequest compute;
  compute.set_mesh_id(level);
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  ASSERT_TRUE(testing::Compute(stub, compute, &chunks).ok());
  EXPECT_EQ(chunks.back().summary().num_vertices(), info.num_vertices());
}

TEST_F(DurabilityTest, SigtermInterruptsRunningJobs) {
  std::string id;
  {
    ServerProcess server(dir_);
    auto mesh = testing::UploadMesh(server.stub(), testing::TestTorus(16), "large");
    ASSERT_TRUE(mesh.ok());
    absl::StatusOr<v1::Job> job = testing::StartRefineJob(server.stub(), mesh->mesh_id(), 6);  // minutes of work
    ASSERT_TRUE(job.ok()) << job.status();
    id = job->job_id();
    std::vector<v1::JobEvent> events;
    testing::WatchJob(server.stub(), id, 0, &events, [](const v1::JobEvent& e) { return e.step() == 2; });
    ASSERT_EQ(events.back().state(), v1::JOB_STATE_RUNNING);
    const int status = server.Signal(SIGTERM);  // the job is cancelled, not waited for
    ASSERT_TRUE(WIFEXITED(status)) << "status " << status;
    EXPECT_EQ(WEXITSTATUS(status), 0);
  }
  ServerProcess restarted(dir_);
  grpc::ClientContext ctx;
  v1::GetJobRequest get;
  get.set_job_id(id);
  v1::Job job;
  ASSERT_TRUE(restarted.stub().GetJob(&ctx, get, &job).ok());
  EXPECT_EQ(job.state(), v1::JOB_STATE_FAILED);
  EXPECT_EQ(job.error(), "interrupted by server shutdown");
  grpc::ClientContext list_ctx;
  v1::ListMeshesResponse list;
  ASSERT_TRUE(restarted.stub().ListMeshes(&list_ctx, v1::ListMeshesRequest(), &list).ok());
  EXPECT_EQ(list.meshes_size(), 1) << "the interrupted job's levels were not rolled back";
}

}  // namespace
}  // namespace geomfit::server
