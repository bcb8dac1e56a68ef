// k-rings and half rings (2.1, Table 2.1, Fig 2.2) and adaptive growth.
#include <algorithm>
#include <cstdlib>
#include <set>

#include <gtest/gtest.h>

#include "core/fitting/neighborhood.h"
#include "core/surfaces/analytic.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

// An n x n planar grid; triangles all split the same way (valence 6) or quads.
Mesh PlanarGrid(int n, bool quads) {
  Mesh m;
  m.positions.resize((n + 1) * (n + 1), 3);
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.positions.row(j * (n + 1) + i) << i, j, 0;
  m.faces.Mutable().resize(n * n * (quads ? 1 : 2), 4);
  int f = 0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
      if (quads) {
        m.faces.Mutable().row(f++) << a, b, c, d;
      } else {
        m.faces.Mutable().row(f++) << a, b, c, -1;
        m.faces.Mutable().row(f++) << a, c, d, -1;
      }
    }
  return m;
}

int StencilSize(const Mesh& m, int v, double rings) {
  const Topology t = BuildTopology(m).value();
  RingSpec spec;
  spec.rings = rings;
  spec.adaptive = false;
  spec.max_rings = rings;
  spec.max_points = kMaxStencil;
  return BuildNeighborhoods(t, m, spec, 1).Size(v);
}

TEST(NeighborhoodTest, TriangleRingSizesMatchTable21) {
  const Mesh m = PlanarGrid(12, false);
  const int centre = 6 * 13 + 6;
  // Table 2.1: (d+1)/2 rings hold 7, 13, 19, 31, 37, 55 points for d = 1..6.
  const double rings[] = {1, 1.5, 2, 2.5, 3, 3.5};
  const int expected[] = {7, 13, 19, 31, 37, 55};
  for (int i = 0; i < 6; ++i) EXPECT_EQ(StencilSize(m, centre, rings[i]), expected[i]) << rings[i];
}

TEST(NeighborhoodTest, QuadRingSizesFollowFig22) {
  const Mesh m = PlanarGrid(12, true);
  const int centre = 6 * 13 + 6;
  EXPECT_EQ(StencilSize(m, centre, 1), 5);     // edge neighbours
  EXPECT_EQ(StencilSize(m, centre, 1.5), 9);   // the four incident quads
  EXPECT_EQ(StencilSize(m, centre, 2), 13);    // |i| + |j| <= 2
  EXPECT_EQ(StencilSize(m, centre, 2.5), 21);  // 5 x 5 without corners
}

TEST(NeighborhoodTest, StencilsStartAtTheVertexAndHaveNoDuplicates) {
  GeneratorOptions g;
  g.n = 10;
  const Mesh m = GenerateBumpMesh(g);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 4;
  const Neighborhoods nb = BuildNeighborhoods(t, m, RingSpecFor(o), 2);
  for (int v = 0; v < m.NumVertices(); ++v) {
    ASSERT_EQ(nb.Points(v)[0], v);
    std::set<int> unique(nb.Points(v), nb.Points(v) + nb.Size(v));
    ASSERT_EQ(static_cast<int>(unique.size()), nb.Size(v));
  }
}

TEST(NeighborhoodTest, AdaptiveGrowthReachesMinimumAndBoundaryGrowsFurther) {
  GeneratorOptions g;
  g.n = 16;
  const Mesh m = GenerateBumpMesh(g);
  const Topology t = BuildTopology(m).value();
  for (int d = 1; d <= 6; ++d) {
    FitOptions o;
    o.degree = d;
    const RingSpec spec = RingSpecFor(o);
    EXPECT_EQ(spec.min_points, static_cast<int>(std::ceil((d <= 2 ? 2.0 : 1.5) * NumCoefficients(d))));
    const Neighborhoods nb = BuildNeighborhoods(t, m, spec, 1);
    for (int v = 0; v < m.NumVertices(); ++v) {
      const int want = t.is_boundary[v] ? spec.min_points_boundary : spec.min_points;
      ASSERT_GE(nb.Size(v), want) << "vertex " << v << " degree " << d << " rings " << nb.rings[v];
      ASSERT_LE(nb.Size(v), spec.max_points);
      ASSERT_GE(nb.rings[v], spec.rings);
    }
    // Corner vertex 0 needs more rings than the start.
    EXPECT_GT(nb.rings[0], spec.rings) << "degree " << d;
  }
}

