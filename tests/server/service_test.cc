// The service over a real loopback channel (in-process server).
#include <future>
#include <memory>
#include <thread>

#include <gtest/gtest.h>

#include "core/quantities/differentials.h"
#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::Compute;
using testing::HealthCheck;
using testing::InProcessServer;

absl::StatusOr<Differentials> Read(const std::vector<v1::ComputeDifferentialsResponse>& chunks,
                                   v1::FitSummary* summary = nullptr) {
  wire::DifferentialsReader reader;
  for (const auto& c : chunks) {
    absl::Status s = reader.Add(c);
    if (!s.ok()) return s;
  }
  if (summary) *summary = reader.summary();
  return reader.Finish();
}

TEST(ServiceTest, UploadComputeDownloadOverTheWire) {
  InProcessServer server;
  EXPECT_EQ(HealthCheck(server.channel()), "SERVING");
  EXPECT_EQ(HealthCheck(server.channel(), "geomfit.v1.GeomFit"), "SERVING");
  const Mesh mesh = testing::TestSphere(8);
  auto info = testing::UploadMesh(server.stub(), mesh, "sphere", 97);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->revision(), 1);
  EXPECT_EQ(info->name(), "sphere");

  auto downloaded = testing::Download(server.stub(), info->mesh_id());
  ASSERT_TRUE(downloaded.ok()) << downloaded.status();
  EXPECT_TRUE(testing::SameMesh(*downloaded, mesh));

  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  request.set_chunk_rows(50);
  wire::AddQuantities(kAllQuantities, &request);
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  ASSERT_TRUE(Compute(server.stub(), request, &chunks).ok());
  EXPECT_EQ(chunks.size(), static_cast<size_t>((mesh.NumVertices() + 49) / 50));
  v1::FitSummary summary;
  auto remote = Read(chunks, &summary);
  ASSERT_TRUE(remote.ok()) << remote.status();
  FitOptions options;
  auto local = ComputeDifferentials(mesh, options, kAllQuantities);
  ASSERT_TRUE(local.ok());
  EXPECT_EQ(remote->mean, local->mean);
  EXPECT_EQ(remote->dir1, local->dir1);
  EXPECT_EQ(remote->k1, local->k1);

  grpc::ClientContext ctx;
  v1::Statistics stats;
  ASSERT_TRUE(server.stub().GetStatistics(&ctx, v1::GetStatisticsRequest(), &stats).ok());
  std::map<std::string, int64_t> counts;
  for (const auto& m : stats.methods()) counts[m.method()] = m.count();
  EXPECT_EQ(counts["UploadMesh"], 1);
  EXPECT_EQ(counts["DownloadMesh"], 1);
  EXPECT_EQ(counts["ComputeDifferentials"], 1);
  EXPECT_EQ(stats.stored_meshes(), 1);
  EXPECT_GT(stats.cache_bytes(), 0);

  grpc::ClientContext ctx2;
  v1::ServerInfo server_info;
  ASSERT_TRUE(server.stub().GetServerInfo(&ctx2, v1::GetServerInfoRequest(), &server_info).ok());
  EXPECT_EQ(server_info.api_version(), "geomfit.v1");
}

TEST(ServiceTest, ConcurrentIdenticalRequestsFitOnce) {
  InProcessServer server;
  auto info = testing::UploadMesh(server.stub(), testing::TestTorus(40));
  ASSERT_TRUE(info.ok());
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  request.mutable_options()->set_degree(4);
  std::vector<std::thread> clients;
  std::atomic<int> ok{0}, hits{0};
  for (int i = 0; i < 4; ++i) {
    clients.emplace_back([&] {
      std::vector<v1::ComputeDifferentialsResponse> chunks;
      if (Compute(server.stub(), request, &chunks).ok()) {
        ++ok;
        hits += chunks.back().summary().fit_cache_hit();
      }
    });
  }
  for (auto& t : clients) t.join();
  EXPECT_EQ(ok.load(), 4);
  EXPECT_EQ(hits.load(), 3);
  grpc::ClientContext ctx;
  v1::Statistics stats;
  ASSERT_TRUE(server.stub().GetStatistics(&ctx, v1::GetStatisticsRequest(), &stats).ok());
  EXPECT_EQ(stats.caches(2).tier(), "fitting");
  EXPECT_EQ(stats.caches(2).misses(), 2) << "one fitting and one evaluation, shared by all four";
}

