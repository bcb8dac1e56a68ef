// DifferentialsFromJet (Table 3.1, 3.2.7-3.2.10) on exact jets of analytic surfaces, in
// a deliberately non-orthogonal parametrization.
#include <cmath>
#include <cstring>

#include <gtest/gtest.h>

#include "core/quantities/differentials.h"
#include "core/mesh/topology.h"
#include "core/surfaces/analytic.h"

namespace geomfit {
namespace {

// Torus x(u, v) with u = s + 0.3 t, v = t - 0.2 s (sheared parameters).
SurfaceJet ShearedTorusJet(double s, double t, double R, double r) {
  const double a = 0.3, b = -0.2;
  const double u = s + a * t, v = t + b * s;
  const double cu = std::cos(u), su = std::sin(u), cv = std::cos(v), sv = std::sin(v);
  const Eigen::Vector3d X(((R + r * cv) * cu), (R + r * cv) * su, r * sv);
  const Eigen::Vector3d Xu(-(R + r * cv) * su, (R + r * cv) * cu, 0);
  const Eigen::Vector3d Xv(-r * sv * cu, -r * sv * su, r * cv);
  const Eigen::Vector3d Xuu(-(R + r * cv) * cu, -(R + r * cv) * su, 0);
  const Eigen::Vector3d Xuv(r * sv * su, -r * sv * cu, 0);
  const Eigen::Vector3d Xvv(-r * cv * cu, -r * cv * su, -r * sv);
  // Chain rule: d/ds = Xu + b Xv, d/dt = a Xu + Xv.
  SurfaceJet jet;
  jet.x = X;
  jet.J.col(0) = Xu + b * Xv;
  jet.J.col(1) = a * Xu + Xv;
  jet.xuu = Xuu + 2 * b * Xuv + b * b * Xvv;
  jet.xuv = a * Xuu + (1 + a * b) * Xuv + b * Xvv;
  jet.xvv = a * a * Xuu + 2 * a * Xuv + Xvv;
  return jet;
}

TEST(DifferentialsFromJetTest, TorusInShearedParameters) {
  auto torus = MakeTorus(1.0, 0.3);
  for (double s : {0.0, 0.7, 2.1, 4.0})
    for (double t : {0.0, 1.3, 2.9, 5.5}) {
      const SurfaceJet jet = ShearedTorusJet(s, t, 1.0, 0.3);
      const PointDifferentials p = DifferentialsFromJet(jet);
      const ExactDifferentials e = torus->At(jet.x);
      EXPECT_NEAR((p.normal - e.normal).norm(), 0, 1e-13);
      EXPECT_NEAR(p.mean, e.mean, 1e-12);
      EXPECT_NEAR(p.gaussian, e.gaussian, 1e-12);
      EXPECT_NEAR(p.k1, e.k1, 1e-12);
      EXPECT_NEAR(p.k2, e.k2, 1e-12);
      EXPECT_NEAR(p.e1.cross(e.e1).norm(), 0, 1e-12);
      EXPECT_NEAR(p.e2.cross(e.e2).norm(), 0, 1e-12);
      // (e1, e2, n) right-handed and orthonormal; C = k1 e1 e1^T + k2 e2 e2^T.
      EXPECT_NEAR(p.e1.cross(p.e2).dot(p.normal), 1, 1e-13);
      EXPECT_NEAR((p.tensor * p.e1 - p.k1 * p.e1).norm(), 0, 1e-12);
      EXPECT_NEAR((p.tensor * p.normal).norm(), 0, 1e-12);
      EXPECT_NEAR(p.tensor.trace(), 2 * p.mean, 1e-12);
    }
}

TEST(DifferentialsFromJetTest, SphereHasPositiveCurvatureWithOutwardNormal) {
  // Sphere of radius 2 by longitude/latitude near the equator.
  const double R = 2, u = 0.4, v = 0.3;
  SurfaceJet jet;
  const Eigen::Vector3d n(std::cos(v) * std::cos(u), std::cos(v) * std::sin(u), std::sin(v));
  jet.x = R * n;
  jet.J.col(0) = R * Eigen::Vector3d(-std::cos(v) * std::sin(u), std::cos(v) * std::cos(u), 0);
  jet.J.col(1) = R * Eigen::Vector3d(-std::sin(v) * std::cos(u), -std::sin(v) * std::sin(u), std::cos(v));
  jet.xuu = R * Eigen::Vector3d(-std::cos(v) * std::cos(u), -std::cos(v) * std::sin(u), 0);
  jet.xuv = R * Eigen::Vector3d(std::sin(v) * std::sin(u), -std::sin(v) * std::cos(u), 0);
  jet.xvv = -R * n;
  const PointDifferentials p = DifferentialsFromJet(jet);
  EXPECT_NEAR((p.normal - n).norm(), 0, 1e-14);
  EXPECT_NEAR(p.mean, 0.5, 1e-14);
  EXPECT_NEAR(p.gaussian, 0.25, 1e-14);
  EXPECT_NEAR(p.k1, 0.5, 1e-14);
  EXPECT_NEAR(p.k2, 0.5, 1e-14);
}

// ComputeDifferentials evaluates height-function fits several vertices at a time: every
// quantity must be DifferentialsFromJet(Jet(v))'s bit for bit, on curved fits, on
// degree-1 fits (equal principal curvatures: the directions are the QR's) and on
// local-parametrization fits (one at a time), with a vertex count that leaves a partial
// group, in every entry point.
TEST(ComputeDifferentialsTest, EqualsDifferentialsFromJetBitForBit) {
  auto same = [](const double* a, const double* b, int n) { return std::memcmp(a, b, 8 * n) == 0; };
  GeneratorOptions g;
  g.n = 13;
  g.jitter = 0.3;
  const Mesh mesh = GenerateTorusMesh(g);  // 507 vertices: 63 groups of 8 and 3 more
  const Topology topo = BuildTopology(mesh).value();
  for (FitMethod method : {FitMethod::kLHF, FitMethod::kLOP})
    for (int degree : {1, 2, 3}) {
      FitOptions o;
      o.method = method;
      o.degree = degree;
      const auto fits = FitSurface(mesh, topo, o).value();
      const Differentials a = ComputeDifferentials(*fits, kAllQuantities, 2);
      const Differentials b = ComputeDifferentials(*fits, kAllQuantities, RunContext(nullptr, 1)).value();
      Differentials c = AllocateDifferentials(fits->num_vertices(), kAllQuantities);
      EvaluateDifferentials(*fits, kAllQuantities, 0, 100, &c);
      EvaluateDifferentials(*fits, kAllQuantities, 100, fits->num_vertices(), &c);
      const Differentials& cc = c;
      int checked = 0;
      for (const Differentials* d : {&a, &b, &cc})
        for (int v = 0; v < fits->num_vertices(); ++v) {
          ASSERT_GE(fits->diagnostics(v).degree_used, 1);
          const PointDifferentials p = DifferentialsFromJet(fits->Jet(v));
          SCOPED_TRACE(::testing::Message() << "degree " << degree << " vertex " << v);
          EXPECT_TRUE(same(d->normals.row(v).data(), p.normal.data(), 3));
          EXPECT_TRUE(same(&d->mean(v), &p.mean, 1));
          EXPECT_TRUE(same(&d->gaussian(v), &p.gaussian, 1));
          EXPECT_TRUE(same(&d->k1(v), &p.k1, 1));
          EXPECT_TRUE(same(&d->k2(v), &p.k2, 1));
          EXPECT_TRUE(same(d->dir1.row(v).data(), p.e1.data(), 3));
          EXPECT_TRUE(same(d->dir2.row(v).data(), p.e2.data(), 3));
          EXPECT_TRUE(same(d->tensor.row(v).data(), p.tensor.data(), 9));
          if (degree == 1) {
            EXPECT_EQ(p.k1, p.k2);  // the equal-curvature branch ran
          } else if (degree == 2 && v % 50 == 0) {
            EXPECT_NE(p.k1, p.k2);
          }
          ++checked;
        }
      EXPECT_EQ(checked, 3 * 507);
    }
}

}  // namespace
}  // namespace geomfit
