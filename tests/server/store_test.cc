#include <filesystem>

#include <gtest/gtest.h>

#include "server/mesh_store.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

std::string TempDir(const std::string& name) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("geomfit_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  return dir.string();
}

MeshRecord InfoFor(const std::string& id, const Mesh& m) {
  MeshRecord info;
  info.mesh_id = id;
  info.num_vertices = m.NumVertices();
  info.num_faces = m.NumFaces();
  info.labels["case"] = "store";
  AmendForPositions(m.positions, 1, &info);
  return info;
}

/// `mesh` with new positions, as UpdatePositions hands it to a store.
std::shared_ptr<const Mesh> Moved(const Mesh& mesh, const Positions& positions) {
  auto moved = std::make_shared<Mesh>(mesh);
  moved->positions = positions;
  return moved;
}

class StoreTest : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    dir_ = TempDir(GetParam());
    if (GetParam() == "memory") {
      store_ = NewMemoryStore();
    } else {
      auto s = OpenSqliteStore(dir_);
      ASSERT_TRUE(s.ok()) << s.status();
      store_ = std::move(*s);
    }
  }
  void TearDown() override {
    store_.reset();
    std::filesystem::remove_all(dir_);
  }
  std::string dir_;
  std::unique_ptr<MeshStore> store_;
};

TEST_P(StoreTest, InsertGetUpdateListDelete) {
  const Mesh mesh = testing::TestTorus();
  auto inserted = store_->Insert(InfoFor("m-1", mesh), mesh);
  ASSERT_TRUE(inserted.ok()) << inserted.status();
  auto again = store_->Insert(InfoFor("m-1", testing::TestSphere()), testing::TestSphere());
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->num_vertices, mesh.NumVertices()) << "existing id: nothing is overwritten";

  auto got = store_->Get("m-1");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_TRUE(testing::SameMesh(*got->mesh, mesh));
  EXPECT_EQ(got->info.labels.at("case"), "store");

  const Positions moved = mesh.positions * 3.0;
  auto updated = store_->UpdatePositions("m-1", 1, Moved(mesh, moved));
  ASSERT_TRUE(updated.ok()) << updated.status();
  EXPECT_EQ(updated->revision, 2);
  EXPECT_EQ(store_->UpdatePositions("m-1", 1, Moved(mesh, moved)).status().code(), absl::StatusCode::kAborted);
  EXPECT_EQ(store_->UpdatePositions("nope", std::nullopt, Moved(mesh, moved)).status().code(), absl::StatusCode::kNotFound);
  got = store_->Get("m-1");
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->mesh->positions, moved);
  EXPECT_EQ(got->mesh->faces, mesh.faces);

  ASSERT_TRUE(store_->Insert(InfoFor("m-0", mesh), mesh).ok());
  ASSERT_TRUE(store_->Insert(InfoFor("m-2", mesh), mesh).ok());
  auto page = store_->List("m-0", 10);
  ASSERT_TRUE(page.ok());
  ASSERT_EQ(page->size(), 2u);
  EXPECT_EQ((*page)[0].mesh_id, "m-1");
  EXPECT_EQ(store_->Stats().meshes, 3);

  EXPECT_TRUE(store_->Delete("m-1").ok());
  EXPECT_EQ(store_->Delete("m-1").code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->Get("m-1").status().code(), absl::StatusCode::kNotFound);
}

INSTANTIATE_TEST_SUITE_P(Stores, StoreTest, ::testing::Values("memory", "sqlite"));

TEST(SqliteStoreTest, SurvivesReopen) {
  const std::string dir = TempDir("reopen");
  const Mesh mesh = testing::TestSphere();
  {
    auto s = OpenSqliteStore(dir);
    ASSERT_TRUE(s.ok());
    ASSERT_TRUE((*s)->Insert(InfoFor("m-x", mesh), mesh).ok());
    ASSERT_TRUE((*s)->UpdatePositions("m-x", 1, Moved(mesh, mesh.positions * 2.0)).ok());
  }
  auto s = OpenSqliteStore(dir);
  ASSERT_TRUE(s.ok());
  auto got = (*s)->Get("m-x");
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->info.revision, 2);
  EXPECT_EQ(got->mesh->positions, Positions(mesh.positions * 2.0));
  std::filesystem::remove_all(dir);
}

TEST(SqliteStoreTest, UnwritableDirectoryIsAClearError) {
  auto s = OpenSqliteStore("/proc/geomfit-cannot-exist");
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("/proc/geomfit-cannot-exist"), std::string::npos) << s.status();
}

}  // namespace
}  // namespace geomfit::server
