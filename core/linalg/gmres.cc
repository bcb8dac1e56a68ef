#include "core/linalg/gmres.h"

#include <cmath>
#include <vector>

#include <Eigen/Dense>

#include "absl/strings/str_format.h"
#include "core/util/status_macros.h"

namespace geomfit {

absl::Status Gmres(const CheckedLinearMap& A, const CheckedLinearMap& preconditioner, const Eigen::VectorXd& b,
                   const GmresOptions& o, Eigen::VectorXd* x, GmresResult* result, const RunContext& ctx) {
  const Eigen::Index n = b.size();
  x->setZero(n);
  *result = GmresResult();
  const double bnorm = b.norm();
  if (bnorm == 0) return absl::OkStatus();
  const int m = o.restart;
  Eigen::MatrixXd V(n, m + 1), H = Eigen::MatrixXd::Zero(m + 1, m);
  Eigen::VectorXd cs(m), sn(m), g(m + 1), w(n), z(n), r = b;
  double rnorm = bnorm;
  while (result->iterations < o.max_iterations) {
    V.col(0) = r / rnorm;
    g.setZero();
    g(0) = rnorm;
    int k = 0;
    for (; k < m && result->iterations < o.max_iterations; ++k) {
      GF_RETURN_IF_ERROR(ctx.Check());
      ++result->iterations;
      GF_RETURN_IF_ERROR(preconditioner(V.col(k), &z));
      GF_RETURN_IF_ERROR(A(z, &w));
      for (int j = 0; j <= k; ++j) {  // modified Gram-Schmidt
        H(j, k) = w.dot(V.col(j));
        w -= H(j, k) * V.col(j);
      }
      H(k + 1, k) = w.norm();
      if (H(k + 1, k) > 0) V.col(k + 1) = w / H(k + 1, k);
      for (int j = 0; j < k; ++j) {  // earlier rotations
        const double t = cs(j) * H(j, k) + sn(j) * H(j + 1, k);
        H(j + 1, k) = -sn(j) * H(j, k) + cs(j) * H(j + 1, k);
        H(j, k) = t;
      }
      const double d = std::hypot(H(k, k), H(k + 1, k));
      cs(k) = H(k, k) / d;
      sn(k) = H(k + 1, k) / d;
      H(k, k) = d;
      H(k + 1, k) = 0;
      g(k + 1) = -sn(k) * g(k);
      g(k) *= cs(k);
      result->residual = std::abs(g(k + 1)) / bnorm;
      if (result->residual <= o.tolerance || H(k, k) == 0) {
        ++k;
        break;
      }
    }
    // x += M^{-1} V_k y with H_k y = g_k.
    const Eigen::VectorXd y = H.topLeftCorner(k, k).triangularView<Eigen::Upper>().solve(g.head(k));
    GF_RETURN_IF_ERROR(preconditioner(V.leftCols(k) * y, &z));
    *x += z;
    if (result->residual <= o.tolerance) return absl::OkStatus();
    GF_RETURN_IF_ERROR(A(*x, &w));  // the true residual for the restart
    r = b - w;
    rnorm = r.norm();
    result->residual = rnorm / bnorm;
    if (result->residual <= o.tolerance) return absl::OkStatus();
  }
  return absl::FailedPreconditionError(absl::StrFormat("GMRES: relative residual %.3e after %d iterations (wanted %g)",
                                                       result->residual, result->iterations, o.tolerance));
}

}  // namespace geomfit
