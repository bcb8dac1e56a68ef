// geomfit::Client against an in-process server over loopback.
#include "clients/cpp/client/client.h"

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <thread>

#include <gtest/gtest.h>

#include "geomfit/v1/geomfit.pb.h"
#include "core/mesh/content_hash.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

using server::testing::InProcessServer;

std::unique_ptr<Client> ClientFor(int port, bool reupload = false) {
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(port);
  o.chunk_rows = 100;
  o.reupload_on_not_found = reupload;
  o.deadline = std::chrono::seconds(30);
  return Client::Connect(o);
}

int64_t CallsOf(Client& client, const std::string& method) {
  auto stats = client.GetStatistics();
  if (!stats.ok()) return -1;
  for (const auto& m : stats->methods())
    if (m.method() == method) return m.count();
  return 0;
}

TEST(ClientTest, UpdatesWithinOneMessageUseSetPositions) {
  InProcessServer server;
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(server.port());
  auto client = Client::Connect(o);  // default chunk_rows: the mesh fits in one message
  const Mesh mesh = server::testing::TestTorus(10);
  auto info = client->Upload(mesh, "torus");
  ASSERT_TRUE(info.ok()) << info.status();
  auto updated = client->UpdatePositions(info->mesh_id, mesh.positions * 3.0, 1);
  ASSERT_TRUE(updated.ok()) << updated.status();
  EXPECT_EQ(updated->revision, 2);
  EXPECT_EQ(client->UpdatePositions(info->mesh_id, mesh.positions, 1).status().code(), absl::StatusCode::kAborted);
  auto downloaded = client->Download(info->mesh_id);
  ASSERT_TRUE(downloaded.ok());
  EXPECT_EQ(downloaded->positions, Positions(mesh.positions * 3.0));
  EXPECT_EQ(CallsOf(*client, "SetPositions"), 2);
  EXPECT_EQ(CallsOf(*client, "UpdatePositions"), 0);
}

TEST(ClientTest, AStreamTheServerRefusesEndsInItsStatus) {
  server::ServerOptions so = server::testing::LoopbackOptions();
  so.max_vertices = 50;  // the header is refused while the client is still writing
  InProcessServer server(so);
  for (int64_t rows : {int64_t{100}, int64_t{16384}}) {
    ClientOptions o;
    o.target = "127.0.0.1:" + std::to_string(server.port());
    o.chunk_rows = rows;
    auto client = Client::Connect(o);
    for (int i = 0; i < 10; ++i) {
      auto info = client->Upload(server::testing::TestTorus(10), "too big");
      EXPECT_EQ(info.status().code(), absl::StatusCode::kResourceExhausted) << info.status();
    }
  }
}

// The id a client computes before uploading (its x-mesh-id routing key) is the id the
// server gives the upload: triangles and quads, names and labels.
TEST(ClientTest, PredictsTheMeshIdOfAnUpload) {
  InProcessServer server;
  auto client = ClientFor(server.port());
  Mesh cube;
  cube.positions.resize(8, 3);
  for (int i = 0; i < 8; ++i) cube.positions.row(i) << (i & 1), (i >> 1) & 1, (i >> 2) & 1;
  cube.faces.Mutable().resize(6, 4);
  cube.faces.Mutable() << 0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5;
  struct Case {
    Mesh mesh;
    std::string name;
    std::map<std::string, std::string> labels;
  };
  for (const Case& c : {Case{server::testing::TestTorus(10), "torus", {{"b", "2"}, {"a", "1"}}},
                        Case{server::testing::TestSphere(), "", {}}, Case{cube, "cube", {{"k", ""}}}}) {
    const std::string predicted = MeshIdOf(MeshContentHash(c.mesh, c.name, c.labels));
    auto info = client->Upload(c.mesh, c.name, c.labels);
    ASSERT_TRUE(info.ok()) << info.status();
    EXPECT_EQ(info->mesh_id, predicted) << c.name;
    EXPECT_EQ(info->content_hash.substr(0, 20), predicted.substr(2));
  }
}

TEST(ClientTest, ChecksHealth) {
  InProcessServer server;
  auto client = ClientFor(server.port());
  EXPECT_EQ(client->CheckHealth().value_or("error"), "SERVING");
  EXPECT_EQ(client->CheckHealth("geomfit.v1.GeomFit").value_or("error"), "SERVING");
  EXPECT_EQ(client->CheckHealth("no.such.Service").status().code(), absl::StatusCode::kNotFound);
}

