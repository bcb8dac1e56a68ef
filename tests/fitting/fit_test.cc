// The per-vertex WLS fit (2.2-2.4): exactness on polynomials, its stencil operator,
// the condition safeguard, diagnostics, option validation, cancellation.
#include <cmath>
#include <cstring>
#include <map>
#include <mutex>
#include <random>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "core/fitting/fit.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/errors.h"
#include "core/surfaces/analytic.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

using ::testing::HasSubstr;

// The project's irregular torus (R = 1, r = 0.3) at resolution n.
Mesh Torus(int n) {
  GeneratorOptions g;
  g.n = n;
  return GenerateTorusMesh(g);
}

// A flat, jittered, randomly split grid in the plane z = 0: every frame normal is
// exactly +z, so frame coordinates are an exact rotation of (x, y).
Mesh FlatMesh(int n) {
  GeneratorOptions g;
  g.n = n;
  Mesh m = GenerateBumpMesh(g);
  m.positions.col(2).setZero();
  return m;
}

// g(x, y): a full polynomial of degree d with fixed pseudo-random coefficients.
double Poly(int d, double x, double y) {
  double s = 0;
  int i = 0;
  for (int p = 0; p <= d; ++p)
    for (int k = 0; k <= p; ++k, ++i) s += std::sin(1.0 + i) * std::pow(x, p - k) * std::pow(y, k);
  return s;
}

// Gradient of Poly by central differences of its exact polynomial (step small, exact
// enough for a 1e-6 check) is avoided: differentiate analytically instead.
Eigen::Vector2d PolyGrad(int d, double x, double y) {
  Eigen::Vector2d g = Eigen::Vector2d::Zero();
  int i = 0;
  for (int p = 0; p <= d; ++p)
    for (int k = 0; k <= p; ++k, ++i) {
      const double c = std::sin(1.0 + i), j = p - k;
      if (j > 0) g.x() += c * j * std::pow(x, j - 1) * std::pow(y, k);
      if (k > 0) g.y() += c * k * std::pow(x, j) * std::pow(y, k - 1);
    }
  return g;
}

// ApproximateVertexNormals sums corner normals face by face; each vertex's sum must be
// the one over its fan in topo.VertexFaces order, bit for bit, on any numbering, with
// quads, for either weighting and thread count.
TEST(FitTest, VertexNormalsEqualTheSumsOverEachFanInOrder) {
  GeneratorOptions g;
  g.n = 7;
  GeneratorOptions q = g;
  q.quads = true;
  for (const Mesh& base : {GenerateTorusMesh(g), GenerateSphereMesh(g), GenerateBumpMesh(g), GenerateBumpMesh(q)}) {
    const Mesh mesh = testing_util::ShuffleVertices(base, 5);
    const Topology t = BuildTopology(mesh).value();
    for (NormalWeighting w : {NormalWeighting::kArea, NormalWeighting::kAngle}) {
      Positions want(mesh.NumVertices(), 3);
      for (int v = 0; v < mesh.NumVertices(); ++v) {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        const Eigen::Vector3d x = mesh.positions.row(v).transpose();
        for (int i = 0; i < t.NumVertexFaces(v); ++i) {
          const int f = t.VertexFaces(v)[i];
          int c = 0;
          while (mesh.faces(f, c) != v) ++c;
          const Eigen::Vector3d a = mesh.positions.row(mesh.Next(f, c)).transpose() - x;
          const Eigen::Vector3d b = mesh.positions.row(mesh.Prev(f, c)).transpose() - x;
          const Eigen::Vector3d cr = a.cross(b);
          if (w == NormalWeighting::kArea) {
            sum += cr;
          } else if (cr.norm() > 0) {
            sum += std::atan2(cr.norm(), a.dot(b)) * cr / cr.norm();
          }
        }
        want.row(v) = sum / sum.norm();
      }
      for (int threads : {1, 2, 3, 7}) {  // 2+: each thread adds its vertices' corners
        const Positions got = ApproximateVertexNormals(mesh, t, w, threads);
        for (int v = 0; v < mesh.NumVertices(); ++v)
          for (int k = 0; k < 3; ++k) ASSERT_EQ(got(v, k), want(v, k)) << "vertex " << v << " threads " << threads;
      }
    }
  }
}

// On a kRotational relabelling's topology (Topology::fan_rows, the CLI's) each corner's
// spokes are read from the fan-ordered neighbour rows instead of the face rows: the same
// sums bit for bit as the walk over the face rows (fan_rows cleared), on closed and open
// fans, triangles and quads, either weighting, 1 and 2 threads.
TEST(FitTest, FanRowNormalsEqualTheFaceRowWalk) {
  GeneratorOptions g;
  g.n = 9;
  GeneratorOptions q = g;
  q.quads = true;
  for (const Mesh& base : {GenerateTorusMesh(g), GenerateBumpMesh(q), GenerateDelaunaySphereMesh(400, 0.3),
                           GenerateOpenCylinderMesh(g)}) {
    const LocalityRelabelling r =
        RelabelForLocality(testing_util::ShuffleVertices(base, 3), RowOrder::kRotational).value();
    Topology fan = BuildTopology(r).value();
    ASSERT_TRUE(fan.fan_rows);
    Topology walk = fan;
    walk.fan_rows = false;
    for (NormalWeighting w : {NormalWeighting::kArea, NormalWeighting::kAngle})
      for (int threads : {1, 2}) {
        const Positions got = ApproximateVertexNormals(r.mesh, fan, w, threads);
        const Positions want = ApproximateVertexNormals(r.mesh, walk, w, threads);
        for (int v = 0; v < r.mesh.NumVertices(); ++v)
          for (int k = 0; k < 3; ++k) ASSERT_EQ(got(v, k), want(v, k)) << "vertex " << v;
      }
  }
  EXPECT_FALSE(BuildTopology(RelabelForLocality(GenerateTorusMesh(g), RowOrder::kSource).value())->fan_rows);
}

