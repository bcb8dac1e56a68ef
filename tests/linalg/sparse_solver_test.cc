// Sparse solvers: every kind solves a nonsymmetric system of the flows' shape, direct
// solvers analyse a fixed pattern once (UMFPACK with METIS ordering too), and options
// are validated.
#include <gtest/gtest.h>

#include "core/linalg/sparse_solver.h"

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
    for (Preconditioner p : {Preconditioner::kDiagonal, Preconditioner::kIlut}) {
      SolverOptions o;
      o.kind = k;
      o.preconditioner = p;
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
