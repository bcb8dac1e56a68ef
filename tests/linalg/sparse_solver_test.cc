// Sparse solvers: every kind solves a nonsymmetric system of the flows' shape, direct
// solvers analyse a fixed pattern once (UMFPACK with METIS ordering too), and options
// are validated.
#include <gtest/gtest.h>

#include <cstdio>

#include "core/linalg/sparse_solver.h"
#include "core/util/cancel.h"
#include "core/util/run_context.h"

namespace geomfit {
namespace {

using Matrix = SparseSolver::Matrix;

// I - c K with K a nonsymmetric 2D 5-point Laplacian-like stencil (eigenvalues < 0).
Matrix System(int m, double c) {
  std::vector<Eigen::Triplet<double>> t;
  auto id = [&](int i, int j) { return ((j + m) % m) * m + (i + m) % m; };
  for (int j = 0; j < m; ++j)
    for (int i = 0; i < m; ++i) {
      const int r = id(i, j);
      t.emplace_back(r, r, 1 + 4 * c);
      t.emplace_back(r, id(i + 1, j), -1.2 * c);
      t.emplace_back(r, id(i - 1, j), -0.8 * c);
      t.emplace_back(r, id(i, j + 1), -c);
      t.emplace_back(r, id(i, j - 1), -c);
    }
  Matrix A(m * m, m * m);
  A.setFromTriplets(t.begin(), t.end());
  return A;
}

TEST(SparseSolver, EveryKindSolvesAndDirectOnesAnalyseOnce) {
  const Eigen::VectorXd x_true = Eigen::VectorXd::LinSpaced(400, -1, 1);
  for (SolverKind k : {SolverKind::kAuto, SolverKind::kSparseLU, SolverKind::kUmfpack, SolverKind::kKlu,
                       SolverKind::kBiCGSTAB}) {
    for (Preconditioner p : {Preconditioner::kDiagonal, Preconditioner::kIlut, Preconditioner::kAmg,
                             Preconditioner::kAuto}) {
      SolverOptions o;
      o.kind = k;
      o.preconditioner = p;
      o.amg.coarse_size = 40;  // several levels on 400 rows
      if (!SolverAvailable(k)) {
        EXPECT_EQ(ValidateSolverOptions(o).code(), absl::StatusCode::kInvalidArgument);
        continue;
      }
      SparseSolver s(o);
      Eigen::VectorXd x;
      for (int step = 0; step < 3; ++step) {  // same pattern, new values
        const Matrix As = System(20, 0.7 + 0.1 * step);
        ASSERT_TRUE(s.Factorize(As).ok()) << SolverKindName(k);
        const Eigen::VectorXd xs = x_true * (1 + step);
        ASSERT_TRUE(s.Solve(As * xs, &x).ok()) << SolverKindName(k);
        EXPECT_LT((x - xs).lpNorm<Eigen::Infinity>(), 1e-9) << SolverKindName(k);
        EXPECT_GE(s.iterations(), 1);
      }
      EXPECT_EQ(s.analyses(), 1) << SolverKindName(k);
    }
  }
}

// UMFPACK with METIS's nested dissection: same solutions, one analysis for a fixed pattern.
TEST(SparseSolver, UmfpackWithMetisOrderingSolves) {
  ASSERT_TRUE(SolverAvailable(SolverKind::kUmfpack));  // libsuitesparse-dev: scripts/install-deps.sh
  SolverOptions o;
  o.kind = SolverKind::kUmfpack;
  o.umfpack_metis = true;
  SparseSolver s(o);
  const Eigen::VectorXd x_true = Eigen::VectorXd::LinSpaced(900, -1, 1);
  Eigen::VectorXd x;
  for (int step = 0; step < 2; ++step) {
    const Matrix A = System(30, 0.5 + step);
    ASSERT_TRUE(s.Factorize(A).ok());
    ASSERT_TRUE(s.Solve(A * x_true, &x).ok());
    EXPECT_LT((x - x_true).lpNorm<Eigen::Infinity>(), 1e-10);
  }
  EXPECT_EQ(s.analyses(), 1);
}

// Iterations of BiCGSTAB from zero to 1e-12 on System(m, c).
int Iterations(const Matrix& A, Preconditioner p, Eigen::VectorXd* x) {
  SolverOptions o;
  o.kind = SolverKind::kBiCGSTAB;
  o.preconditioner = p;
  SparseSolver s(o);
  EXPECT_TRUE(s.Factorize(A).ok());
  x->resize(0);
  const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(A.rows(), -1, 2).array().sin();
  EXPECT_TRUE(s.Solve(b, x).ok());
  return s.iterations();
}

// AMG: the same solution as a direct solver; iterations bounded as the grid is refined
// (diffusion-dominated I - c K, c = 10 m^2 / 32^2: Jacobi's grow like 1/h).
TEST(Amg, SolvesLikeADirectSolverWithBoundedIterations) {
  std::vector<int> amg, jacobi;
  for (int m : {32, 64, 128}) {
    const Matrix A = System(m, 10.0 * m * m / (32 * 32));
    Eigen::VectorXd x, xj;
    amg.push_back(Iterations(A, Preconditioner::kAmg, &x));
    jacobi.push_back(Iterations(A, Preconditioner::kDiagonal, &xj));
    SolverOptions direct;
    direct.kind = SolverKind::kSparseLU;
    SparseSolver lu(direct);
    ASSERT_TRUE(lu.Factorize(A).ok());
    Eigen::VectorXd xd;
    ASSERT_TRUE(lu.Solve(Eigen::VectorXd::LinSpaced(A.rows(), -1, 2).array().sin(), &xd).ok());
    EXPECT_LT((x - xd).norm(), 1e-10 * xd.norm()) << m;
    std::printf("m %d: AMG %d iterations, Jacobi %d\n", m, amg.back(), jacobi.back());
  }
  for (int l = 1; l < 3; ++l) {
    EXPECT_LE(amg[l], 1.5 * amg[l - 1]) << l;
    EXPECT_GE(jacobi[l], 1.6 * jacobi[l - 1]) << l;
  }
  EXPECT_LE(amg[2], 12);
  Amg h;
  ASSERT_TRUE(h.Build(System(128, 160)).ok());
  EXPECT_GE(h.num_levels(), 3);
  EXPECT_LE(h.rows(h.num_levels() - 1), AmgOptions().coarse_size);
  EXPECT_LT(h.operator_complexity(), 1.6);
  // Deterministic: the same hierarchy and the same V-cycle, bit for bit.
  Amg again;
  ASSERT_TRUE(again.Build(System(128, 160)).ok());
  const Eigen::VectorXd b = Eigen::VectorXd::LinSpaced(128 * 128, 0, 1);
  Eigen::VectorXd y1, y2;
  h.Apply(b, &y1);
  again.Apply(b, &y2);
  EXPECT_EQ(y1, y2);
}

// The set-up polls the context between its phases, several times per level, and stops
// with CANCELLED at whichever poll sees the cancellation, leaving no hierarchy.
TEST(Amg, BuildStopsWhenCancelled) {
  const Matrix A = System(128, 160);
  int polls = 0;
  CancellationToken counting;
  counting.SetPoll([&polls] { return ++polls < 0; });
  Amg h;
  ASSERT_TRUE(h.Build(A, AmgOptions(), RunContext(&counting)).ok());
  EXPECT_GE(polls, 5 * (h.num_levels() - 1));
  for (int stop : {1, 2, polls / 2, polls}) {
    int seen = 0;
    CancellationToken token;
    token.SetPoll([&seen, stop] { return ++seen >= stop; });
    Amg cancelled;
    EXPECT_EQ(cancelled.Build(A, AmgOptions(), RunContext(&token)).code(), absl::StatusCode::kCancelled) << stop;
    EXPECT_FALSE(cancelled.built()) << stop;
  }
  CancellationToken token;
  token.Cancel();
  EXPECT_EQ(h.Build(A, AmgOptions(), RunContext(&token)).code(), absl::StatusCode::kCancelled);
  EXPECT_FALSE(h.built());
}

TEST(Amg, RejectsBadInput) {
  Amg h;
  Matrix rect(3, 4);
  EXPECT_EQ(h.Build(rect).code(), absl::StatusCode::kInvalidArgument);
  Matrix zero_row = System(4, 1);
  zero_row.row(2) *= 0;
  EXPECT_EQ(h.Build(zero_row).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(h.UpdateFinest(System(4, 1)).code(), absl::StatusCode::kFailedPrecondition);
  ASSERT_TRUE(h.Build(System(8, 1)).ok());
  EXPECT_EQ(h.UpdateFinest(System(4, 1)).code(), absl::StatusCode::kInvalidArgument);
  AmgOptions o;
  o.strength = 1;
  EXPECT_EQ(h.Build(System(8, 1), o).code(), absl::StatusCode::kInvalidArgument);
  SolverOptions so;
  so.amg.sweeps = 0;
  EXPECT_EQ(ValidateSolverOptions(so).code(), absl::StatusCode::kInvalidArgument);
}

TEST(SparseSolver, ParsesNamesAndRejectsBadOptions) {
  EXPECT_EQ(ParseSolverKind("klu").value(), SolverKind::kKlu);
  EXPECT_EQ(ParseSolverKind("auto").value(), SolverKind::kAuto);
  EXPECT_EQ(ParseSolverKind("cholesky").status().code(), absl::StatusCode::kInvalidArgument);
  SolverOptions o;
  o.tolerance = 0;
  EXPECT_EQ(ValidateSolverOptions(o).code(), absl::StatusCode::kInvalidArgument);
  o = SolverOptions();
  o.max_iterations = 0;
  EXPECT_EQ(ValidateSolverOptions(o).code(), absl::StatusCode::kInvalidArgument);
  SparseSolver s;
  Matrix rect(3, 4);
  EXPECT_EQ(s.Factorize(rect).code(), absl::StatusCode::kInvalidArgument);
  Matrix singular(3, 3);
  singular.insert(0, 0) = 1;
  singular.makeCompressed();
  EXPECT_EQ(s.Factorize(singular).code(), absl::StatusCode::kFailedPrecondition);
}

}  // namespace
}  // namespace geomfit