// A mesh relabelled for locality (what `geomfit curvature --local` fits on a scattered
// numbering). With RowOrder::kSource rows it gives the source's stencils point for point,
// its vertex normals and every differential quantity bit for bit, in relabelled order.
// With RowOrder::kRotational rows (the CLI's) the stencils hold the same point sets
// (sizes, rings) in another order, so vertex normals, fitted normals, curvatures and
// tensors agree to 1e-12 relative (normals: 1e-12 in norm; scalars: of the largest
// |value| of the quantity over the mesh, as the "equal to 1e-12 relative"),
// diagnostics exactly. Shuffled torus, mixed quad/triangle bump (open), Delaunay sphere
// (a mesher's valences), open cylinder (two boundary loops); degrees 1-6, LHF and LOP,
// 1 and 2 threads.
TEST(FitTest, RelabelledMeshGivesTheSourcesResultsToRoundOff) {
  GeneratorOptions g;
  g.n = 9;
  GeneratorOptions q = g;
  q.quads = true;
  double worst[2] = {0, 0};  // kRotational: vertex normals, fits
  for (const Mesh& base : {GenerateTorusMesh(g), GenerateBumpMesh(q), GenerateDelaunaySphereMesh(400, 0.3),
                           GenerateOpenCylinderMesh(g)}) {
    const Mesh mesh = testing_util::ShuffleVertices(base, 9);
    const Topology t = BuildTopology(mesh).value();
    for (RowOrder order : {RowOrder::kSource, RowOrder::kRotational}) {
      const bool exact = order == RowOrder::kSource;
      const LocalityRelabelling r = RelabelForLocality(mesh, order).value();
      const std::vector<int32_t>& src = r.vertex_source;
      const Topology u = BuildTopology(r).value();
      // |a - b| <= tol x scale, and exactly equal for kSource.
      auto near = [&](double a, double b, double scale, double tol, int slot) {
        if (!exact) worst[slot] = std::max(worst[slot], std::abs(a - b) / scale);
        return exact ? a == b : std::abs(a - b) <= tol * scale;
      };
      for (NormalWeighting w : {NormalWeighting::kArea, NormalWeighting::kAngle})
        for (int threads : {1, 2}) {
          const Positions want = ApproximateVertexNormals(mesh, t, w, threads);
          const Positions got = ApproximateVertexNormals(r.mesh, u, w, threads);
          for (int v = 0; v < mesh.NumVertices(); ++v)
            for (int k = 0; k < 3; ++k) ASSERT_TRUE(near(got(v, k), want(src[v], k), 1.0, 1e-12, 0)) << "vertex " << v;
        }
      for (int degree = 1; degree <= 6; ++degree)
        for (FitMethod method : {FitMethod::kLHF, FitMethod::kLOP}) {
          FitOptions o;
          o.degree = degree;
          o.method = method;
          const Neighborhoods nt = BuildNeighborhoods(t, mesh, RingSpecFor(o), 1);
          const Neighborhoods nu = BuildNeighborhoods(u, r.mesh, RingSpecFor(o), 2);
          for (int v = 0; v < mesh.NumVertices(); ++v) {
            ASSERT_EQ(nu.Size(v), nt.Size(src[v])) << "degree " << degree << " vertex " << v;
            ASSERT_EQ(nu.rings[v], nt.rings[src[v]]);
            std::vector<int32_t> got(nu.Size(v)), want(nt.Points(src[v]), nt.Points(src[v]) + nt.Size(src[v]));
            for (int i = 0; i < nu.Size(v); ++i) got[i] = src[nu.Points(v)[i]];
            ASSERT_EQ(got[0], want[0]);  // the vertex itself first
            if (!exact) std::sort(got.begin(), got.end()), std::sort(want.begin(), want.end());
            ASSERT_EQ(got, want) << "degree " << degree << " vertex " << v;
          }
          const int threads = degree % 2 + 1;
          const Differentials want = ComputeDifferentials(
              *FitSurface(mesh, t, o, nullptr, {}, RunContext(nullptr, threads)).value(), kAllQuantities, threads);
          const Differentials got = ComputeDifferentials(
              *FitSurface(r.mesh, u, o, nullptr, {}, RunContext(nullptr, threads)).value(), kAllQuantities, threads);
          // Relative to max(|value|, the size of the quantity over the mesh), as
          // wls_batch_test's Near (a curvature vanishing by symmetry at its peers' size).
          const double ks = std::max(want.k1.cwiseAbs().maxCoeff(), want.k2.cwiseAbs().maxCoeff());
          const double ts = want.tensor.cwiseAbs().maxCoeff();
          // A fit's round-off grows with its condition (the largest here, 5e4, is degree
          // 6 at the coarse cylinder's rim, 1.2e-12 relative): 1e-12 up to a condition of
          // 1e4, in proportion beyond.
          double tol = 0;
          auto rel = [&](double a, double b, double scale) { return near(a, b, std::max(std::abs(b), scale), tol, 1); };
          for (int v = 0; v < mesh.NumVertices(); ++v) {
            const int s = src[v];
            tol = 1e-12 * std::max(1.0, want.diagnostics[s].condition / 1e4);
            SCOPED_TRACE(::testing::Message() << "mesh " << mesh.NumVertices() << " degree " << degree << " "
                                              << FitMethodName(method) << " vertex " << v);
            for (int k = 0; k < 3; ++k) ASSERT_TRUE(rel(got.normals(v, k), want.normals(s, k), 1.0));
            ASSERT_TRUE(rel(got.mean(v), want.mean(s), ks)) << got.mean(v) << " " << want.mean(s);
            ASSERT_TRUE(rel(got.gaussian(v), want.gaussian(s), ks * ks)) << got.gaussian(v) << " " << want.gaussian(s);
            ASSERT_TRUE(rel(got.k1(v), want.k1(s), ks)) << got.k1(v) << " " << want.k1(s);
            ASSERT_TRUE(rel(got.k2(v), want.k2(s), ks)) << got.k2(v) << " " << want.k2(s);
            for (int k = 0; k < 9; ++k) ASSERT_TRUE(rel(got.tensor(v, k), want.tensor(s, k), ts));
            if (exact) ASSERT_EQ(got.dir1.row(v), want.dir1.row(s));
            ASSERT_EQ(got.diagnostics[v].flags, want.diagnostics[s].flags);
            ASSERT_EQ(got.diagnostics[v].points, want.diagnostics[s].points);
            ASSERT_EQ(got.diagnostics[v].degree_used, want.diagnostics[s].degree_used);
          }
        }
    }
  }
  std::printf("kRotational vs kSource, largest relative difference: vertex normals %.2g, fits %.2g\n", worst[0],
              worst[1]);
  EXPECT_GT(worst[1], 0.0);  // the orders differ: the comparison is not vacuous
}

TEST(FitTest, StencilsReproducePolynomialsOfTheFitDegreeExactly) {
  const Mesh m = FlatMesh(12);
  const Topology t = BuildTopology(m).value();
  for (int d = 1; d <= 6; ++d) {
    for (bool interpolate : {true, false}) {
      FitOptions o;
      o.degree = d;
      o.interpolate = interpolate;
      auto fits = FitSurface(m, t, o, nullptr, FitRequest{.stencils = true}).value();
      ASSERT_TRUE(fits->has_stencils());
      Eigen::VectorXd g(m.NumVertices());
      for (int v = 0; v < m.NumVertices(); ++v) g(v) = Poly(d, m.positions(v, 0), m.positions(v, 1));
      for (int v = 0; v < m.NumVertices(); v += 7) {
        ASSERT_EQ(fits->diagnostics(v).degree_used, d) << "vertex " << v;
        const int n = fits->neighborhoods().Size(v);
        const int32_t* pts = fits->neighborhoods().Points(v);
        const double* S = fits->stencil(v);
        double c00 = 0, c10 = 0, c01 = 0;
        for (int k = 0; k < n; ++k) {
          c00 += S[TaylorIndex(0, 0) * n + k] * g(pts[k]);
          c10 += S[TaylorIndex(1, 0) * n + k] * g(pts[k]);
          c01 += S[TaylorIndex(0, 1) * n + k] * g(pts[k]);
        }
        const LocalFrame& fr = fits->frame(v);
        const Eigen::Vector2d grad = PolyGrad(d, m.positions(v, 0), m.positions(v, 1));
        const Eigen::Vector3d grad3(grad.x(), grad.y(), 0);
        const double scale = 1 + grad.norm();
        EXPECT_NEAR(c00, g(v), 1e-9 * scale) << "d " << d << " vertex " << v;
        EXPECT_NEAR(c10, grad3.dot(fr.t1), 1e-8 * scale) << "d " << d << " vertex " << v;
        EXPECT_NEAR(c01, grad3.dot(fr.t2), 1e-8 * scale) << "d " << d << " vertex " << v;
      }
    }
  }
}