TEST(NeighborhoodTest, MaxPointsStopsAtTheLastCompleteRing) {
  const Mesh m = PlanarGrid(12, false);
  const Topology t = BuildTopology(m).value();
  RingSpec spec;
  spec.rings = 1;
  spec.min_points = 1000;  // always wants more
  spec.max_rings = 6;
  spec.max_points = 40;
  const Neighborhoods nb = BuildNeighborhoods(t, m, spec, 1);
  const int centre = 6 * 13 + 6;
  EXPECT_EQ(nb.Size(centre), 37);  // 3-ring; the 3.5-ring (55) would exceed 40
  EXPECT_EQ(nb.rings[centre], 3.0f);
}

TEST(NeighborhoodTest, IdenticalForAnyThreadCount) {
  GeneratorOptions g;
  g.n = 20;
  const Mesh m = GenerateTorusMesh(g);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 3;
  const Neighborhoods a = BuildNeighborhoods(t, m, RingSpecFor(o), 1);
  for (int threads : {2, 3, 7}) {
    const Neighborhoods b = BuildNeighborhoods(t, m, RingSpecFor(o), threads);
    EXPECT_EQ(a.offsets, b.offsets);
    EXPECT_EQ(a.indices, b.indices);
  }
}

// A mesh numbered at random (here 27,648 vertices, far from local) is grown in
// breadth-first order: the stencils must be those of the same mesh in its generated
// (local) order, relabelled, for any thread count.
TEST(NeighborhoodTest, ShuffledNumberingGivesTheRelabelledStencils) {
  GeneratorOptions g;
  g.n = 96;
  const Mesh m = GenerateTorusMesh(g);
  std::vector<int32_t> perm;
  const Mesh s = testing_util::ShuffleVertices(m, 3, &perm);
  const Topology tm = BuildTopology(m).value(), ts = BuildTopology(s).value();
  int64_t gap = 0;  // above kLocalIndexGap (4096) on average: the breadth-first path
  for (int v = 0; v < ts.num_vertices; ++v)
    for (int j = 0; j < ts.NumNeighbors(v); ++j) gap += std::abs(v - ts.Neighbors(v)[j]);
  ASSERT_GT(gap / static_cast<int64_t>(ts.vv.size()), 4096);
  for (int degree : {2, 4}) {
    FitOptions o;
    o.degree = degree;
    const Neighborhoods a = BuildNeighborhoods(tm, m, RingSpecFor(o), 1);
    const Neighborhoods b = BuildNeighborhoods(ts, s, RingSpecFor(o), 1);
    const Neighborhoods b2 = BuildNeighborhoods(ts, s, RingSpecFor(o), 2);
    EXPECT_EQ(b.offsets, b2.offsets);
    EXPECT_EQ(b.indices, b2.indices);
    int mismatches = 0;
    for (int v = 0; v < m.NumVertices(); ++v) {
      const int w = perm[v];
      std::vector<int32_t> want;
      for (int i = 0; i < a.Size(v); ++i) want.push_back(perm[a.Points(v)[i]]);
      std::vector<int32_t> got(b.Points(w), b.Points(w) + b.Size(w));
      mismatches += got.empty() || got[0] != w || b.rings[w] != a.rings[v];
      std::sort(want.begin(), want.end());
      std::sort(got.begin(), got.end());
      mismatches += got != want;
    }
    EXPECT_EQ(mismatches, 0) << "degree " << degree;
  }
}

}  // namespace
}  // namespace geomfit
