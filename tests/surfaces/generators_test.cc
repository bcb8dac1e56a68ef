// The project's analytic test meshes: valid, on the surface, outward, irregular, and
// h halves when the resolution doubles.
#include <algorithm>

#include <gtest/gtest.h>

#include "core/fitting/frames.h"
#include "core/mesh/topology.h"
#include "core/surfaces/analytic.h"

namespace geomfit {
namespace {

class GeneratorTest : public testing::TestWithParam<std::string> {};

TEST_P(GeneratorTest, ValidOnSurfaceOutwardAndRefining) {
  const std::string name = GetParam();
  auto surface = NamedSurface(name).value();
  double previous_h = 0;
  for (int n : {8, 16, 32}) {
    GeneratorOptions g;
    g.n = n;
    const Mesh m = GenerateNamedMesh(name, g).value();
    auto topo = ValidateMesh(m);
    ASSERT_TRUE(topo.ok()) << topo.status();
    EXPECT_EQ(topo->num_boundary_edges > 0, name == "bump");
    EXPECT_EQ(topo->num_isolated, 0);
    for (int v = 0; v < m.NumVertices(); ++v) {
      const Eigen::Vector3d p = m.positions.row(v).transpose();
      ASSERT_LT((surface->Project(p) - p).norm(), 1e-12) << name << " vertex " << v;
    }
    for (int f = 0; f < m.NumFaces(); ++f) {
      Eigen::Vector3d centre = Eigen::Vector3d::Zero();
      for (int i = 0; i < m.FaceSize(f); ++i) centre += m.positions.row(m.faces(f, i)).transpose();
      centre /= m.FaceSize(f);
      ASSERT_GT(FaceNormal(m, f).dot(surface->At(surface->Project(centre)).normal), 0.5) << name << " face " << f;
    }
    if (!m.HasQuads()) {  // random diagonals: irregular valences
      int lo = 100, hi = 0;
      for (int v = 0; v < m.NumVertices(); ++v)
        if (!topo->is_boundary[v]) lo = std::min(lo, topo->NumNeighbors(v)), hi = std::max(hi, topo->NumNeighbors(v));
      EXPECT_LE(lo, 5);
      EXPECT_GE(hi, 7);
    }
    const double h = AverageEdgeLength(m);
    if (previous_h > 0) {
      EXPECT_NEAR(previous_h / h, 2.0, 0.15) << name;
    }
    previous_h = h;
  }
}

INSTANTIATE_TEST_SUITE_P(Named, GeneratorTest,
                         testing::Values("sphere", "torus", "ellipsoid", "bump", "quadtorus"));

TEST(GeneratorTest, SameSeedSameMeshOtherSeedOtherMesh) {
  GeneratorOptions a, b;
  a.n = b.n = 10;
  EXPECT_EQ(GenerateTorusMesh(a).positions, GenerateTorusMesh(b).positions);
  b.seed = 2;
  EXPECT_NE(GenerateTorusMesh(a).positions, GenerateTorusMesh(b).positions);
}

TEST(GeneratorTest, RejectsUnknownNamesAndBadLevels) {
  GeneratorOptions g;
  EXPECT_FALSE(GenerateNamedMesh("klein", g).ok());
  g.n = 1;
  EXPECT_FALSE(GenerateNamedMesh("torus", g).ok());
}

}  // namespace
}  // namespace geomfit