TEST(FitTest, StencilAppliedToHeightsEqualsTheFit) {
  const Mesh m = Torus(16);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 4;
  auto fits = FitSurface(m, t, o, nullptr, FitRequest{.stencils = true}).value();
  for (int v = 0; v < m.NumVertices(); v += 11) {
    const LocalFrame& fr = fits->frame(v);
    const int n = fits->neighborhoods().Size(v), nc = fits->num_coefficients();
    const int32_t* pts = fits->neighborhoods().Points(v);
    for (int c = 0; c < nc; ++c) {
      double value = 0;
      for (int k = 0; k < n; ++k)
        value += fits->stencil(v)[c * n + k] * fr.normal.dot(m.positions.row(pts[k]).transpose() - fr.origin);
      EXPECT_NEAR(value, fits->coefficients(v)[c], 1e-9 * (1 + std::abs(value))) << v << " " << c;
    }
  }
}

TEST(FitTest, ConditionSafeguardDropsWholeDegrees) {
  const Mesh m = Torus(12);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 4;
  o.cond_threshold[4] = 1.0;  // no degree-4 system is that well conditioned
  o.cond_threshold[3] = 1.0;
  auto fits = FitSurface(m, t, o).value();
  for (int v = 0; v < m.NumVertices(); ++v) {
    const VertexDiagnostics& d = fits->diagnostics(v);
    ASSERT_EQ(d.degree_requested, 4);
    ASSERT_EQ(d.degree_used, 2);
    ASSERT_TRUE(d.flags & kFlagDowngraded);
    ASSERT_EQ(d.rank, NumCoefficients(2));  // interpolating: 5 solved + c00
    // Coefficients above the degree used are zero.
    for (int c = NumCoefficients(2); c < NumCoefficients(4); ++c) ASSERT_EQ(fits->coefficients(v)[c], 0.0);
  }
  // Without the forced cut-off nothing is downgraded on this well-shaped mesh.
  o.cond_threshold[4] = 1e4;
  o.cond_threshold[3] = 3.3e3;
  fits = FitSurface(m, t, o).value();
  for (int v = 0; v < m.NumVertices(); ++v) ASSERT_EQ(fits->diagnostics(v).degree_used, 4);
}

TEST(FitTest, SafeguardAngleFiltersFoldedNeighbours) {
  // On a coarse torus with a tiny cut-off angle, points are dropped (fewer used).
  const Mesh m = Torus(6);
  const Topology t = BuildTopology(m).value();
  FitOptions wide, narrow;
  wide.degree = narrow.degree = 2;
  narrow.safeguard_angle_deg = 20;
  auto a = FitSurface(m, t, wide).value(), b = FitSurface(m, t, narrow).value();
  int fewer = 0;
  for (int v = 0; v < m.NumVertices(); ++v) fewer += b->diagnostics(v).points < a->diagnostics(v).points;
  EXPECT_GT(fewer, m.NumVertices() / 2);
}

TEST(FitTest, IsolatedAndStarvedVerticesAreFlaggedNotFatal) {
  Mesh m;
  m.positions.resize(4, 3);
  m.positions << 0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 5, 5;  // vertex 3 is isolated
  m.faces.Mutable().resize(1, 4);
  m.faces.Mutable() << 0, 1, 2, -1;
  FitOptions o;
  o.degree = 2;
  auto d = ComputeDifferentials(m, o);
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_TRUE(d->diagnostics[3].flags & kFlagIsolated);
  EXPECT_TRUE(std::isnan(d->mean(3)));
  for (int v = 0; v < 3; ++v) {
    EXPECT_TRUE(d->diagnostics[v].flags & kFlagTooFewPoints);
    EXPECT_TRUE(d->diagnostics[v].flags & kFlagBoundary);
    EXPECT_NEAR(std::abs(d->normals(v, 2)), 1.0, 1e-12);  // degree 1 still gives the plane
  }
}

// Frames, coefficients, diagnostics and stencils are sized unwritten and reset per
// vertex by the thread that fits it: equal bit for bit for 1, 2, 3 and 7 threads, on every
// path (lane set-up at degree 2, the batched kernel, stencils, blocks reported in vertex
// order), with boundary and isolated vertices, over storage poisoned with NaN before.
TEST(FitTest, FitsAreBitIdenticalForAnyThreadCount) {
  GeneratorOptions g;
  g.n = 44;  // 2025 vertices: 4 blocks of the fit loop
  Mesh m = GenerateBumpMesh(g);
  const int nv = m.NumVertices();
  m.positions.conservativeResize(nv + 2, 3);
  m.positions.bottomRows(2) << 3, 3, 3, 4, 4, 4;  // two isolated vertices
  const Topology t = BuildTopology(m).value();
  ASSERT_EQ(static_cast<int>(t.locality_order.size()), nv + 2);
  for (int degree : {1, 2, 4}) {  // 1: its Hermite normals (plane_slopes.h)
    FitOptions o;
    o.degree = degree;
    const auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(t, m, RingSpecFor(o), 1));
    for (int path = 0; path < 3; ++path) {  // 0: plain, 1: stencils, 2: blocks reported
      FitRequest req;
      req.stencils = path == 1;
      int64_t reported = 0;
      const FittedBlockFn count = [&](const SurfaceFits&, int64_t b, int64_t e) { reported += e - b; };
      std::shared_ptr<const SurfaceFits> one;
      for (int threads : {1, 2, 3, 7}) {
        SCOPED_TRACE(::testing::Message() << "degree " << degree << " path " << path << " threads " << threads);
        {  // freed storage of the fits' sizes full of NaN, for the fit's vectors to reuse
          std::vector<std::vector<double>> poison;
          for (size_t doubles : {sizeof(LocalFrame) / 8 * (nv + 2), size_t{28} * (nv + 2), size_t{2} * (nv + 2)})
            poison.emplace_back(doubles, std::nan(""));
        }
        reported = 0;
        const auto fits =
            FitSurface(m, t, o, nb, req, RunContext(nullptr, threads), path == 2 ? count : FittedBlockFn()).value();
        if (path == 2) ASSERT_EQ(reported, nv + 2);
        for (int v : {nv, nv + 1}) {  // isolated: the fallback frame, zero coefficients
          EXPECT_TRUE(fits->diagnostics(v).flags & kFlagIsolated);
          EXPECT_EQ(fits->frame(v).normal, Eigen::Vector3d::UnitZ());
          for (int i = 0; i < fits->num_coefficients(); ++i) EXPECT_EQ(fits->coefficients(v)[i], 0.0);
        }
        if (threads == 1) {
          one = fits;
          continue;
        }
        const size_t ncoef = static_cast<size_t>(fits->dims()) * fits->num_coefficients();
        for (int v = 0; v < nv + 2; ++v) {
          ASSERT_EQ(0, std::memcmp(&fits->frame(v), &one->frame(v), sizeof(LocalFrame))) << "vertex " << v;
          ASSERT_EQ(0, std::memcmp(fits->coefficients(v), one->coefficients(v), ncoef * 8)) << "vertex " << v;
          const VertexDiagnostics &a = fits->diagnostics(v), &b = one->diagnostics(v);
          ASSERT_EQ(a.points, b.points);
          ASSERT_EQ(a.degree_requested, b.degree_requested);
          ASSERT_EQ(a.degree_used, b.degree_used);
          ASSERT_EQ(a.rank, b.rank);
          ASSERT_EQ(a.flags, b.flags);
          ASSERT_EQ(0, std::memcmp(&a.condition, &b.condition, sizeof(float)));
          ASSERT_EQ(a.flags & kFlagBoundary, t.is_boundary[v] ? kFlagBoundary : 0);
          if (req.stencils)
            ASSERT_EQ(0, std::memcmp(fits->stencil(v), one->stencil(v), sizeof(double) * fits->stencil_rows() * nb->Size(v)));
        }
      }
    }
  }
}

