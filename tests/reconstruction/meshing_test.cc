// Meshing on the reconstructed surface (4.2): high-order element nodes, uniform
// refinement and point projection, all on the surface to O(h^(d+1)); geometric normal
// jumps across edges O(h^d).
#include <cstdio>
#include <map>
#include <random>
#include <set>

#include <gtest/gtest.h>

#include "core/reconstruction/meshing.h"
#include "core/reconstruction/projection.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"

namespace geomfit {
namespace {

struct Fixture {
  Mesh mesh;
  Topology topo;
  std::shared_ptr<const SurfaceFits> fits;
  double h;
};

Fixture Make(const std::string& name, int n, int degree) {
  GeneratorOptions g;
  g.n = n;
  Fixture s;
  s.mesh = GenerateNamedMesh(name, g).value();
  s.topo = BuildTopology(s.mesh).value();
  FitOptions o;
  o.degree = degree;
  s.fits = FitSurface(s.mesh, s.topo, o).value();
  s.h = AverageEdgeLength(s.mesh);
  return s;
}

double MaxDistance(const AnalyticSurface& exact, const Positions& x) {
  double e = 0;
  for (int i = 0; i < x.rows(); ++i) e = std::max(e, (exact.Project(x.row(i).transpose()) - x.row(i).transpose()).norm());
  return e;
}

TEST(MeshingTest, HighOrderNodesAreSharedAndOrdered) {
  for (const char* name : {"torus", "quadtorus"}) {
    const Fixture s = Make(name, 6, 2);
    WalfSurface walf(s.mesh, s.fits);
    int edges = 0;
    for (int v = 0; v < s.topo.num_vertices; ++v) edges += s.topo.NumNeighbors(v);
    edges /= 2;
    for (int order : {2, 3}) {
      const HighOrderMesh ho = MakeHighOrderMesh(walf, s.topo, order).value();
      const bool quads = s.mesh.HasQuads();
      const int per_face = quads ? (order + 1) * (order + 1) : (order + 1) * (order + 2) / 2;
      const int interior = quads ? (order - 1) * (order - 1) : (order == 3 ? 1 : 0);
      EXPECT_EQ(ho.nodes.rows(), s.mesh.NumVertices() + edges * (order - 1) + s.mesh.NumFaces() * interior);
      for (int f = 0; f < s.mesh.NumFaces(); ++f) {
        ASSERT_EQ(ho.offsets[f + 1] - ho.offsets[f], per_face);
        const int32_t* e = ho.elements.data() + ho.offsets[f];
        for (int c = 0; c < s.mesh.FaceSize(f); ++c) ASSERT_EQ(e[c], s.mesh.faces(f, c));  // corners first
      }
      // Each edge's nodes are shared by exactly its two faces; interior nodes by one.
      std::map<int, int> uses;
      std::set<int> edge_nodes;
      for (int f = 0; f < s.mesh.NumFaces(); ++f) {
        const int n = s.mesh.FaceSize(f);
        for (int q = ho.offsets[f]; q < ho.offsets[f + 1]; ++q) {
          uses[ho.elements[q]]++;
          if (q - ho.offsets[f] >= n && q - ho.offsets[f] < n * order) edge_nodes.insert(ho.elements[q]);
        }
      }
      EXPECT_EQ(static_cast<int>(edge_nodes.size()), edges * (order - 1));
      for (auto [id, count] : uses)
        if (id >= s.mesh.NumVertices()) {
          ASSERT_EQ(count, edge_nodes.count(id) ? 2 : 1) << id;
        }
    }
  }
}

TEST(MeshingTest, RefinedMeshesAreValidAndCounted) {
  const Fixture tri = Make("torus", 6, 3), quad = Make("quadtorus", 6, 3);
  int edges = 0;
  for (int v = 0; v < tri.topo.num_vertices; ++v) edges += tri.topo.NumNeighbors(v);
  edges /= 2;
  WalfSurface wt(tri.mesh, tri.fits), wq(quad.mesh, quad.fits);
  const Mesh r = RefineMesh(wt, tri.topo, 2).value();
  EXPECT_EQ(r.NumVertices(), tri.mesh.NumVertices() + edges);
  EXPECT_EQ(r.NumFaces(), 4 * tri.mesh.NumFaces());
  EXPECT_TRUE(ValidateMesh(r).ok()) << ValidateMesh(r).status();
  for (int factor : {2, 3}) {
    const Mesh rq = RefineMesh(wq, quad.topo, factor).value();
    EXPECT_EQ(rq.NumFaces(), factor * factor * quad.mesh.NumFaces());
    EXPECT_TRUE(rq.HasQuads());
    EXPECT_TRUE(ValidateMesh(rq).ok());
  }
  EXPECT_FALSE(RefineMesh(wt, tri.topo, 1).ok());
  EXPECT_FALSE(MakeHighOrderMesh(wt, tri.topo, 4).ok());
}

// Refined vertices, cubic element nodes and projected points lie on the surface to
// O(h^(d+1)); the geometric normal jumps across edges O(h^d).
TEST(MeshingTest, ConvergenceOfNodesRefinementProjectionAndNormalJumps) {
  auto torus = MakeTorus();
  for (int d : {2, 3, 4}) {
    std::vector<double> h, nodes, refined, projected, jumps, linear;
    for (int n : {12, 24, 48}) {
      const Fixture s = Make("torus", n, d);
      WalfSurface walf(s.mesh, s.fits);
      LinearSurface flat(s.mesh);
      h.push_back(s.h);
      nodes.push_back(MaxDistance(*torus, MakeHighOrderMesh(walf, s.topo, 3).value().nodes));
      refined.push_back(MaxDistance(*torus, RefineMesh(walf, s.topo, 2).value().positions));
      linear.push_back(MaxDistance(*torus, RefineMesh(flat, s.topo, 2).value().positions));
      // Points pushed off the surface by ~h/4 along the normal, and sideways.
      std::mt19937_64 rng(3);
      std::uniform_real_distribution<double> u(-1, 1);
      Positions off(500, 3);
      for (int i = 0; i < off.rows(); ++i) {
        const int v = static_cast<int>((i * 7919) % s.mesh.NumVertices());
        const Eigen::Vector3d p = s.mesh.positions.row(v).transpose();
        off.row(i) = (p + 0.25 * s.h * u(rng) * torus->At(p).normal + 0.3 * s.h * Eigen::Vector3d(u(rng), u(rng), u(rng))).transpose();
      }
      std::vector<ProjectedPoint> proj;
      ASSERT_TRUE(ProjectPoints(walf, s.topo, off, &proj).ok());
      Positions px(proj.size(), 3);
      for (size_t i = 0; i < proj.size(); ++i) px.row(i) = proj[i].point.position.transpose();
      projected.push_back(MaxDistance(*torus, px));
      // Geometric normal (j1 x j2) at edge midpoints seen from both faces.
      double jump = 0;
      for (int f = 0; f < s.mesh.NumFaces(); f += 3) {
        const int a = s.mesh.faces(f, 0), b = s.mesh.faces(f, 1);
        for (int i = 0; i < s.topo.NumVertexFaces(a); ++i) {
          const int g = s.topo.VertexFaces(a)[i];
          int c = 0;
          while (c < 3 && s.mesh.faces(g, c) != b) ++c;
          if (g == f || c == 3 || s.mesh.faces(g, (c + 1) % 3) != a) continue;
          // Edge a-b is edge 0 of f at xi = 0.5; in g it runs b -> a from corner c.
          const double xi_g = c == 0 ? 0.5 : c == 1 ? 0.5 : 0.0, eta_g = c == 0 ? 0.0 : 0.5;
          const SurfacePoint pf = walf.Evaluate({f, 0.5, 0.0}), pg = walf.Evaluate({g, xi_g, eta_g});
          EXPECT_LT((pf.position - pg.position).norm(), 1e-13);  // C0 across the edge
          const Eigen::Vector3d nf = pf.jacobian.col(0).cross(pf.jacobian.col(1)).normalized();
          const Eigen::Vector3d ng = pg.jacobian.col(0).cross(pg.jacobian.col(1)).normalized();
          jump = std::max(jump, (nf - ng).norm());
        }
      }
      jumps.push_back(jump);
    }
    std::printf("d=%d orders: cubic nodes %.2f refined %.2f projected %.2f normal jump %.2f (linear refine %.2f)\n", d,
                ConvergenceOrder(h, nodes), ConvergenceOrder(h, refined), ConvergenceOrder(h, projected),
                ConvergenceOrder(h, jumps), ConvergenceOrder(h, linear));
    EXPECT_GE(ConvergenceOrder(h, nodes), d + 1 - 0.5);
    EXPECT_GE(ConvergenceOrder(h, refined), d + 1 - 0.5);
    EXPECT_GE(ConvergenceOrder(h, projected), d + 1 - 0.5);
    EXPECT_GE(ConvergenceOrder(h, jumps), d - 0.5);
    EXPECT_NEAR(ConvergenceOrder(h, linear), 2, 0.3);
  }
}

TEST(ProjectionTest, RejectsNonFinitePoints) {
  const Fixture s = Make("sphere", 4, 2);
  WalfSurface walf(s.mesh, s.fits);
  Positions p(2, 3);
  p << 0, 0, 1.1, 0, NAN, 0;
  std::vector<ProjectedPoint> out;
  const absl::Status st = ProjectPoints(walf, s.topo, p, &out);
  EXPECT_EQ(st.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(st.message().find("point 1"), std::string::npos);
}

}  // namespace
}  // namespace geomfit
