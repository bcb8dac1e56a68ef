// Bearer tokens and tenants (--auth-tokens): every RPC of one tenant is blind to
// another's meshes and jobs (NOT_FOUND, never a hint that they exist); calls without a
// valid token are UNAUTHENTICATED; health stays open.
#include <algorithm>
#include <fstream>

#include <gtest/gtest.h>

#include "server/auth.h"
#include "tests/server/tenant_util.h"

namespace geomfit {
namespace {

using server::testing::ClientWith;
using server::testing::InProcessServer;
using server::testing::kTokenA;
using server::testing::kTokenB;
using server::testing::TenantOptions;
using server::testing::TokenFile;

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
    // Every other RPC too, before it looks at the (unknown) id.
    const auto kUnauthenticated = absl::StatusCode::kUnauthenticated;
    const Mesh mesh = server::testing::TestTorus(5);
    EXPECT_EQ(c->UpdatePositions("x", mesh.positions).status().code(), kUnauthenticated);  // stream
    EXPECT_EQ(ClientWith(server.port(), token, 0)->UpdatePositions("x", mesh.positions).status().code(),
              kUnauthenticated);  // SetPositions
    EXPECT_EQ(c->DeleteMesh("x").code(), kUnauthenticated);
    EXPECT_EQ(c->ComputeDifferentials("x", FitOptions()).status().code(), kUnauthenticated);
    EXPECT_EQ(c->ProjectPoints("x", mesh.positions.topRows(3)).status().code(), kUnauthenticated);
    EXPECT_EQ(c->HighOrderNodes("x", 2).status().code(), kUnauthenticated);
    EXPECT_EQ(c->RefineMesh("x", 2).status().code(), kUnauthenticated);
    EXPECT_EQ(c->Integrate("x", IntegrationInput()).status().code(), kUnauthenticated);
    EXPECT_EQ(c->GetOperator("x", v1::OPERATOR_LAPLACE_BELTRAMI).status().code(), kUnauthenticated);
    EXPECT_EQ(c->ApplyOperator("x", v1::OPERATOR_LAPLACE_BELTRAMI, mesh.positions).status().code(),
              kUnauthenticated);
    v1::StartJobRequest start;
    start.mutable_refine()->set_mesh_id("x");
    EXPECT_EQ(c->StartJob(start).status().code(), kUnauthenticated);
    v1::FlowJob flow;
    flow.set_mesh_id("x");
    EXPECT_EQ(c->StartFlow(flow).status().code(), kUnauthenticated);
    EXPECT_EQ(c->GetJob("x").status().code(), kUnauthenticated);
    EXPECT_EQ(c->CancelJob("x").status().code(), kUnauthenticated);
    EXPECT_EQ(c->GetServerInfo().status().code(), kUnauthenticated);
    EXPECT_EQ(c->GetStatistics().status().code(), kUnauthenticated);
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
  EXPECT_EQ(b->GetOperator(id, v1::OPERATOR_LAPLACE_BELTRAMI).status().code(), kNotFound);
  EXPECT_EQ(b->ApplyOperator(id, v1::OPERATOR_LAPLACE_BELTRAMI, mesh.positions).status().code(), kNotFound);
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

TEST(TenantTest, FlowJobsAreTheirTenantsOnly) {
  InProcessServer server(TenantOptions());
  auto a = ClientWith(server.port(), kTokenA);
  auto b = ClientWith(server.port(), kTokenB);
  auto mine = a->Upload(server::testing::TestSphere(4), "a's sphere");
  ASSERT_TRUE(mine.ok()) << mine.status();
  v1::FlowJob spec;
  spec.set_mesh_id(mine->mesh_id);
  spec.set_dt(1e-3);
  spec.set_steps(2);
  const auto kNotFound = absl::StatusCode::kNotFound;
  EXPECT_EQ(b->StartFlow(spec).status().code(), kNotFound);
  auto job = a->StartFlow(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  EXPECT_EQ(job->request().flow().mesh_id(), mine->mesh_id);
  // The other tenant learns nothing of it...
  EXPECT_EQ(b->GetJob(job->job_id()).status().code(), kNotFound);
  EXPECT_EQ(b->CancelJob(job->job_id()).status().code(), kNotFound);
  EXPECT_EQ(b->WatchJob(job->job_id(), 0, [](const v1::JobEvent&) { return true; }).code(), kNotFound);
  EXPECT_TRUE(b->ListJobs()->empty());
  // ...while the owner watches, gets and lists it; its snapshot is a revision of a's mesh.
  v1::JobEvent last;
  ASSERT_TRUE(a->WatchJob(job->job_id(), 0, [&](const v1::JobEvent& e) {
                  last = e;
                  return true;
                }).ok());
  EXPECT_EQ(last.state(), v1::JOB_STATE_SUCCEEDED) << last.message();
  auto got = a->GetJob(job->job_id());
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->state(), v1::JOB_STATE_SUCCEEDED);
  EXPECT_EQ(a->ListJobs()->size(), 1u);
  EXPECT_EQ(a->GetMesh(mine->mesh_id)->revision, 2);
  EXPECT_TRUE(b->ListMeshes()->empty());
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