// The FitSurfaceOnce tests' variants: 0-2 and 6 the plain path (LHF d2, d4, LOP; 6 on
// a topology with a locality order), 3-5 paths that keep their inputs (two passes, a
// normal pre-fit, the noise mode).
FitOptions FitOnceVariant(int variant) {
  FitOptions o;
  o.degree = variant == 1 ? 4 : 2;
  o.jet_hermite = JetHermiteMode::kOff;  // degree 4 on the plain path
  if (variant == 2) o.method = FitMethod::kLOP;
  if (variant == 3) o.two_pass = true;
  if (variant == 4) o.normal_degree = 3;
  if (variant == 5) o.noise = NoiseMode::kOn;
  return o;
}

// FitSurfaceOnce frees the mesh's faces, the topology's rows, the positions and the
// normals as soon as its plain path has read them (fit.h): its fits must be FitSurface's
// bit for bit (a read of anything freed would crash or change them), on the plain path
// (LHF d2 / d4, LOP; a topology with or without a locality order) and on paths that keep
// their inputs to the end (two passes, a normal pre-fit, the noise mode), on a relabelled bump (boundary flags from is_boundary, which
// is kept), 1 and 2 threads; keep_neighborhoods = false leaves no stencils in the fits.
TEST(FitTest, FitSurfaceOnceGivesFitSurfacesBits) {
  GeneratorOptions g;
  g.n = 40;
  const Mesh shuffled = testing_util::ShuffleVertices(GenerateBumpMesh(g), 7, nullptr);
  const LocalityRelabelling r = RelabelForLocality(shuffled).value();
  for (int variant = 0; variant < 7; ++variant) {
    // Variant 6: the plain path on a mesh's own topology (with a locality order).
    const Topology topo = variant == 6 ? BuildTopology(r.mesh).value() : BuildTopology(r).value();
    ASSERT_EQ(topo.locality_order.empty(), variant != 6);
    ASSERT_GT(topo.num_boundary_edges, 0);
    const int nv = r.mesh.NumVertices();
    const FitOptions o = FitOnceVariant(variant);
    for (int threads : {1, 2}) {
      SCOPED_TRACE(::testing::Message() << "variant " << variant << " threads " << threads);
      const RunContext ctx(nullptr, threads);
      const auto want = FitSurface(r.mesh, topo, o, nullptr, {}, ctx).value();
      FitRequest req;
      req.keep_neighborhoods = threads == 2;
      const auto got = FitSurfaceOnce(r.mesh, topo, o, req, ctx).value();
      EXPECT_EQ(got->has_neighborhoods(), threads == 2);
      EXPECT_TRUE(want->has_neighborhoods());
      ASSERT_EQ(got->num_vertices(), nv);
      const size_t ncoef = static_cast<size_t>(got->dims()) * got->num_coefficients();
      int boundary = 0;
      for (int v = 0; v < nv; ++v) {
        ASSERT_EQ(0, std::memcmp(&got->frame(v), &want->frame(v), sizeof(LocalFrame))) << "vertex " << v;
        ASSERT_EQ(0, std::memcmp(got->coefficients(v), want->coefficients(v), ncoef * 8)) << "vertex " << v;
        const VertexDiagnostics &a = got->diagnostics(v), &b = want->diagnostics(v);
        ASSERT_EQ(a.points, b.points) << "vertex " << v;
        ASSERT_EQ(a.degree_requested, b.degree_requested);
        ASSERT_EQ(a.degree_used, b.degree_used);
        ASSERT_EQ(a.rank, b.rank);
        ASSERT_EQ(a.flags, b.flags);
        ASSERT_EQ(0, std::memcmp(&a.condition, &b.condition, sizeof(float)));
        boundary += (a.flags & kFlagBoundary) != 0;
      }
      EXPECT_GT(boundary, 0);
    }
  }
}

