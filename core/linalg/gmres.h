#pragma once
// Restarted GMRES with right preconditioning (Saad, Iterative Methods for Sparse Linear
// Systems, Alg. 9.5): for Newton steps whose Jacobian is too costly to factorize, with a
// factorization of a sparser approximation as the preconditioner.
#include <functional>

#include <Eigen/Core>

#include "absl/status/status.h"
#include "core/util/run_context.h"

namespace geomfit {

struct GmresOptions {
  double tolerance = 1e-6;   ///< on |b - A x| / |b|
  int restart = 50;          ///< Krylov dimension per cycle
  int max_iterations = 500;  ///< matrix-vector products in all
};

struct GmresResult {
  int iterations = 0;
  double residual = 0;  ///< relative, as estimated by the Arnoldi recurrence
};

/// y = A x and y = M^{-1} x (the preconditioner); both overwrite y. Unlike LinearMap
/// (sparse_solver.h) a map may fail (a factorization that cannot solve), and Gmres passes it on.
using CheckedLinearMap = std::function<absl::Status(const Eigen::VectorXd& x, Eigen::VectorXd* y)>;

/// Solves A x = b from x = 0. FAILED_PRECONDITION when the tolerance is not reached in
/// max_iterations (x holds the best iterate); errors of the maps pass through; polls ctx
/// every iteration.
absl::Status Gmres(const CheckedLinearMap& A, const CheckedLinearMap& preconditioner, const Eigen::VectorXd& b,
                   const GmresOptions& options, Eigen::VectorXd* x, GmresResult* result,
                   const RunContext& ctx = RunContext());

}  // namespace geomfit
