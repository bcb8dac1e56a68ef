#pragma once
#include <algorithm>
#include <cmath>

namespace geomfit {

/// y <- (I - tau v v^T) y for the reflector v = (1, x[j+1..m)) acting on rows j..m-1.
inline void ApplyReflector(const double* x, double tau, int j, int m, double* y) {
  double w = y[j];
  for (int i = j + 1; i < m; ++i) w += x[i] * y[i];
  w *= tau;
  y[j] -= w;
  for (int i = j + 1; i < m; ++i) y[i] -= w * x[i];
}

/// Householder QR of a small column-major matrix stored in place with leading
/// dimension `ld`, written for the per-vertex fits (2.4): no allocation, and the
/// reflectors are applied to trailing right-hand-side columns during the
/// factorization, so [A | B] -> [R | Q^T B] in one sweep.
///
/// On return the upper triangle of the first `n` columns holds R, the part below the
/// diagonal holds the reflectors' vectors (implicit leading 1), and tau[j] their factors.
inline void HouseholderQRInPlace(double* a, int ld, int m, int n, int nrhs, double* tau) {
  const int steps = std::min(m, n);
  for (int j = 0; j < steps; ++j) {
    double* x = a + j * ld;
    double sigma = 0;
    for (int i = j + 1; i < m; ++i) sigma += x[i] * x[i];
    const double alpha = x[j];
    if (sigma == 0) {  // already upper triangular in this column: H = I
      tau[j] = 0;
      continue;
    }
    const double norm = std::sqrt(alpha * alpha + sigma);
    const double beta = alpha >= 0 ? -norm : norm;
    const double inv = 1 / (alpha - beta);
    for (int i = j + 1; i < m; ++i) x[i] *= inv;
    tau[j] = (beta - alpha) / beta;
    x[j] = beta;
    for (int c = j + 1; c < n + nrhs; ++c) ApplyReflector(x, tau[j], j, m, a + c * ld);  // H_j to the rest
  }
}

/// y <- Q y for the reflectors stored by HouseholderQRInPlace (first `k` of them).
inline void ApplyQ(const double* a, int ld, int m, int k, const double* tau, double* y) {
  for (int j = k - 1; j >= 0; --j) {
    if (tau[j] != 0) ApplyReflector(a + j * ld, tau[j], j, m, y);
  }
}

/// Inverse of the upper-triangular k x k R (column-major, leading dimension ld) into `inv` (leading dimension k); returns false on a zero pivot.
inline bool InvertUpper(const double* r, int ld, int k, double* inv) {
  for (int c = 0; c < k; ++c)
    if (r[c * ld + c] == 0) return false;
  // Column c of inv solves R x = e_c; backward column sweeps (axpy on R's contiguous
  // columns) instead of strided row dot products.
  for (int c = 0; c < k; ++c) {
    double* x = inv + c * k;
    for (int i = 0; i < k; ++i) x[i] = 0;
    x[c] = 1;
    for (int i = c; i >= 0; --i) {
      const double* ri = r + i * ld;
      const double xi = x[i] /= ri[i];
      for (int l = 0; l < i; ++l) x[l] -= xi * ri[l];
    }
  }
  return true;
}

}  // namespace geomfit