// FitSurfaceOnceInBlocks hands each block's fits over in a window of its own, dropped
// after the call: every vertex once, in blocks of vertex indices whose windows hold
// that block alone (first_vertex() == begin), FitSurface's bits, on the plain path (LHF
// d2 on fan rows, d4 on spans, LOP; with and without a locality order); elsewhere (two
// passes, normal pre-fit, noise mode) one block of the whole fits. Quantities evaluated
// block by block (what `curvature --local` does) equal ComputeDifferentials' bits. Each
// window is overwritten with NaNs after its block is read: a later read of it would change
// the results.
TEST(FitTest, FitSurfaceOnceInBlocksHandsOverFitSurfacesBits) {
  GeneratorOptions g;
  g.n = 40;
  const Mesh shuffled = testing_util::ShuffleVertices(GenerateBumpMesh(g), 7, nullptr);
  const LocalityRelabelling r = RelabelForLocality(shuffled).value();
  for (int variant = 0; variant < 7; ++variant) {
    const Topology topo = variant == 6 ? BuildTopology(r.mesh).value() : BuildTopology(r).value();
    const int nv = r.mesh.NumVertices();
    const FitOptions o = FitOnceVariant(variant);
    const bool plain = variant <= 2 || variant == 6;
    for (int threads : {1, 2}) {
      SCOPED_TRACE(::testing::Message() << "variant " << variant << " threads " << threads);
      const RunContext ctx(nullptr, threads);
      const auto want = FitSurface(r.mesh, topo, o, nullptr, {}, ctx).value();
      const Differentials want_d = ComputeDifferentials(*want, kAllQuantities, 1);
      const size_t ncoef = static_cast<size_t>(want->dims()) * want->num_coefficients();
      std::vector<LocalFrame> frames(nv);
      std::vector<double> coefficients(nv * ncoef);
      std::vector<VertexDiagnostics> diagnostics(nv);
      std::vector<int> seen(nv, 0);
      Differentials d = AllocateDifferentials(nv, kAllQuantities);
      std::mutex mu;
      std::vector<std::pair<int64_t, int64_t>> blocks;
      ASSERT_TRUE(FitSurfaceOnceInBlocks(
                      r.mesh, topo, o,
                      [&](const SurfaceFits& fits, int64_t begin, int64_t end) {
                        {
                          std::lock_guard<std::mutex> lock(mu);
                          blocks.emplace_back(begin, end);
                        }
                        ASSERT_EQ(fits.first_vertex(), begin);
                        ASSERT_EQ(fits.num_vertices(), end - begin);
                        for (int64_t v = begin; v < end; ++v) {
                          ++seen[v];
                          frames[v] = fits.frame(static_cast<int>(v));
                          std::memcpy(&coefficients[v * ncoef], fits.coefficients(static_cast<int>(v)), ncoef * 8);
                          diagnostics[v] = fits.diagnostics(static_cast<int>(v));
                        }
                        EvaluateDifferentials(fits, kAllQuantities, begin, end, &d);
                        // Poison the window: whatever reads it after the call gets NaNs.
                        for (int64_t v = begin; v < end; ++v) {
                          auto& fr = const_cast<LocalFrame&>(fits.frame(static_cast<int>(v)));
                          fr.origin.setConstant(std::nan("")), fr.normal.setConstant(std::nan(""));
                          double* c = const_cast<double*>(fits.coefficients(static_cast<int>(v)));
                          std::fill_n(c, ncoef, std::nan(""));
                        }
                      },
                      ctx)
                      .ok());
      if (plain) {
        EXPECT_GT(blocks.size(), 1u);
        for (const auto& [begin, end] : blocks) EXPECT_LE(end - begin, 512);
      } else {
        ASSERT_EQ(blocks.size(), 1u);
        EXPECT_EQ(blocks[0], std::make_pair(int64_t{0}, int64_t{nv}));
      }
      for (int v = 0; v < nv; ++v) {
        ASSERT_EQ(seen[v], 1) << "vertex " << v;
        ASSERT_EQ(0, std::memcmp(&frames[v], &want->frame(v), sizeof(LocalFrame))) << "vertex " << v;
        ASSERT_EQ(0, std::memcmp(&coefficients[v * ncoef], want->coefficients(v), ncoef * 8)) << "vertex " << v;
        const VertexDiagnostics &a = diagnostics[v], &b = want->diagnostics(v);
        ASSERT_EQ(a.points, b.points);
        ASSERT_EQ(a.degree_used, b.degree_used);
        ASSERT_EQ(a.rank, b.rank);
        ASSERT_EQ(a.flags, b.flags);
        ASSERT_EQ(0, std::memcmp(&a.condition, &b.condition, sizeof(float)));
        ASSERT_EQ(d.diagnostics[v].flags, want_d.diagnostics[v].flags);
      }
      const auto same = [](const auto& x, const auto& y) {
        return x.size() == y.size() && std::memcmp(x.data(), y.data(), x.size() * sizeof(double)) == 0;
      };
      EXPECT_TRUE(same(d.normals, want_d.normals));
      EXPECT_TRUE(same(d.mean, want_d.mean));
      EXPECT_TRUE(same(d.gaussian, want_d.gaussian));
      EXPECT_TRUE(same(d.k1, want_d.k1));
      EXPECT_TRUE(same(d.k2, want_d.k2));
      EXPECT_TRUE(same(d.dir1, want_d.dir1));
      EXPECT_TRUE(same(d.dir2, want_d.dir2));
      EXPECT_TRUE(same(d.tensor, want_d.tensor));
    }
  }
}

TEST(FitTest, RejectsBadOptionsNamingTheField) {
  FitOptions o;
  o.degree = 7;
  EXPECT_THAT(ValidateFitOptions(o).message(), HasSubstr("degree"));
  o = FitOptions();
  o.rings = 1.25;
  EXPECT_THAT(ValidateFitOptions(o).message(), HasSubstr("rings"));
  o = FitOptions();
  o.safeguard_angle_deg = 0;
  EXPECT_THAT(ValidateFitOptions(o).message(), HasSubstr("safeguard_angle_deg"));
  o = FitOptions();
  o.max_points = 5000;
  EXPECT_THAT(ValidateFitOptions(o).message(), HasSubstr("max_points"));
  o = FitOptions();
  o.cond_threshold[3] = 0;
  EXPECT_THAT(ValidateFitOptions(o).message(), HasSubstr("cond_threshold[3]"));
  EXPECT_EQ(ValidateFitOptions(o).code(), absl::StatusCode::kInvalidArgument);
  // Options that change results change the identity; automatic values equal explicit ones.
  FitOptions a, b;
  b.rings = a.StartRings();
  b.min_points_factor = a.MinPointsFactor();
  EXPECT_EQ(FitOptionsIdentity(a), FitOptionsIdentity(b));
  b.interpolate = false;
  EXPECT_NE(FitOptionsIdentity(a), FitOptionsIdentity(b));
  // Exact bits, not formatted text: %g makes these one string, they are two identities.
  FitOptions c, d;
  c.min_points_factor = 1.5;
  d.min_points_factor = 1.5000001;
  EXPECT_EQ(FitOptionsKey(c), FitOptionsKey(d));
  EXPECT_NE(FitOptionsIdentity(c), FitOptionsIdentity(d));
  d = c;
  d.weight_epsilon = 0.01 * (1 + 1e-12);
  EXPECT_NE(FitOptionsIdentity(c), FitOptionsIdentity(d));
}

TEST(FitTest, CancellationStopsTheFit) {
  const Mesh m = Torus(40);
  const Topology t = BuildTopology(m).value();
  CancellationToken token;
  token.Cancel();
  auto fits = FitSurface(m, t, FitOptions(), nullptr, {}, RunContext(&token));
  EXPECT_EQ(fits.status().code(), absl::StatusCode::kCancelled);
  CancellationToken expired(CancellationToken::Clock::now() - std::chrono::seconds(1));
  EXPECT_EQ(FitSurface(m, t, FitOptions(), nullptr, {}, RunContext(&expired)).status().code(),
            absl::StatusCode::kDeadlineExceeded);
}

// The slope refinement (degree 1's Hermite normals, plane_slopes.h, and degree 2's
// quadratic_hermite too) polls the
// RunContext: cancelled once the plain fit's last chunk is done, it runs none of its own
// (no progress after the cancellation, where the same run uncancelled reports the
// refinement's chunks), returns CANCELLED and streams no block; a token cancelled before
// the start or past its deadline stops it as the plain fit.
TEST(FitTest, SlopeRefinementIsCancellable) {
  const Mesh m = Torus(40);
  const Topology t = BuildTopology(m).value();
  FitOptions slopes, plane, quadratic;
  slopes.slope_refinement = 2;
  ASSERT_EQ(slopes.SlopePasses(), 2);
  plane.degree = 1;
  ASSERT_TRUE(plane.PlaneHermite());
  quadratic.quadratic_hermite = true;
  ASSERT_TRUE(quadratic.QuadraticHermite());
  for (const FitOptions& o : {slopes, plane, quadratic}) {
    SCOPED_TRACE(o.degree);
    for (const bool cancel : {false, true}) {
      CancellationToken token;
      bool fit_done = false;
      int after_fit = 0;  // progress reports after the fit phase's last one
      const RunContext ctx(&token, 1, [&](const Progress& p) {
        if (fit_done) {
          ++after_fit;
        } else if (p.phase == "fit" && p.done == p.total) {
          fit_done = true;
          if (cancel) token.Cancel();
        }
      });
      int blocks = 0;
      const auto fits = FitSurface(m, t, o, nullptr, {}, ctx, [&](const SurfaceFits&, int64_t, int64_t) { ++blocks; });
      EXPECT_TRUE(fit_done);
      if (cancel) {
        EXPECT_EQ(fits.status().code(), absl::StatusCode::kCancelled);
        EXPECT_EQ(after_fit, 0);
        EXPECT_EQ(blocks, 0);
      } else {
        ASSERT_TRUE(fits.ok()) << fits.status();
        EXPECT_GT(after_fit, 0);  // the refinement's chunks
        EXPECT_EQ(blocks, 1);
      }
    }
    CancellationToken token;
    token.Cancel();
    EXPECT_EQ(FitSurface(m, t, o, nullptr, {}, RunContext(&token)).status().code(), absl::StatusCode::kCancelled);
    CancellationToken expired(CancellationToken::Clock::now() - std::chrono::seconds(1));
    EXPECT_EQ(FitSurface(m, t, o, nullptr, {}, RunContext(&expired)).status().code(),
              absl::StatusCode::kDeadlineExceeded);
  }
}

