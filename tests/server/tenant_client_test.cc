// Bearer tokens and tenants (--auth-tokens): every RPC of one tenant is blind to
// another's meshes and jobs (NOT_FOUND, never a hint that they exist); calls without a
// valid token are UNAUTHENTICATED; health stays open.
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "clients/cpp/client/client.h"
#include "server/auth.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

using server::testing::InProcessServer;
constexpr char kTokenA[] = "token-of-tenant-a-0123456789";
constexpr char kTokenB[] = "token-of-tenant-b-0123456789";

std::string WriteFile(const std::string& name, const std::string& text) {
  const std::string path =
      (std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()))).string();
  std::ofstream(path) << text;
  return path;
}

std::string TokenFile() {
  return WriteFile("geomfit_tokens", std::string("# token tenant\n") + kTokenA + " alpha\n" + kTokenB + "  beta\n");
}

server::ServerOptions TenantOptions() {
  server::ServerOptions o = server::testing::LoopbackOptions();
  o.auth_tokens = TokenFile();
  return o;
}

/// chunk_rows 50: uploads and updates of the test meshes stream in several messages;
/// 0: an update is one SetPositions message.
std::unique_ptr<Client> ClientWith(int port, const std::string& token, int64_t chunk_rows = 50) {
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(port);
  o.max_attempts = 1;
  o.token = token;
  if (chunk_rows > 0) o.chunk_rows = chunk_rows;
  return Client::Connect(o);
}

