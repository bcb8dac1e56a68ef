// The engine without a server or protobuf: snapshots, typed keys, fits, cancellation.
#include "server/workspace/workspace.h"

#include <gtest/gtest.h>

#include "core/quantities/differentials.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

class WorkspaceTest : public ::testing::Test {
 protected:
  WorkspaceTest() : store_(NewMemoryStore()), cache_(64 << 20), ws_(store_.get(), &cache_, WorkspaceOptions{.threads = 1}) {}

  std::string Add(const Mesh& mesh) {
    auto r = ws_.AddMesh(mesh, MeshMeta{"t", {{"k", "v"}}});
    EXPECT_TRUE(r.ok()) << r.status();
    return r.ok() ? r->mesh_id : "";
  }

  std::unique_ptr<MeshStore> store_;
  Cache cache_;
  Workspace ws_;
};

TEST_F(WorkspaceTest, SnapshotOutlivesAnUpdate) {
  const Mesh mesh = testing::TestTorus(12);
  const std::string id = Add(mesh);
  auto s1 = ws_.Acquire(id, 0);
  ASSERT_TRUE(s1.ok()) << s1.status();
  EXPECT_EQ(s1->revision, 1);
  auto info = ws_.UpdatePositions(id, 1, mesh.positions * 2.0);
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->revision, 2);
  // Revision 1 is retired from the cache and the store, but the snapshot still has it.
  EXPECT_EQ(ws_.Acquire(id, 1).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(s1->mesh->positions, mesh.positions);
  auto fitted = ws_.Fit(*s1, FitOptions(), ws_.Context(nullptr));
  ASSERT_TRUE(fitted.ok()) << fitted.status();
  EXPECT_EQ(fitted->revision, 1);
  auto s2 = ws_.Acquire(id, 0);
  ASSERT_TRUE(s2.ok());
  EXPECT_EQ(s2->revision, 2);
  EXPECT_EQ(s2->topology, s1->topology) << "topology survives position updates";
  EXPECT_TRUE(s2->mesh->faces.SharesWith(s1->mesh->faces)) << "revisions share one faces array";
  EXPECT_EQ(ws_.UpdatePositions(id, 1, mesh.positions).status().code(), absl::StatusCode::kAborted);
  EXPECT_EQ(ws_.UpdatePositions(id, std::nullopt, mesh.positions.topRows(3)).status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST_F(WorkspaceTest, NearlyEqualOptionsGetTheirOwnFits) {
  // 1.5 and 1.5000001 printed with %g are one string; as keys they must stay two.
  const Mesh mesh = testing::TestTorus(16);
  const std::string id = Add(mesh);
  auto s = ws_.Acquire(id, 0).value();
  FitOptions odd;
  odd.degree = 3;
  odd.min_points_factor = 1.5000001;  // 16 points where 1.5 gives 15
  FitOptions plain;
  plain.degree = 3;
  plain.min_points_factor = 1.5;
  auto a = ws_.Evaluate(s, odd, kAllQuantities, ws_.Context(nullptr));
  ASSERT_TRUE(a.ok());
  auto b = ws_.Evaluate(s, plain, kAllQuantities, ws_.Context(nullptr));
  ASSERT_TRUE(b.ok());
  EXPECT_FALSE(b->fitted.hit) << "the default's fits came from the other options' cache entry";
  const Differentials local = ComputeDifferentials(mesh, plain, kAllQuantities, RunContext(nullptr, 1)).value();
  EXPECT_EQ(b->values->mean, local.mean);
  EXPECT_EQ(b->values->normals, local.normals);
  EXPECT_NE(a->values->mean, local.mean) << "the options differ in their stencils; the test needs that";
}

TEST_F(WorkspaceTest, CancelledFitIsNotCached) {
  const std::string id = Add(testing::TestTorus(16));
  auto s = ws_.Acquire(id, 0).value();
  CancellationToken token;
  token.Cancel();
  EXPECT_EQ(ws_.Fit(s, FitOptions(), ws_.Context(&token)).status().code(), absl::StatusCode::kCancelled);
  EXPECT_EQ(cache_.Stats(Tier::kFitting).entries, 0);
  auto f = ws_.Fit(s, FitOptions(), ws_.Context(nullptr));
  ASSERT_TRUE(f.ok());
  EXPECT_FALSE(f->hit);
}

TEST_F(WorkspaceTest, ReconstructionUsesTheCoreDefaults) {
  const std::string id = Add(testing::TestSphere(10));
  auto s = ws_.Acquire(id, 0).value();
  auto r = ws_.Reconstruct(s, ReconstructionOptions(), false, ws_.Context(nullptr));
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_EQ((*r)->fits->options().degree, DefaultReconstructionFit().degree);
  EXPECT_TRUE((*r)->fits->options().oscillation_safeguard);
  ReconstructionOptions bad;
  bad.feature_angle_deg = 200;
  auto e = ws_.Reconstruct(s, bad, false, ws_.Context(nullptr));
  EXPECT_EQ(e.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(e.status().message().find("feature_angle_deg"), std::string::npos) << e.status();
}

TEST_F(WorkspaceTest, DeleteForgetsEverything) {
  const std::string id = Add(testing::TestTorus(12));
  auto s = ws_.Acquire(id, 0).value();
  ASSERT_TRUE(ws_.Fit(s, FitOptions(), ws_.Context(nullptr)).ok());
  ASSERT_TRUE(ws_.Delete(id).ok());
  EXPECT_EQ(cache_.bytes(), 0);
  EXPECT_EQ(ws_.Acquire(id, 0).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(ws_.Delete(id).code(), absl::StatusCode::kNotFound);
}

}  // namespace
}  // namespace geomfit::server