TEST(FitTest, TwoPassRefitsInFittedFrames) {
  const Mesh m = Torus(16);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 4;
  o.jet_hermite = JetHermiteMode::kOff;  // the fits' own normals
  auto one = FitSurface(m, t, o).value();
  o.two_pass = true;
  auto two = FitSurface(m, t, o).value();
  // Second-pass frames are the first pass's fitted normals, not the averaged ones.
  const PointDifferentials p = DifferentialsFromJet(one->Jet(5));
  EXPECT_NEAR((two->frame(5).normal - p.normal).norm(), 0, 1e-14);
  EXPECT_GT((one->frame(5).normal - p.normal).norm(), 1e-6);
}

// Normal refinement (FitOptions::normal_degree): degree-2 fits in the frames of a
// degree-3 pre-fit keep its tangent plane, so their normals converge at ~3 instead of ~2,
// are several times more accurate than the same degree-2 fits without it (the CGAL-free
// reference: same stencils, same weights), and the curvatures keep their order. On a
// mesh perturbed along the normal by O(h^3) the pre-fit's gradient carries an O(h^2) noise
// term: the normals keep the data's order 2 and stay within 1.3x of the unrefined fit's.
TEST(FitTest, NormalRefinementGivesThirdOrderNormalsAtDegreeTwo) {
  auto torus = NamedSurface("torus").value();
  for (const double alpha : {0.0, 0.5}) {
    std::vector<double> h, refined, plain, h_refined, h_plain;
    for (int n : {16, 32, 64}) {
      GeneratorOptions g;
      g.n = n;
      const Mesh clean = GenerateTorusMesh(g);
      const Mesh m = alpha > 0 ? PerturbAlongNormals(clean, *torus, alpha, 3) : clean;
      const Topology t = BuildTopology(m).value();
      FitOptions o;
      ASSERT_EQ(o.NormalDegree(), 2);  // off by default (it costs a degree-3 fit)
      o.normal_degree = 3;
      ASSERT_EQ(o.NormalDegree(), 3);
      const auto fr = FitSurface(m, t, o).value();
      o.normal_degree = 2;
      const auto fp = FitSurface(m, t, o).value();
      const DifferentialErrors er = MeasureErrors(clean, *torus, ComputeDifferentials(*fr));
      const DifferentialErrors ep = MeasureErrors(clean, *torus, ComputeDifferentials(*fp));
      h.push_back(er.h);
      refined.push_back(er.normal.l2), plain.push_back(ep.normal.l2);
      h_refined.push_back(er.mean.l2), h_plain.push_back(ep.mean.l2);
      const double gain = alpha > 0 ? 1.3 : 0.5;
      EXPECT_LT(er.normal.l2, gain * ep.normal.l2) << n << " alpha " << alpha;
      EXPECT_LT(er.normal.linf, 1.2 * gain * ep.normal.linf) << n << " alpha " << alpha;
      EXPECT_LT(er.mean.l2, 1.1 * ep.mean.l2) << n << " alpha " << alpha;
      // The final fit keeps the pre-fit's tangent plane: its frame normal is its normal.
      EXPECT_NEAR((DifferentialsFromJet(fr->Jet(7)).normal - fr->frame(7).normal).norm(), 0, 1e-14);
    }
    EXPECT_GE(ConvergenceOrder(h, refined), alpha > 0 ? 2.0 : 2.7) << alpha;
    if (alpha == 0) EXPECT_LE(ConvergenceOrder(h, plain), 2.4);
    EXPECT_GE(ConvergenceOrder(h, h_refined), 1.6) << alpha;
  }
  FitOptions bad;
  bad.normal_degree = 1;
  EXPECT_THAT(ValidateFitOptions(bad).message(), HasSubstr("normal_degree"));
  FitOptions svd;  // the SVD comparator solves without it
  svd.normal_degree = 3;
  svd.solver = WlsSolver::kSVD;
  EXPECT_EQ(svd.NormalDegree(), 2);
}

// Hermite curvatures (FitOptions::hermite_hessian): on the irregular (jittered,
// random-diagonal) torus, a plain degree-2 fit's H and K are dominated by the quartic
// Taylor term (orders ~1.8 and ~1.4 at these resolutions); fitted to the points'
// directional second derivatives 4h/r^2 - g/r from heights and refined normals, in which
// it cancels, they are 4-7x more accurate at every level (measured: H 0.11-0.22x, K
// 0.21-0.27x the plain fit's) and keep at least the plain fit's orders. The option
// implies the degree-3 normal pre-fit and changes nothing at other degrees or with noise.
TEST(FitTest, HermiteHessianCancelsTheQuarticTermAtDegreeTwo) {
  auto torus = NamedSurface("torus").value();
  std::vector<double> h, herm_h, herm_k, plain_h, plain_k;
  for (int n : {16, 32, 64}) {
    GeneratorOptions g;
    g.n = n;
    const Mesh m = GenerateTorusMesh(g);
    const Topology t = BuildTopology(m).value();
    FitOptions o;
    o.hermite_hessian = true;
    ASSERT_TRUE(o.HermiteHessian());
    ASSERT_EQ(o.NormalDegree(), 3);
    const DifferentialErrors eh = MeasureErrors(m, *torus, ComputeDifferentials(*FitSurface(m, t, o).value()));
    const DifferentialErrors ep = MeasureErrors(m, *torus, ComputeDifferentials(*FitSurface(m, t, FitOptions()).value()));
    h.push_back(eh.h);
    herm_h.push_back(eh.mean.l2), herm_k.push_back(eh.gaussian.l2);
    plain_h.push_back(ep.mean.l2), plain_k.push_back(ep.gaussian.l2);
    EXPECT_LT(eh.mean.l2, 0.35 * ep.mean.l2) << n;
    EXPECT_LT(eh.gaussian.l2, 0.35 * ep.gaussian.l2) << n;
    EXPECT_LT(eh.mean.linf, 0.6 * ep.mean.linf) << n;
    EXPECT_LT(eh.gaussian.linf, 0.6 * ep.gaussian.linf) << n;
    EXPECT_LT(eh.normal.l2, 0.5 * ep.normal.l2) << n;  // the refinement's O(h^3) normals
  }
  EXPECT_GE(ConvergenceOrder(h, herm_h), 1.95);
  EXPECT_GE(ConvergenceOrder(h, herm_k), 1.45);
  EXPECT_LE(ConvergenceOrder(h, plain_h), 1.9);
  EXPECT_LE(ConvergenceOrder(h, plain_k), 1.5);

  FitOptions o;  // ignored away from degree 2 and with noise on
  o.hermite_hessian = true;
  o.degree = 3;
  EXPECT_FALSE(o.HermiteHessian());
  EXPECT_EQ(o.NormalDegree(), 3);
  FitOptions cubic;
  cubic.degree = 3;
  EXPECT_EQ(FitOptionsIdentity(o), FitOptionsIdentity(cubic));
  o.degree = 2;
  o.noise = NoiseMode::kOn;
  EXPECT_FALSE(o.HermiteHessian());
  EXPECT_EQ(o.NormalDegree(), 3);  // the noise mode's own cubic normal pre-fit (noise.h)
}