TEST(TokenTableTest, ParsesReloadsAndRejects) {
  const std::string path = TokenFile();
  auto table = server::TokenTable::Load(path);
  ASSERT_TRUE(table.ok()) << table.status();
  EXPECT_EQ((*table)->TenantOf(kTokenA), "alpha");
  EXPECT_EQ((*table)->TenantOf(kTokenB), "beta");
  EXPECT_FALSE((*table)->TenantOf("token-of-tenant-a-012345678").has_value());  // a prefix
  EXPECT_FALSE((*table)->TenantOf("").has_value());
  EXPECT_EQ(server::Authenticate(**table, std::string("Bearer ") + kTokenA).value(), "alpha");
  EXPECT_EQ(server::Authenticate(**table, kTokenA).status().code(), absl::StatusCode::kUnauthenticated);
  std::ofstream(path) << kTokenB << " gamma\n";
  ASSERT_TRUE((*table)->Reload().ok());
  EXPECT_FALSE((*table)->TenantOf(kTokenA).has_value());
  EXPECT_EQ((*table)->TenantOf(kTokenB), "gamma");
  std::ofstream(path) << "short alpha\n";
  EXPECT_EQ((*table)->Reload().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ((*table)->TenantOf(kTokenB), "gamma");  // the old table stays
  std::ofstream(path) << kTokenA << " bad/tenant\n";
  EXPECT_EQ(server::TokenTable::Load(path).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(TenantTest, CallsWithoutAValidTokenAreUnauthenticatedAndHealthStaysOpen) {
  InProcessServer server(TenantOptions());
  for (const std::string token : {"", "not-a-token-of-anyone-123"}) {
    auto c = ClientWith(server.port(), token);
    EXPECT_EQ(c->ListMeshes().status().code(), absl::StatusCode::kUnauthenticated) << token;
    EXPECT_EQ(c->Upload(server::testing::TestTorus(5)).status().code(), absl::StatusCode::kUnauthenticated);
    EXPECT_EQ(c->GetMesh("x").status().code(), absl::StatusCode::kUnauthenticated);
    EXPECT_EQ(c->Download("x").status().code(), absl::StatusCode::kUnauthenticated);
    EXPECT_EQ(c->ListJobs().status().code(), absl::StatusCode::kUnauthenticated);
    EXPECT_EQ(c->WatchJob("x", 0, [](const v1::JobEvent&) { return true; }).code(),
              absl::StatusCode::kUnauthenticated);
  }
  EXPECT_EQ(server::testing::HealthCheck(server.channel()), "SERVING");
  EXPECT_EQ(ClientWith(server.port(), "")->CheckHealth().value_or("error"), "SERVING");
}

TEST(TenantTest, EveryRpcOfAnotherTenantFindsNothing) {
  InProcessServer server(TenantOptions());
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  const Mesh mesh = server::testing::TestTorus(8);
  auto mine = a->Upload(mesh, "a's torus");
  ASSERT_TRUE(mine.ok()) << mine.status();
  const std::string id = mine->mesh_id;
  EXPECT_EQ(id.find('/'), std::string::npos) << id;  // the tenant prefix never shows
  // The owner can do everything.
  ASSERT_TRUE(a->GetMesh(id).ok());
  ASSERT_TRUE(a->ComputeDifferentials(id, FitOptions()).ok());
  ASSERT_EQ(a->ListMeshes()->size(), 1u);
  // The other tenant: NOT_FOUND everywhere, nothing listed, nothing changed.
  const auto kNotFound = absl::StatusCode::kNotFound;
  EXPECT_TRUE(b->ListMeshes()->empty());
  EXPECT_EQ(b->GetMesh(id).status().code(), kNotFound);
  EXPECT_EQ(b->Download(id).status().code(), kNotFound);
  EXPECT_EQ(b->UpdatePositions(id, mesh.positions * 2.0).status().code(), kNotFound);  // stream (chunk_rows)
  EXPECT_EQ(ClientWith(server.port(), kTokenB, 0)->UpdatePositions(id, mesh.positions * 2.0).status().code(),
            kNotFound);  // SetPositions
  EXPECT_EQ(b->ComputeDifferentials(id, FitOptions()).status().code(), kNotFound);
  EXPECT_EQ(b->ProjectPoints(id, mesh.positions.topRows(3)).status().code(), kNotFound);
  EXPECT_EQ(b->HighOrderNodes(id, 2).status().code(), kNotFound);
  EXPECT_EQ(b->RefineMesh(id, 2).status().code(), kNotFound);
  EXPECT_EQ(b->Integrate(id, IntegrationInput()).status().code(), kNotFound);
  EXPECT_EQ(b->DeleteMesh(id).code(), kNotFound);
  v1::StartJobRequest start;
  start.mutable_refine()->set_mesh_id(id);
  start.mutable_refine()->set_levels(1);
  EXPECT_EQ(b->StartJob(start).status().code(), kNotFound);
  auto job = a->StartJob(start);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->request().refine().mesh_id(), id);
  EXPECT_EQ(b->GetJob(job->job_id()).status().code(), kNotFound);
  EXPECT_EQ(b->CancelJob(job->job_id()).status().code(), kNotFound);
  EXPECT_EQ(b->WatchJob(job->job_id(), 0, [](const v1::JobEvent&) { return true; }).code(), kNotFound);
  EXPECT_TRUE(b->ListJobs()->empty());
  // The owner's job ran on the owner's mesh and stored its result in the owner's namespace.
  ASSERT_TRUE(a->WatchJob(job->job_id(), 0, [](const v1::JobEvent&) { return true; }).ok());
  EXPECT_EQ(a->ListJobs()->size(), 1u);
  auto listed = a->ListMeshes();
  ASSERT_TRUE(listed.ok());
  EXPECT_EQ(listed->size(), 2u);  // the torus and its refinement
  for (const RemoteMesh& m : *listed) EXPECT_EQ(m.mesh_id.find('/'), std::string::npos) << m.mesh_id;
  EXPECT_TRUE(b->ListMeshes()->empty());
  // And a's mesh is untouched.
  auto info = a->GetMesh(id);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->revision, 1);
  EXPECT_TRUE(a->DeleteMesh(id).ok());
}

TEST(TenantTest, IdenticalUploadsByTwoTenantsAreIndependentMeshes) {
  InProcessServer server(TenantOptions());
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  const Mesh mesh = server::testing::TestTorus(6);
  auto ma = a->Upload(mesh, "same");
  auto mb = b->Upload(mesh, "same");
  ASSERT_TRUE(ma.ok() && mb.ok());
  EXPECT_EQ(ma->mesh_id, mb->mesh_id);  // the same content id, each in its own namespace
  ASSERT_TRUE(a->UpdatePositions(ma->mesh_id, mesh.positions * 3.0).ok());
  EXPECT_EQ(a->GetMesh(ma->mesh_id)->revision, 2);
  EXPECT_EQ(b->GetMesh(mb->mesh_id)->revision, 1);
  EXPECT_EQ(b->Download(mb->mesh_id)->positions, mesh.positions);
  ASSERT_TRUE(b->DeleteMesh(mb->mesh_id).ok());
  EXPECT_EQ(a->GetMesh(ma->mesh_id)->revision, 2);
}

TEST(TenantTest, ListMeshesPagesWithinTheTenant) {
  InProcessServer server(TenantOptions());
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  for (int i = 0; i < 5; ++i) {
    ASSERT_TRUE(a->Upload(server::testing::TestTorus(5), "a" + std::to_string(i)).ok());
    ASSERT_TRUE(b->Upload(server::testing::TestTorus(5), "b" + std::to_string(i)).ok());
  }
  // Raw pages of 2: three pages of a's five meshes, none of b's.
  v1::ListMeshesRequest request;
  request.set_page_size(2);
  std::vector<std::string> names;
  for (int page = 0; page < 4; ++page) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", std::string("Bearer ") + kTokenA);
    v1::ListMeshesResponse response;
    ASSERT_TRUE(server.stub().ListMeshes(&ctx, request, &response).ok());
    for (const auto& m : response.meshes()) names.push_back(m.name());
    if (response.next_page_token().empty()) break;
    request.set_page_token(response.next_page_token());
  }
  std::sort(names.begin(), names.end());
  EXPECT_EQ(names, (std::vector<std::string>{"a0", "a1", "a2", "a3", "a4"}));
}

}  // namespace
}  // namespace geomfit