/// Polls GetStatistics until it shows `n` finished ComputeDifferentials calls (then
/// *last_code says whether any failed); false after many polls.
bool WaitForComputeRecords(v1::GeomFit::Stub& stub, int n, std::string* last_code) {
  for (int i = 0; i < 2000; ++i) {
    grpc::ClientContext ctx;
    v1::Statistics stats;
    if (stub.GetStatistics(&ctx, v1::GetStatisticsRequest(), &stats).ok()) {
      for (const auto& m : stats.methods()) {
        if (m.method() == "ComputeDifferentials" && m.count() >= n) {
          *last_code = m.errors() > 0 ? "error" : "ok";
          return true;
        }
      }
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return false;
}

TEST(ServiceTest, DeadlineAndCancellationStopTheFit) {
  InProcessServer server;
  auto info = testing::UploadMesh(server.stub(), testing::TestTorus(120), "big", 20000);
  ASSERT_TRUE(info.ok()) << info.status();
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  request.mutable_options()->set_degree(6);
  request.mutable_options()->set_method(v1::FIT_METHOD_LOP);

  // Full fit time, for comparison (cached afterwards, so use another degree below).
  const auto t0 = std::chrono::steady_clock::now();
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  ASSERT_TRUE(Compute(server.stub(), request, &chunks).ok());
  const double full_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_GT(full_ms, 200) << "the mesh is too small to observe cancellation";

  request.mutable_options()->set_degree(5);
  chunks.clear();
  // CPU, not wall time, once the call ended: a loaded machine slows the stop down.
  grpc::Status s = Compute(server.stub(), request, &chunks, 50);
  EXPECT_EQ(s.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  EXPECT_LT(testing::CpuSecondsAfterCancel([] {}), testing::kStoppedCpuSeconds)
      << "the server kept fitting after the deadline";
  std::string code;
  EXPECT_TRUE(WaitForComputeRecords(server.stub(), 2, &code));
  EXPECT_EQ(code, "error");

  {  // client cancellation
    grpc::ClientContext ctx;
    auto reader = server.stub().ComputeDifferentials(&ctx, request);
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    EXPECT_LT(testing::CpuSecondsAfterCancel([&] { ctx.TryCancel(); }), testing::kStoppedCpuSeconds)
        << "the server kept fitting after the client cancelled";
    v1::ComputeDifferentialsResponse r;
    while (reader->Read(&r)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  }
  EXPECT_TRUE(WaitForComputeRecords(server.stub(), 3, &code));

  chunks.clear();
  ASSERT_TRUE(Compute(server.stub(), request, &chunks).ok());
  EXPECT_FALSE(chunks.back().summary().fit_cache_hit()) << "a cancelled fit must not be cached";
  EXPECT_EQ(HealthCheck(server.channel()), "SERVING");
}

/// A degree-6 LOP fit of a 115k-vertex torus: ~0.5 s on one server thread, long enough
/// that a call is still computing 100 ms after its fit's first progress message.
v1::ComputeDifferentialsRequest SlowRequest(v1::GeomFit::Stub& stub) {
  auto info = testing::UploadMesh(stub, testing::TestTorus(240), "slow", 20000);
  EXPECT_TRUE(info.ok()) << info.status();
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info.ok() ? info->mesh_id() : "");
  request.mutable_options()->set_degree(6);
  request.mutable_options()->set_method(v1::FIT_METHOD_LOP);
  request.set_progress(true);
  return request;
}

/// Runs `request` on a thread of its own; the returned future is ready once the fit's
/// first progress message arrived, so the call is surely in flight (not a sleep).
std::future<void> ComputeInBackground(v1::GeomFit::Stub& stub, const v1::ComputeDifferentialsRequest& request,
                                      grpc::Status* status, std::thread* thread) {
  return testing::StreamInBackground<v1::ComputeDifferentialsResponse>(
      [&stub, request](grpc::ClientContext* ctx) { return stub.ComputeDifferentials(ctx, request); }, "fit", nullptr,
      status, thread);
}

TEST(ServiceTest, DrainingFinishesInFlightCallsAndRefusesNewOnes) {
  InProcessServer server;
  grpc::Status in_flight;
  std::thread client;
  std::future<void> started = ComputeInBackground(server.stub(), SlowRequest(server.stub()), &in_flight, &client);
  ASSERT_EQ(started.wait_for(std::chrono::seconds(30)), std::future_status::ready);
  std::thread stopper([&] { server.server().Shutdown(30); });
  std::string health;
  for (int i = 0; i < 200 && (health = HealthCheck(server.channel())) == "SERVING"; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ(health, "NOT_SERVING");
  grpc::ClientContext ctx;
  v1::ServerInfo info;
  EXPECT_EQ(server.stub().GetServerInfo(&ctx, v1::GetServerInfoRequest(), &info).error_code(),
            grpc::StatusCode::UNAVAILABLE);
  client.join();
  stopper.join();
  EXPECT_TRUE(in_flight.ok()) << in_flight.error_message();
}

TEST(ServiceTest, DrainDeadlineCancelsWhatIsLeft) {
  InProcessServer server;
  grpc::Status in_flight;
  std::thread client;
  std::future<void> started = ComputeInBackground(server.stub(), SlowRequest(server.stub()), &in_flight, &client);
  ASSERT_EQ(started.wait_for(std::chrono::seconds(30)), std::future_status::ready);
  // CPU, not wall time, after the drain deadline: a loaded machine slows the stop down.
  const double cpu = testing::CpuSecondsAfterCancel([&] { server.server().Shutdown(0.1); },
                                                    std::chrono::milliseconds(100));
  client.join();
  EXPECT_FALSE(in_flight.ok());
  EXPECT_LT(cpu, testing::kStoppedCpuSeconds) << "the fit went on after the drain deadline";
}

TEST(ServiceTest, PortSharingIsOff) {
  InProcessServer first;
  ServerOptions o = testing::LoopbackOptions();
  o.port = first.port();
  auto second = Server::Start(o);
  ASSERT_FALSE(second.ok()) << "two servers share port " << o.port;
  EXPECT_EQ(second.status().code(), absl::StatusCode::kUnavailable);
  EXPECT_NE(second.status().message().find(std::to_string(o.port)), std::string::npos) << second.status();
}

}  // namespace
}  // namespace geomfit::server