// Slope refinement (FitOptions::slope_refinement, one and two passes): normals from
// h - p.G/3 with the neighbours' degree-2 normals (the cubic term cancels) and Hermite
// Hessians in the refined frame, on the fit's own stencils. Errors against CGAL Jet_fitting_3 at degree 2 on the
// same stencils (Monge_via_jet_fitting(2, 2); CGAL is not linked into the tests: its
// errors below are `cgal_compare 2 2 torus,quadtorus,ellipsoid 16,32,64`'s, bench/README.md
// "Degree 2 from the neighbours' normals"): every norm at most 0.5x CGAL's (the largest
// 0.47x / 0.49x, the coarsest quad torus's normal Linf), and the orders of the refined
// quantities above CGAL's.
// Every vertex's refinement is independent of the batch it lands in (vector lanes of 8,
// stencils sorted by size within chunks) and of the threads: the slots in locality order
// and in vertex order (other batches, other records) and 1 or 2 threads give the same bits.
TEST(FitTest, SlopeRefinementIsIndependentOfOrderAndThreads) {
  GeneratorOptions g;
  g.n = 24;
  const Mesh m = GenerateNamedMesh("ellipsoid", g).value();
  const Topology t = BuildTopology(m).value();
  ASSERT_EQ(static_cast<int>(t.locality_order.size()), m.NumVertices());
  Topology plain_copy = t;  // slots = vertices
  plain_copy.locality_order.clear();
  const Topology& plain = plain_copy;
  for (const int passes : {1, 2}) {
    FitOptions o;
    o.slope_refinement = passes;
    const Differentials ref = ComputeDifferentials(*FitSurface(m, t, o, nullptr, {}, RunContext(nullptr, 1)).value());
    const Differentials unrefined = ComputeDifferentials(*FitSurface(m, t, FitOptions()).value());
    EXPECT_GT((ref.normals - unrefined.normals).norm(), 0) << passes;
    for (const Topology* topo : {&t, &plain})
      for (const int threads : {1, 2}) {
        const Differentials d =
            ComputeDifferentials(*FitSurface(m, *topo, o, nullptr, {}, RunContext(nullptr, threads)).value());
        EXPECT_EQ(d.normals, ref.normals) << passes << " " << threads;
        EXPECT_EQ(d.mean, ref.mean) << passes << " " << threads;
        EXPECT_EQ(d.gaussian, ref.gaussian) << passes << " " << threads;
      }
  }
}

// FitOptions::quadratic_hermite (slopes.h: the fit's own operator applied twice to
// h - p.G/3, the Hessian 0.7 of the second application's and 0.3 of the fit's): on the
// jittered torus (and a shuffled copy, the external mesher's order) every norm below 0.45x
// CGAL's (CGAL's errors as in the test below, the same meshes), orders above the plain fit's;
// off, the plain fit's normals and K stay above half of CGAL's. Results independent of the
// threads and of the slots' order.
TEST(FitTest, QuadraticHermiteBelowHalfOfCgalAtDegreeTwo) {
  const double cgal[3][6] = {{2.30e-02, 5.87e-02, 1.82e-01, 3.12e-01, 2.37e-01, 4.42e-01},
                             {4.60e-03, 1.21e-02, 4.92e-02, 1.23e-01, 9.06e-02, 1.96e-01},
                             {1.06e-03, 3.04e-03, 1.61e-02, 4.90e-02, 4.17e-02, 1.08e-01}};
  FitOptions o;
  o.quadratic_hermite = true;
  ASSERT_TRUE(o.QuadraticHermite());
  std::vector<double> h, err[6], plain_err[6];
  const int levels[3] = {16, 32, 64};
  for (int i = 0; i < 3; ++i) {
    GeneratorOptions g;
    g.n = levels[i];
    const Mesh base = GenerateNamedMesh("torus", g).value();
    auto surface = NamedSurface("torus").value();
    for (const bool shuffled : {false, true}) {
      const Mesh m = shuffled ? testing_util::ShuffleVertices(base, 13) : base;
      const Topology t = BuildTopology(m).value();
      const DifferentialErrors e = MeasureErrors(m, *surface, ComputeDifferentials(*FitSurface(m, t, o).value()));
      const DifferentialErrors p = MeasureErrors(m, *surface, ComputeDifferentials(*FitSurface(m, t, FitOptions()).value()));
      const double ours[6] = {e.normal.l2, e.normal.linf, e.mean.l2, e.mean.linf, e.gaussian.l2, e.gaussian.linf};
      const double plain[6] = {p.normal.l2, p.normal.linf, p.mean.l2, p.mean.linf, p.gaussian.l2, p.gaussian.linf};
      for (int k = 0; k < 6; ++k) {
        EXPECT_LT(ours[k], 0.45 * cgal[i][k]) << "n " << levels[i] << " norm " << k << " shuffled " << shuffled;
        if (!shuffled) err[k].push_back(ours[k]), plain_err[k].push_back(plain[k]);
      }
      if (!shuffled) h.push_back(e.h);
    }
    // Off: normals and K above half of CGAL's (0.5-0.8x).
    EXPECT_GT(plain_err[0].back(), 0.5 * cgal[i][0]);
    EXPECT_GT(plain_err[4].back(), 0.5 * cgal[i][4]);
  }
  // Orders (cgal_compare, L2 / Linf: normals 2.81 / 2.69, H 2.31 / 1.78, K 1.76 / 1.37, at most
  // 0.36x CGAL's; the plain fit 2.18 / 2.23, 1.81 / 1.29, 1.37 / 0.89; CGAL 2.23 / 2.14,
  // 1.76 / 1.34, 1.26 / 1.02).
  const double min_order[6] = {2.6, 2.6, 2.0, 1.6, 1.6, 1.3};
  for (int k = 0; k < 6; ++k) {
    EXPECT_GE(ConvergenceOrder(h, err[k]), min_order[k]) << "norm " << k;
    EXPECT_GT(ConvergenceOrder(h, err[k]), ConvergenceOrder(h, plain_err[k])) << "norm " << k;
  }
  // Independent of the threads and of the slots (locality order or vertex order).
  GeneratorOptions g;
  g.n = 24;
  const Mesh m = GenerateNamedMesh("ellipsoid", g).value();
  const Topology t = BuildTopology(m).value();
  Topology plain_copy = t;
  plain_copy.locality_order.clear();
  const Differentials ref = ComputeDifferentials(*FitSurface(m, t, o, nullptr, {}, RunContext(nullptr, 1)).value());
  for (const Topology* topo : {&t, static_cast<const Topology*>(&plain_copy)})
    for (const int threads : {1, 2}) {
      const Differentials d = ComputeDifferentials(*FitSurface(m, *topo, o, nullptr, {}, RunContext(nullptr, threads)).value());
      EXPECT_EQ(d.normals, ref.normals) << threads;
      EXPECT_EQ(d.mean, ref.mean) << threads;
      EXPECT_EQ(d.gaussian, ref.gaussian) << threads;
    }
  // Ignored where it does not apply; a key of its own where it does.
  FitOptions cubic = o;
  cubic.degree = 3;
  EXPECT_FALSE(cubic.QuadraticHermite());
  EXPECT_EQ(FitOptionsIdentity(cubic), FitOptionsIdentity([] { FitOptions c; c.degree = 3; return c; }()));
  EXPECT_NE(FitOptionsIdentity(o), FitOptionsIdentity(FitOptions()));
  EXPECT_NE(FitOptionsKey(o), FitOptionsKey(FitOptions()));
  FitOptions both = o;
  both.slope_refinement = 1;  // slope_refinement's passes instead
  EXPECT_FALSE(both.QuadraticHermite());
  both = o;
  both.noise = NoiseMode::kOn;
  EXPECT_FALSE(both.QuadraticHermite());
}

