// GFD surface operators (§5.1): Laplace-Beltrami convergence (order >= d - 1 in L-inf)
// on sphere, torus and ellipsoid; discrete identities (L 1 = 0, L x = -2 H n, tr Hess =
// L, div x = 2, gradients tangent, div grad = L to truncation order); pattern reuse.
#include <cmath>
#include <cstdlib>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/mesh/topology.h"
#include "core/operators/operators.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"

namespace geomfit {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;
using Eigen::VectorXd;

// An ambient function with its gradient and Hessian, so that the exact Laplace-Beltrami
// on a surface is tr(H) - n^T H n - 2 H_mean (n . grad).
struct AmbientFn {
  std::string name;
  std::function<double(const Vector3d&)> f;
  std::function<Vector3d(const Vector3d&)> grad;
  std::function<Matrix3d(const Vector3d&)> hess;
};

std::vector<AmbientFn> Functions() {
  return {
      {"x", [](const Vector3d& p) { return p.x(); }, [](const Vector3d&) { return Vector3d(1, 0, 0); },
       [](const Vector3d&) { return Matrix3d::Zero().eval(); }},
      {"yz", [](const Vector3d& p) { return p.y() * p.z(); },
       [](const Vector3d& p) { return Vector3d(0, p.z(), p.y()); },
       [](const Vector3d&) {
         Matrix3d h = Matrix3d::Zero();
         h(1, 2) = h(2, 1) = 1;
         return h;
       }},
      {"expx", [](const Vector3d& p) { return std::exp(p.x()); },
       [](const Vector3d& p) { return Vector3d(std::exp(p.x()), 0, 0); },
       [](const Vector3d& p) {
         Matrix3d h = Matrix3d::Zero();
         h(0, 0) = std::exp(p.x());
         return h;
       }},
  };
}

double ExactLaplaceBeltrami(const AmbientFn& fn, const ExactDifferentials& e, const Vector3d& p) {
  const Matrix3d H = fn.hess(p);
  return H.trace() - e.normal.dot(H * e.normal) - 2 * e.mean * e.normal.dot(fn.grad(p));
}

struct Fitted {
  Mesh mesh;
  Topology topo;
  std::shared_ptr<const SurfaceFits> fits;
};

Fitted Fit(const std::string& surface, int n, int degree) {
  GeneratorOptions g;
  g.n = n;
  Fitted r;
  r.mesh = GenerateNamedMesh(surface, g).value();
  r.topo = BuildTopology(r.mesh).value();
  FitOptions o;
  o.degree = degree;
  r.fits = FitForOperators(r.mesh, r.topo, o, nullptr, RunContext()).value();
  return r;
}

VectorXd Sample(const Mesh& m, const std::function<double(const Vector3d&)>& f) {
  VectorXd v(m.NumVertices());
  for (int i = 0; i < m.NumVertices(); ++i) v(i) = f(m.positions.row(i).transpose());
  return v;
}

// L-inf on randomly jittered meshes is set by one worst vertex per mesh, so measured
// slopes scatter by up to ~0.35 around d - 1 over these (pre-asymptotic) levels, as in
// the fitting convergence tests (which allow 0.4).
constexpr double kOrderSlack = 0.4;

struct Case {
  std::string surface;
  std::vector<int> levels;
};

class LaplaceBeltramiOrder : public testing::TestWithParam<Case> {};

TEST_P(LaplaceBeltramiOrder, LinfOrderAtLeastDegreeMinusOne) {
  const Case& c = GetParam();
  auto exact = NamedSurface(c.surface).value();
  const std::vector<AmbientFn> fns = Functions();
  for (int degree = 2; degree <= 6; ++degree) {
    std::vector<double> h;
    std::vector<std::vector<double>> err(fns.size());
    for (int n : c.levels) {
      const Fitted f = Fit(c.surface, n, degree);
      const SparseMatrix L = LaplaceBeltramiMatrix(*f.fits).value();
      h.push_back(AverageEdgeLength(f.mesh));
      int downgraded = 0;
      for (const VertexDiagnostics& d : f.fits->diagnostics()) downgraded += d.degree_used < degree;
      if (getenv("GF_VERBOSE")) std::printf("  n=%d d=%d downgraded %d\n", n, degree, downgraded);
      for (size_t q = 0; q < fns.size(); ++q) {
        const VectorXd Lf = L * Sample(f.mesh, fns[q].f);
        double e = 0;
        for (int i = 0; i < f.mesh.NumVertices(); ++i) {
          const Vector3d p = f.mesh.positions.row(i).transpose();
          e = std::max(e, std::abs(Lf(i) - ExactLaplaceBeltrami(fns[q], exact->At(p), p)));
        }
        err[q].push_back(e);
        if (getenv("GF_VERBOSE")) std::printf("    %s %.3e\n", fns[q].name.c_str(), e);
      }
    }
    for (size_t q = 0; q < fns.size(); ++q) {
      const double order = ConvergenceOrder(h, err[q]);
      std::printf("%s d=%d LB(%s) Linf errors %.2e .. %.2e order %.2f\n", c.surface.c_str(), degree,
                  fns[q].name.c_str(), err[q].front(), err[q].back(), order);
      EXPECT_GE(order, degree - 1 - kOrderSlack) << c.surface << " degree " << degree << " " << fns[q].name;
    }
  }
}

INSTANTIATE_TEST_SUITE_P(Surfaces, LaplaceBeltramiOrder,
                         testing::Values(Case{"sphere", {8, 12, 17, 24}}, Case{"torus", {16, 22, 32, 45}},
                                         Case{"ellipsoid", {8, 12, 17, 24}}),
                         [](const testing::TestParamInfo<Case>& i) { return i.param.surface; });

// Identities that hold exactly for the discrete operators (to roundoff): stencil rows
// of derivatives sum to zero, the position's fit is the surface's own fit, and the
// Hessian's trace is the Laplace-Beltrami operator.
TEST(OperatorIdentities, ExactDiscreteIdentities) {
  for (const std::string surface : {"sphere", "torus", "ellipsoid"}) {
    for (int degree = 1; degree <= 6; ++degree) {
      const Fitted f = Fit(surface, surface == "torus" ? 12 : 8, degree);
      const int nv = f.mesh.NumVertices();
      const SparseMatrix L = LaplaceBeltramiMatrix(*f.fits).value();
      const SparseMatrix G = GradientMatrix(*f.fits).value();
      const SparseMatrix D = DivergenceMatrix(*f.fits).value();
      const SparseMatrix Hs = HessianMatrix(*f.fits).value();
      const SparseMatrix W = WeingartenMatrix(*f.fits).value();
      ASSERT_EQ(L.rows(), nv);
      ASSERT_EQ(G.rows(), 3 * nv);
      ASSERT_EQ(D.cols(), 3 * nv);
      ASSERT_EQ(Hs.rows(), 9 * nv);
      const double scale = L.cwiseAbs().sum() / nv;  // ~ 1/h^2 per row

      EXPECT_LE((L * VectorXd::Ones(nv)).lpNorm<Eigen::Infinity>(), 1e-10 * scale) << surface << degree;
      EXPECT_LE((G * VectorXd::Ones(nv)).lpNorm<Eigen::Infinity>(), 1e-10 * (1 + scale)) << surface << degree;

      VectorXd x(3 * nv);  // positions interleaved (x0, y0, z0, x1, ...)
      for (int i = 0; i < nv; ++i) x.segment<3>(3 * i) = f.mesh.positions.row(i).transpose();
      const VectorXd divx = D * x;
      for (int i = 0; i < nv; ++i) ASSERT_NEAR(divx(i), 2.0, 1e-10) << surface << degree << " vertex " << i;

      const VectorXd phi = Sample(f.mesh, [](const Vector3d& p) { return std::exp(p.x()) * p.y() + p.z(); });
      const VectorXd Lphi = L * phi, Gphi = G * phi, Hphi = Hs * phi;
      const Eigen::MatrixXd Lx = L * Eigen::MatrixXd(f.mesh.positions);
      for (int i = 0; i < nv; ++i) {
        const HeightGeometry g = HeightGeometryAt(*f.fits, i);
        // L x = -2 H n, with the fit's own H and normal (the mean-curvature vector).
        for (int c = 0; c < 3; ++c) {
          ASSERT_NEAR(Lx(i, c), -2 * g.mean * g.normal(c), 1e-9 * (1 + std::abs(g.mean))) << surface << degree << " " << i;
        }
        ASSERT_NEAR(g.normal.dot(Gphi.segment<3>(3 * i)), 0, 1e-10 * (1 + Gphi.segment<3>(3 * i).norm()));
        ASSERT_NEAR(Hphi(9 * i) + Hphi(9 * i + 4) + Hphi(9 * i + 8), Lphi(i), 1e-9 * (1 + std::abs(Lphi(i))));
        ASSERT_NEAR(Hphi(9 * i + 1), Hphi(9 * i + 3), 1e-9 * (1 + std::abs(Hphi(9 * i + 1))));  // symmetric
        const Matrix3d Wi = W.block(3 * i, 3 * i, 3, 3);
        ASSERT_NEAR(Wi.trace(), 2 * g.mean, 1e-10 * (1 + std::abs(g.mean)));
        ASSERT_LT((Wi * g.normal).norm(), 1e-10 * (1 + std::abs(g.mean)));
      }
    }
  }
}

// On the unit sphere the Weingarten map is the tangential projector, and the text's
// tangential divergence of the position vanishes (div x = 2, 2 H n . x = 2).
TEST(OperatorIdentities, SphereWeingartenAndTangentialDivergence) {
  const Fitted f = Fit("sphere", 16, 4);
  const int nv = f.mesh.NumVertices();
  const SparseMatrix W = WeingartenMatrix(*f.fits).value();
  const SparseMatrix Dt = DivergenceMatrix(*f.fits, /*tangential=*/true).value();
  VectorXd x(3 * nv);
  for (int i = 0; i < nv; ++i) x.segment<3>(3 * i) = f.mesh.positions.row(i).transpose();
  const VectorXd dtx = Dt * x;
  double werr = 0;
  for (int i = 0; i < nv; ++i) {
    const Vector3d n = f.mesh.positions.row(i).transpose();
    const Matrix3d T = Matrix3d::Identity() - n * n.transpose();
    werr = std::max(werr, (Matrix3d(W.block(3 * i, 3 * i, 3, 3)) - T).cwiseAbs().maxCoeff());
  }
  std::printf("sphere n=16 d=4: |W - T|inf %.2e, |div_T x|inf %.2e\n", werr, dtx.lpNorm<Eigen::Infinity>());
  EXPECT_LT(werr, 2e-3);
  EXPECT_LT(dtx.lpNorm<Eigen::Infinity>(), 2e-3);
}

// div grad = Laplace-Beltrami to truncation order, and the gradient converges to the
// exact tangential gradient at order >= d.
TEST(OperatorIdentities, DivergenceOfGradientConvergesToLaplaceBeltrami) {
  auto exact = NamedSurface("ellipsoid").value();
  const AmbientFn fn = Functions()[2];
  for (int degree : {3, 4, 5}) {
    std::vector<double> h, div_err, grad_err;
    for (int n : {8, 11, 16, 22}) {
      const Fitted f = Fit("ellipsoid", n, degree);
      const SparseMatrix L = LaplaceBeltramiMatrix(*f.fits).value();
      const SparseMatrix G = GradientMatrix(*f.fits).value();
      const SparseMatrix D = DivergenceMatrix(*f.fits).value();
      const VectorXd phi = Sample(f.mesh, fn.f);
      const VectorXd Gphi = G * phi;
      h.push_back(AverageEdgeLength(f.mesh));
      div_err.push_back((D * Gphi - L * phi).lpNorm<Eigen::Infinity>());
      double ge = 0;
      for (int i = 0; i < f.mesh.NumVertices(); ++i) {
        const Vector3d p = f.mesh.positions.row(i).transpose(), nrm = exact->At(p).normal;
        const Vector3d g = fn.grad(p) - nrm.dot(fn.grad(p)) * nrm;
        ge = std::max(ge, (Gphi.segment<3>(3 * i) - g).norm());
      }
      grad_err.push_back(ge);
    }
    const double div_order = ConvergenceOrder(h, div_err), grad_order = ConvergenceOrder(h, grad_err);
    std::printf("ellipsoid d=%d |DG - L|inf %.2e .. %.2e order %.2f; grad err %.2e .. %.2e order %.2f\n", degree,
                div_err.front(), div_err.back(), div_order, grad_err.front(), grad_err.back(), grad_order);
    EXPECT_GE(div_order, degree - 2) << degree;
    EXPECT_GE(grad_order, degree - 0.5) << degree;
  }
}

// The pattern depends on topology only: refilling the same matrix for a moved mesh keeps
// its structure (arrays and sizes) and gives the values of a fresh assembly.
TEST(OperatorAssembler, RefillKeepsPatternAcrossRevisions) {
  Fitted f = Fit("torus", 12, 4);
  FitOptions o;
  o.degree = 4;
  const auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(f.topo, f.mesh, RingSpecFor(o)));
  const OperatorAssembler a(nb);
  auto fits0 = FitForOperators(f.mesh, f.topo, o, nb, RunContext()).value();
  SparseMatrix L = a.Pattern(OperatorKind::kLaplaceBeltrami);
  ASSERT_TRUE(a.Assemble(OperatorKind::kLaplaceBeltrami, *fits0, &L).ok());
  const int* outer = L.outerIndexPtr();
  const int* inner = L.innerIndexPtr();
  const Eigen::Index nnz = L.nonZeros();
  EXPECT_EQ(nnz, static_cast<Eigen::Index>(nb->indices.size()));

