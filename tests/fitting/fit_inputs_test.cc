// FitInputCache (fit_inputs.h): the cached normals and point records are the fresh ones
// bit for bit, reused while the positions stay, replaced when they change; fits over a
// Neighborhoods whose cache is filled equal fits over fresh stencils.
#include <cstring>

#include <gtest/gtest.h>

#include "core/fitting/fit.h"
#include "core/fitting/fit_inputs.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "core/surfaces/analytic.h"

namespace geomfit {
namespace {

bool SameBits(const double* a, const double* b, size_t n) { return std::memcmp(a, b, 8 * n) == 0; }

Mesh JitteredTorus() {
  GeneratorOptions g;
  g.n = 16;
  g.jitter = 0.3;
  return GenerateTorusMesh(g);
}

TEST(FitInputCacheTest, NormalsAndRecordsEqualFreshOnesAndAreReused) {
  const Mesh mesh = JitteredTorus();
  const Topology topo = BuildTopology(mesh).value();
  ASSERT_EQ(static_cast<int>(topo.locality_order.size()), mesh.NumVertices());
  const Neighborhoods nb = BuildNeighborhoods(topo, mesh, RingSpecFor(FitOptions()), 1);
  EXPECT_EQ(nb.fit_inputs.Bytes(), 0u);
  const size_t empty_bytes = nb.Bytes();
  for (NormalWeighting w : {NormalWeighting::kArea, NormalWeighting::kAngle}) {
    const auto a = nb.fit_inputs.Get(mesh, topo, w, &nb.ordered.order, 2);
    const Positions fresh = ApproximateVertexNormals(mesh, topo, w, 1);
    ASSERT_EQ(a->normals.rows(), mesh.NumVertices());
    EXPECT_TRUE(SameBits(a->normals.data(), fresh.data(), fresh.size()));
    const PointRecords records = MakePointRecords(mesh.positions, fresh, nb.ordered.order.data(), 1);
    ASSERT_EQ(a->records.size(), records.size());
    EXPECT_EQ(std::memcmp(a->records.data(), records.data(), sizeof(PointRecord) * records.size()), 0);
    // Record k: the position and normal of the k-th vertex of the order.
    const int v = nb.ordered.order[7];
    EXPECT_EQ(records[7].p[1], mesh.positions(v, 1));
    EXPECT_EQ(records[7].n[2], fresh(v, 2));
    EXPECT_EQ(nb.fit_inputs.Get(mesh, topo, w, &nb.ordered.order, 1), a);  // reused
  }
  EXPECT_GT(nb.Bytes(), empty_bytes);
  // Moved positions: computed again.
  Mesh moved = mesh;
  moved.positions(3, 0) += 1e-9;
  const auto before = nb.fit_inputs.Get(mesh, topo, NormalWeighting::kArea, &nb.ordered.order, 1);
  const auto after = nb.fit_inputs.Get(moved, topo, NormalWeighting::kArea, &nb.ordered.order, 1);
  EXPECT_NE(after, before);
  const Positions fresh = ApproximateVertexNormals(moved, topo, NormalWeighting::kArea, 1);
  EXPECT_TRUE(SameBits(after->normals.data(), fresh.data(), fresh.size()));
  EXPECT_NE(after->records[nb.ordered.rank[3]].p[0], before->records[nb.ordered.rank[3]].p[0]);
  // Copies start empty.
  const Neighborhoods copy = nb;
  EXPECT_EQ(copy.fit_inputs.Bytes(), 0u);
  EXPECT_GT(nb.fit_inputs.Bytes(), 0u);
}

// Fits and diagnostics bit for bit.
void ExpectSameFits(const SurfaceFits& a, const SurfaceFits& b) {
  ASSERT_EQ(a.num_vertices(), b.num_vertices());
  const int nc = a.dims() * a.num_coefficients();
  for (int v = 0; v < a.num_vertices(); ++v) {
    SCOPED_TRACE(::testing::Message() << "vertex " << v);
    ASSERT_TRUE(SameBits(a.coefficients(v), b.coefficients(v), nc));
    ASSERT_TRUE(SameBits(a.frame(v).normal.data(), b.frame(v).normal.data(), 3));
    ASSERT_TRUE(SameBits(a.frame(v).t1.data(), b.frame(v).t1.data(), 3));
    ASSERT_EQ(a.diagnostics(v).flags, b.diagnostics(v).flags);
    ASSERT_EQ(a.diagnostics(v).degree_used, b.diagnostics(v).degree_used);
  }
}

TEST(FitInputCacheTest, FitsOverACachedNeighborhoodsEqualFreshFits) {
  const Mesh mesh = JitteredTorus();
  const Topology topo = BuildTopology(mesh).value();
  Mesh moved = mesh;
  for (int v = 0; v < moved.NumVertices(); v += 5) moved.positions(v, 2) += 1e-3;
  for (int degree : {2, 4}) {
    for (bool two_pass : {false, true}) {
      FitOptions o;
      o.degree = degree;
      o.two_pass = two_pass;
      o.frame_normals = two_pass ? NormalWeighting::kAngle : NormalWeighting::kArea;
      SCOPED_TRACE(::testing::Message() << "degree " << degree << " two_pass " << two_pass);
      const auto nb = std::make_shared<const Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(o), 1));
      const auto first = FitSurface(mesh, topo, o, nb).value();   // fills the cache
      const auto second = FitSurface(mesh, topo, o, nb).value();  // reads it
      const auto fresh = FitSurface(mesh, topo, o).value();       // own stencils, own cache
      ExpectSameFits(*first, *fresh);
      ExpectSameFits(*second, *fresh);
      // Another geometry over the same stencils (a new revision): its own normals.
      const auto moved_fits = FitSurface(moved, topo, o, nb).value();
      ExpectSameFits(*moved_fits, *FitSurface(moved, topo, o).value());
      EXPECT_NE(moved_fits->frame(0).origin[2], first->frame(0).origin[2]);
    }
  }
}

}  // namespace
}  // namespace geomfit