TEST(FitTest, SlopeRefinementHalvesCgalsErrorsAtDegreeTwo) {
  struct Case {
    const char* mesh;
    int n;
    double cgal[6];  // normal L2, Linf, H L2, Linf, K L2, Linf (errors.h)
  };
  const Case cases[] = {
      {"torus", 16, {2.30e-02, 5.87e-02, 1.82e-01, 3.12e-01, 2.37e-01, 4.42e-01}},
      {"torus", 32, {4.60e-03, 1.21e-02, 4.92e-02, 1.23e-01, 9.06e-02, 1.96e-01}},
      {"torus", 64, {1.06e-03, 3.04e-03, 1.61e-02, 4.90e-02, 4.17e-02, 1.08e-01}},
      {"quadtorus", 16, {1.28e-02, 3.18e-02, 1.84e-01, 2.15e-01, 1.73e-01, 2.57e-01}},
      {"quadtorus", 32, {2.11e-03, 5.99e-03, 4.43e-02, 6.47e-02, 5.09e-02, 8.46e-02}},
      {"quadtorus", 64, {4.44e-04, 1.18e-03, 1.16e-02, 2.50e-02, 1.97e-02, 4.36e-02}},
      {"ellipsoid", 16, {4.98e-03, 1.29e-02, 1.92e-02, 6.62e-02, 3.67e-02, 1.02e-01}},
      {"ellipsoid", 32, {1.27e-03, 3.42e-03, 8.38e-03, 3.06e-02, 1.58e-02, 4.58e-02}},
  };
  for (const int passes : {1, 2}) {
    std::map<std::string, std::vector<std::array<double, 4>>> levels;  // h, normal, H, K (L2)
    for (const Case& c : cases) {
      GeneratorOptions g;
      g.n = c.n;
      const Mesh m = GenerateNamedMesh(c.mesh, g).value();
      const Topology t = BuildTopology(m).value();
      auto surface = NamedSurface(c.mesh).value();
      FitOptions o;
      o.slope_refinement = passes;
      ASSERT_EQ(o.SlopePasses(), passes);
      const auto fits = FitSurface(m, t, o).value();
      const DifferentialErrors e = MeasureErrors(m, *surface, ComputeDifferentials(*fits));
      const double ours[6] = {e.normal.l2, e.normal.linf, e.mean.l2, e.mean.linf, e.gaussian.l2, e.gaussian.linf};
      for (int k = 0; k < 6; ++k) {
        EXPECT_LT(ours[k], 0.5 * c.cgal[k]) << c.mesh << " n " << c.n << " norm " << k << " passes " << passes;
      }
      levels[c.mesh].push_back({e.h, e.normal.l2, e.mean.l2, e.gaussian.l2});
      // The refined frame is the fit's tangent plane: its normal is the reported one.
      EXPECT_NEAR((DifferentialsFromJet(fits->Jet(5)).normal - fits->frame(5).normal).norm(), 0, 1e-14);
      if (c.n == 16 && passes == 1) {  // streamed fits are reported once refined, as one block
        std::vector<std::pair<int64_t, int64_t>> blocks;
        const auto streamed = FitSurface(m, t, o, nullptr, {}, {}, [&](const SurfaceFits& f, int64_t b, int64_t e) {
                                blocks.emplace_back(b, e);
                                EXPECT_EQ(f.frame(3).normal, fits->frame(3).normal);
                              }).value();
        ASSERT_EQ(blocks.size(), 1u);
        EXPECT_EQ(blocks[0], std::make_pair(int64_t{0}, int64_t{m.NumVertices()}));
        EXPECT_EQ(streamed->frame(3).normal, fits->frame(3).normal);
      }
    }
    for (const char* mesh : {"torus", "quadtorus"}) {
      std::vector<double> h, nrm, mean, gauss;
      for (const auto& l : levels[mesh]) h.push_back(l[0]), nrm.push_back(l[1]), mean.push_back(l[2]), gauss.push_back(l[3]);
      // Measured (one pass): normals 2.92 / 3.10, H 2.74 / 2.86, K 1.96 / 2.05 (CGAL
      // 2.23-2.43, 1.76-2.00, 1.26-1.57).
      EXPECT_GE(ConvergenceOrder(h, nrm), 2.8) << mesh << " passes " << passes;
      EXPECT_GE(ConvergenceOrder(h, mean), 2.5) << mesh << " passes " << passes;
      EXPECT_GE(ConvergenceOrder(h, gauss), 1.8) << mesh << " passes " << passes;
    }
  }

  // Off by default; ignored away from interpolating degree-2 LHF fits, and where the
  // degree-3 pre-fit is asked for: the other degrees' results and keys are unchanged.
  EXPECT_EQ(FitOptions().SlopePasses(), 0);
  FitOptions o;
  o.slope_refinement = 1;
  o.degree = 3;
  EXPECT_EQ(o.SlopePasses(), 0);
  FitOptions cubic;
  cubic.degree = 3;
  EXPECT_EQ(FitOptionsIdentity(o), FitOptionsIdentity(cubic));
  o.degree = 2;
  EXPECT_NE(FitOptionsIdentity(o), FitOptionsIdentity(FitOptions()));
  o.noise = NoiseMode::kOn;
  EXPECT_EQ(o.SlopePasses(), 0);
  o.noise = NoiseMode::kOff;
  o.hermite_hessian = true;
  EXPECT_EQ(o.SlopePasses(), 0);
  o.hermite_hessian = false;
  o.interpolate = false;
  EXPECT_EQ(o.SlopePasses(), 0);
  o.slope_refinement = 4;
  EXPECT_THAT(ValidateFitOptions(o).message(), HasSubstr("slope_refinement"));
}

}  // namespace
}  // namespace geomfit