TEST(ClientTest, RoundTrip) {
  InProcessServer server;
  auto client = ClientFor(server.port());
  const Mesh mesh = server::testing::TestTorus(10);
  auto info = client->Upload(mesh, "torus", {{"kind", "test"}});
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->revision, 1);
  EXPECT_EQ(info->labels.at("kind"), "test");
  EXPECT_EQ(info->num_vertices, mesh.NumVertices());

  FitOptions options;
  options.degree = 3;
  auto d = client->ComputeDifferentials(info->mesh_id, options, kMeanCurvature | kNormals, 0, true);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->values.mean.size(), mesh.NumVertices());
  EXPECT_EQ(d->values.normals.rows(), mesh.NumVertices());
  EXPECT_EQ(d->values.k1.size(), 0) << "not requested";
  EXPECT_EQ(d->values.diagnostics.size(), static_cast<size_t>(mesh.NumVertices()));
  EXPECT_EQ(d->summary.degree_requested, 3);

  auto updated = client->UpdatePositions(info->mesh_id, mesh.positions * 2.0, 1);
  ASSERT_TRUE(updated.ok()) << updated.status();
  EXPECT_EQ(updated->revision, 2);
  EXPECT_EQ(client->UpdatePositions(info->mesh_id, mesh.positions, 1).status().code(), absl::StatusCode::kAborted);
  RemoteMesh got;
  auto downloaded = client->Download(info->mesh_id, &got);
  ASSERT_TRUE(downloaded.ok()) << downloaded.status();
  EXPECT_EQ(downloaded->positions, Positions(mesh.positions * 2.0));
  EXPECT_EQ(downloaded->faces, mesh.faces);
  EXPECT_EQ(got.revision, 2);

  auto list = client->ListMeshes();
  ASSERT_TRUE(list.ok());
  ASSERT_EQ(list->size(), 1u);
  ASSERT_TRUE(client->DeleteMesh(info->mesh_id).ok());
  EXPECT_EQ(client->GetMesh(info->mesh_id).status().code(), absl::StatusCode::kNotFound);
  auto server_info = client->GetServerInfo();
  ASSERT_TRUE(server_info.ok());
  EXPECT_EQ(server_info->api_version(), "geomfit.v1");
}

TEST(ClientTest, ReuploadsWhenTheServerLostTheMesh) {
  InProcessServer server;
  auto client = ClientFor(server.port(), /*reupload=*/true);
  auto other = ClientFor(server.port());
  const Mesh mesh = server::testing::TestSphere(6);
  auto info = client->Upload(mesh, "s");
  ASSERT_TRUE(info.ok());
  ASSERT_TRUE(client->UpdatePositions(info->mesh_id, mesh.positions * 3.0).ok());
  ASSERT_TRUE(other->DeleteMesh(info->mesh_id).ok());  // behind the client's back
  auto d = client->ComputeDifferentials(info->mesh_id, FitOptions(), kMeanCurvature);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_NEAR(d->values.mean.mean(), 1.0 / 3.0, 0.05) << "re-uploaded with the latest positions";
  EXPECT_NE(client->ResolveId(info->mesh_id), info->mesh_id);
  EXPECT_EQ(other->ComputeDifferentials(info->mesh_id, FitOptions()).status().code(), absl::StatusCode::kNotFound);
}

using server::testing::FreePort;

TEST(ClientTest, RetriesWhileTheServerIsUnavailable) {
  const int port = FreePort();
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(port);
  // ~30 s of retries: the server starts 300 ms in, but the channel reconnects on gRPC's
  // own backoff (1 s, 2.6 s, ...), which a loaded machine's late start may push past 3 s.
  o.max_attempts = 300;
  o.initial_backoff = std::chrono::milliseconds(50);
  o.max_backoff = std::chrono::milliseconds(100);
  auto client = Client::Connect(o);
  std::unique_ptr<InProcessServer> server;
  std::thread starter([&] {
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    server::ServerOptions so = server::testing::LoopbackOptions();
    so.port = port;
    server = std::make_unique<InProcessServer>(so);
  });
  auto info = client->GetServerInfo();
  starter.join();
  EXPECT_TRUE(info.ok()) << info.status();

  o.max_attempts = 1;
  o.target = "127.0.0.1:" + std::to_string(FreePort());
  EXPECT_EQ(Client::Connect(o)->GetServerInfo().status().code(), absl::StatusCode::kUnavailable);
}

}  // namespace
}  // namespace geomfit