  Mesh moved = f.mesh;
  moved.positions *= 1.1;
  moved.positions.col(2) *= 0.9;
  auto fits1 = FitForOperators(moved, f.topo, o, nb, RunContext()).value();
  ASSERT_TRUE(a.Assemble(OperatorKind::kLaplaceBeltrami, *fits1, &L).ok());
  EXPECT_EQ(L.outerIndexPtr(), outer);
  EXPECT_EQ(L.innerIndexPtr(), inner);
  EXPECT_EQ(L.nonZeros(), nnz);
  const SparseMatrix fresh = LaplaceBeltramiMatrix(*fits1).value();
  EXPECT_EQ((L - fresh).norm(), 0.0);
  EXPECT_GT((L - a.Assemble(OperatorKind::kLaplaceBeltrami, *fits0).value()).norm(), 1e-3);
  for (OperatorKind k : {OperatorKind::kGradient, OperatorKind::kDivergence, OperatorKind::kTangentialDivergence,
                         OperatorKind::kHessian, OperatorKind::kWeingarten}) {
    SparseMatrix m = a.Pattern(k);
    ASSERT_TRUE(a.Assemble(k, *fits1, &m).ok()) << OperatorKindName(k);
    EXPECT_TRUE(m.isCompressed());
  }
}

TEST(OperatorAssembler, RejectsUnsuitableFitsAndStopsWhenCancelled) {
  Fitted f = Fit("sphere", 8, 3);
  FitOptions o;
  o.degree = 3;
  auto plain = FitSurface(f.mesh, f.topo, o).value();
  EXPECT_EQ(LaplaceBeltramiMatrix(*plain).status().code(), absl::StatusCode::kFailedPrecondition);
  FitRequest r;
  r.stencils = true;
  r.stencil_order = 1;
  auto first_only = FitSurface(f.mesh, f.topo, o, nullptr, r).value();
  EXPECT_EQ(LaplaceBeltramiMatrix(*first_only).status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(first_only->stencil_rows(), 3);
  o.method = FitMethod::kLOP;
  EXPECT_EQ(FitForOperators(f.mesh, f.topo, o, nullptr, RunContext()).status().code(),
            absl::StatusCode::kInvalidArgument);
  FitRequest with_stencils;
  with_stencils.stencils = true;
  auto lop = FitSurface(f.mesh, f.topo, o, nullptr, with_stencils).value();
  EXPECT_EQ(GradientMatrix(*lop).status().code(), absl::StatusCode::kFailedPrecondition);

  Fitted other = Fit("sphere", 9, 3);
  const OperatorAssembler a(std::make_shared<Neighborhoods>(other.fits->neighborhoods()));
  EXPECT_EQ(a.Assemble(OperatorKind::kGradient, *f.fits).status().code(), absl::StatusCode::kInvalidArgument);

  CancellationToken token;
  token.Cancel();
  EXPECT_EQ(LaplaceBeltramiMatrix(*f.fits, RunContext(&token)).status().code(), absl::StatusCode::kCancelled);
}

}  // namespace
}  // namespace geomfit
