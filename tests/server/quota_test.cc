// Per-tenant store quotas in the engine (--quota-meshes, --quota-bytes): counted per
// tenant, identical uploads charged once, deletes credited, usage derived from the
// store when it is reopened.
#include "server/workspace/quotas.h"

#include <unistd.h>

#include <filesystem>

#include <gtest/gtest.h>

#include "server/workspace/workspace.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::IsQuotaError;

/// A workspace over `store` with `limits`, its usage loaded.
struct Engine {
  Engine(MeshStore* store, StoreQuotaLimits limits)
      : cache(64 << 20), ws(store, &cache, WorkspaceOptions{.threads = 1, .quotas = limits}) {
    EXPECT_TRUE(ws.quotas().Load(*store).ok());
  }
  absl::StatusOr<MeshRecord> Add(int n, const std::string& tenant, const std::string& name) {
    return ws.AddMesh(testing::TestTorus(n), MeshMeta{name, {}, tenant});
  }
  Cache cache;
  Workspace ws;
};

TEST(StoreQuotasTest, MeshesAreCountedPerTenant) {
  auto store = NewMemoryStore();
  Engine e(store.get(), {.meshes = 2});
  auto first = e.Add(5, "a", "1");
  ASSERT_TRUE(first.ok()) << first.status();
  ASSERT_TRUE(e.Add(5, "a", "2").ok());
  const absl::Status third = e.Add(5, "a", "3").status();
  EXPECT_TRUE(IsQuotaError(third, "--quota-meshes=2")) << third;
  // Content a tenant has stored already is returned as stored and charged nothing.
  auto again = e.Add(5, "a", "1");
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_EQ(again->mesh_id, first->mesh_id);
  EXPECT_EQ(e.ws.quotas().Usage("a").meshes, 2);
  EXPECT_EQ(e.ws.quotas().Usage("a").bytes, 2 * StoredBytes(*first));
  // Another tenant (and the single tenant "") has a quota of its own.
  EXPECT_TRUE(e.Add(5, "b", "1").ok());
  EXPECT_TRUE(e.Add(5, "", "1").ok());
  EXPECT_EQ(e.ws.quotas().Usage("b").meshes, 1);
  // Updates keep one revision: the usage stays; a delete frees a place.
  ASSERT_TRUE(e.ws.UpdatePositions(first->mesh_id, 1, testing::TestTorus(5).positions * 2.0).ok());
  EXPECT_EQ(e.ws.quotas().Usage("a").bytes, 2 * StoredBytes(*first));
  ASSERT_TRUE(e.ws.Delete(first->mesh_id).ok());
  EXPECT_EQ(e.ws.quotas().Usage("a").meshes, 1);
  EXPECT_TRUE(e.Add(5, "a", "3").ok());
  EXPECT_EQ(e.ws.Delete(first->mesh_id).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(e.ws.quotas().Usage("a").meshes, 2);
}

TEST(StoreQuotasTest, BytesAreTheArraysOfTheStoredMeshes) {
  const Mesh mesh = testing::TestTorus(8);
  const int64_t bytes = MeshBytes(mesh);
  auto store = NewMemoryStore();
  Engine e(store.get(), {.bytes = 2 * bytes + bytes / 2});
  auto first = e.Add(8, "a", "1");
  ASSERT_TRUE(first.ok()) << first.status();
  EXPECT_EQ(StoredBytes(*first), bytes);
  EXPECT_EQ(bytes, 24 * mesh.NumVertices() + 16 * mesh.NumFaces());
  ASSERT_TRUE(e.Add(8, "a", "2").ok());
  const absl::Status third = e.Add(8, "a", "3").status();
  EXPECT_TRUE(IsQuotaError(third, "--quota-bytes=" + std::to_string(2 * bytes + bytes / 2))) << third;
  const Mesh small = testing::TestTorus(4);
  ASSERT_LE(MeshBytes(small), bytes / 2);
  EXPECT_TRUE(e.Add(4, "a", "small").ok()) << "what still fits is stored";
  EXPECT_EQ(e.ws.quotas().Usage("a").bytes, 2 * bytes + MeshBytes(small));
}

TEST(StoreQuotasTest, UsageIsDerivedFromTheStoreWhenItIsReopened) {
  const std::string dir =
      (std::filesystem::temp_directory_path() / ("geomfit_quota_" + std::to_string(getpid()))).string();
  std::filesystem::remove_all(dir);
  const StoreQuotaLimits limits{.meshes = 2};
  {
    auto store = OpenSqliteStore(dir);
    ASSERT_TRUE(store.ok()) << store.status();
    Engine e(store->get(), limits);
    ASSERT_TRUE(e.Add(5, "a", "1").ok());
    ASSERT_TRUE(e.Add(5, "a", "2").ok());
    ASSERT_TRUE(e.Add(5, "b", "1").ok());
  }
  auto store = OpenSqliteStore(dir);
  ASSERT_TRUE(store.ok()) << store.status();
  Engine e(store->get(), limits);
  EXPECT_EQ(e.ws.quotas().Usage("a").meshes, 2);
  EXPECT_EQ(e.ws.quotas().Usage("a").bytes, 2 * MeshBytes(testing::TestTorus(5)));
  EXPECT_EQ(e.ws.quotas().Usage("b").meshes, 1);
  EXPECT_TRUE(IsQuotaError(e.Add(5, "a", "3").status(), "--quota-meshes=2"));
  EXPECT_TRUE(e.Add(5, "b", "2").ok());
  std::filesystem::remove_all(dir);
}

TEST(StoreQuotasTest, NoLimitsCountNothing) {
  auto store = NewMemoryStore();
  Engine e(store.get(), {});
  EXPECT_FALSE(e.ws.quotas().enabled());
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(e.Add(5, "a", std::to_string(i)).ok());
  EXPECT_EQ(e.ws.quotas().Usage("a").meshes, 0);
}

}  // namespace
}  // namespace geomfit::server
