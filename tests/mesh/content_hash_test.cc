// The mesh content hash names stored meshes and routes them (deploy/router): it must
// stay the same across releases, processes and machines.
#include "core/mesh/content_hash.h"

#include <cmath>
#include <utility>

#include <gtest/gtest.h>

namespace geomfit {
namespace {

Mesh Tetrahedron() {
  Mesh m;
  m.positions.resize(4, 3);
  m.positions << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor> tris(4, 3);
  tris << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  m.faces = TrianglesToFaces(tris);
  return m;
}

TEST(ContentHashTest, FrozenValues) {
  const Mesh m = Tetrahedron();
  EXPECT_EQ(MeshContentHash(m, "", {}), "e273ddae7b34f594f0b943964f62b17d");
  EXPECT_EQ(MeshContentHash(m, "tet", {{"a", "1"}}), "e673b3388681aa10802c4f1a549b0840");
  EXPECT_EQ(MeshIdOf(MeshContentHash(m, "", {})), "m-" + MeshContentHash(m, "", {}).substr(0, 20));
}

TEST(ContentHashTest, EveryPartCounts) {
  const Mesh m = Tetrahedron();
  const std::string base = MeshContentHash(m, "tet", {{"a", "1"}});
  Mesh moved = m;
  moved.positions(3, 2) = std::nextafter(1.0, 2.0);
  EXPECT_NE(MeshContentHash(moved, "tet", {{"a", "1"}}), base);
  Mesh flipped = m;
  std::swap(flipped.faces.Mutable()(0, 1), flipped.faces.Mutable()(0, 2));
  EXPECT_NE(MeshContentHash(flipped, "tet", {{"a", "1"}}), base);
  EXPECT_NE(MeshContentHash(m, "tet2", {{"a", "1"}}), base);
  EXPECT_NE(MeshContentHash(m, "tet", {{"a", "2"}}), base);
  EXPECT_NE(MeshContentHash(m, "tet", {{"a", "1"}, {"b", ""}}), base);
  // Lengths are hashed: moving bytes between name and label does not collide.
  EXPECT_NE(MeshContentHash(m, "tet", {{"a1", ""}}), MeshContentHash(m, "teta", {{"1", ""}}));
  EXPECT_EQ(MeshContentHash(m, "tet", {{"a", "1"}}), base) << "deterministic";
}

}  // namespace
}  // namespace geomfit
