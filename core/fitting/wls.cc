#include "core/fitting/wls.h"

#include <algorithm>
#include <cmath>

#include "core/fitting/small_qr.h"

namespace geomfit {
namespace {

constexpr int kMaxCoef = kMaxCoefficients;
constexpr double kFactorial[] = {1, 1, 2, 6, 24, 120, 720};
constexpr int TaylorIdx(int j, int k) { return (j + k) * (j + k + 1) / 2 + k; }

// y = R_k^-1 (Q^T b)_k by back substitution; column-major R with leading dimension ld.
void BackSubstitute(const double* R, int ld, int k, const double* qtb, double* y) {
  for (int i = k - 1; i >= 0; --i) {
    double sum = qtb[i];
    for (int l = i + 1; l < k; ++l) sum -= R[l * ld + i] * y[l];
    y[i] = sum / R[i * ld + i];
  }
}

}  // namespace

namespace {

// 1 / (j! k!) by total degree p and k (j = p - k), in TaylorIndex order.
constexpr double kInvFactorials[kMaxCoef] = {
    1,                                                             // p = 0
    1, 1,                                                          // p = 1
    1.0 / 2, 1, 1.0 / 2,                                           // p = 2
    1.0 / 6, 1.0 / 2, 1.0 / 2, 1.0 / 6,                            // p = 3
    1.0 / 24, 1.0 / 6, 1.0 / 4, 1.0 / 6, 1.0 / 24,                 // p = 4
    1.0 / 120, 1.0 / 24, 1.0 / 12, 1.0 / 12, 1.0 / 24, 1.0 / 120,  // p = 5
    1.0 / 720, 1.0 / 120, 1.0 / 48, 1.0 / 36, 1.0 / 48, 1.0 / 120, 1.0 / 720};  // p = 6

// The degree as a template parameter lets the compiler unroll the (hot) evaluation:
// f = sum_k v^k Q_k(u), each Q_k and Q_k' by Horner's rule.
template <int D>
void EvalTaylorFixed(const double* c, double u, double v, double* value, double* du, double* dv) {
  double f = 0, fu = 0, fv = 0, vk = 1, vk1 = 0;  // v^k, v^(k-1)
  for (int k = 0; k <= D; ++k) {
    auto a = [&](int j) { const int i = TaylorIdx(j, k); return c[i] * kInvFactorials[i]; };
    double q = a(D - k), dq = 0;
    for (int j = D - k - 1; j >= 0; --j) {
      dq = dq * u + q;
      q = q * u + a(j);
    }
    f += vk * q;
    fu += vk * dq;
    fv += k * vk1 * q;
    vk1 = vk;
    vk *= v;
  }
  if (value) *value = f;
  if (du) *du = fu;
  if (dv) *dv = fv;
}

}  // namespace

void EvalTaylor(const double* c, int degree, double u, double v, double* value, double* du,
                double* dv) {
  switch (degree) {
    case 0: return EvalTaylorFixed<0>(c, u, v, value, du, dv);
    case 1: return EvalTaylorFixed<1>(c, u, v, value, du, dv);
    case 2: return EvalTaylorFixed<2>(c, u, v, value, du, dv);
    case 3: return EvalTaylorFixed<3>(c, u, v, value, du, dv);
    case 4: return EvalTaylorFixed<4>(c, u, v, value, du, dv);
    case 5: return EvalTaylorFixed<5>(c, u, v, value, du, dv);
    default: return EvalTaylorFixed<6>(c, u, v, value, du, dv);
  }
}

WlsSolution SolveWls(const WlsProblem& P, const WlsSettings& S, double* coefficients, double* op) {
  WlsSolution sol;
  const int ncoef = NumCoefficients(S.degree);
  const int first_col = S.interpolate ? 1 : 0;  // c00 is fixed by interpolation
  std::fill(coefficients, coefficients + P.dims * ncoef, 0.0);
  if (op) std::fill(op, op + static_cast<size_t>(ncoef) * P.rows, 0.0);

  // Keep rows with a positive safeguard factor; scale distances by the stencil radius.
  int keep[kMaxStencil];
  int rows = 0;
  double radius2 = 0;
  for (int r = 0; r < P.rows; ++r) {
    if (!(P.gamma[r] > 0)) continue;
    keep[rows++] = r;
    radius2 = std::max(radius2, P.u[r] * P.u[r] + P.v[r] * P.v[r]);
  }
  if (rows == 0 || radius2 == 0) return sol;
  const double h = sol.radius = std::sqrt(radius2);

  // Weighted Vandermonde [A | B] (2.3.5), column-major with ld = rows.
  const int cols = ncoef - first_col, ld = rows, dims = P.dims;
  double a[kMaxStencil * (kMaxCoef + 3)];
  double weight[kMaxStencil];
  double* B = a + cols * ld;
  double inv_fact[kMaxCoef];  // 1 / (j! k!) per column, in column order
  {
    int c = 0;
    for (int p = first_col; p <= S.degree; ++p)
      for (int k = 0; k <= p; ++k) inv_fact[c++] = 1.0 / (kFactorial[p - k] * kFactorial[k]);
  }
  for (int i = 0; i < rows; ++i) {
    const int r = keep[i];
    const double u = P.u[r] / h, v = P.v[r] / h;
    // (2.2.1): w = gamma / (sqrt(|u|^2 + eps))^(d/2) = gamma / s^(d/4), s = |u|^2 + eps.
    const double s2 = u * u + v * v + S.weight_epsilon;
    const double root = S.degree % 2 == 0 ? std::sqrt(s2) : std::sqrt(std::sqrt(s2));  // s^(1/2) or s^(1/4)
    double denom = root;
    for (int e = 1, n = S.degree % 2 == 0 ? S.degree / 2 : S.degree; e < n; ++e) denom *= root;
    const double w = weight[i] = P.gamma[r] / denom;
    double up[kMaxDegree + 1] = {1}, vp[kMaxDegree + 1] = {1};
    for (int e = 1; e <= S.degree; ++e) up[e] = up[e - 1] * u, vp[e] = vp[e - 1] * v;
    int c = 0;
    for (int p = first_col; p <= S.degree; ++p)
      for (int k = 0; k <= p; ++k, ++c) a[c * ld + i] = w * inv_fact[c] * up[p - k] * vp[k];
    for (int d = 0; d < dims; ++d) B[d * ld + i] = w * P.rhs[d][r];
  }
  // Column scaling by 2-norms (2.6.6).
  double scale[kMaxCoef];
  for (int c = 0; c < cols; ++c) {
    double norm2 = 0;
    for (int i = 0; i < rows; ++i) norm2 += a[c * ld + i] * a[c * ld + i];
    scale[c] = norm2 > 0 ? 1 / std::sqrt(norm2) : 1.0;
    for (int i = 0; i < rows; ++i) a[c * ld + i] *= scale[c];
  }
  double tau[kMaxCoef];
  HouseholderQRInPlace(a, ld, rows, cols, dims, tau);  // [A | B] -> [R | Q^T B]
  const int kq = std::min(rows, cols);

  // Condition safeguard (2.4): the leading k x k block of R factors the first k columns
  // and inv(R)'s leading block inverts it, so the 1-norms of every leading block are
  // prefix maxima of column sums: one triangular inverse prices every degree.
  int usable = kq;  // columns before the first (numerically) zero pivot
  const double tiny = 1e-13 * std::max(1.0, std::abs(a[0]));
  for (int c = 0; c < kq; ++c)
    if (!(std::abs(a[c * ld + c]) > tiny)) {
      usable = c;
      break;
    }
  double rinv[kMaxCoef * kMaxCoef];
  InvertUpper(a, ld, usable, rinv);
  double colsum_r[kMaxCoef], colsum_i[kMaxCoef];
  for (int c = 0; c < usable; ++c) {
    colsum_r[c] = colsum_i[c] = 0;
    for (int i = 0; i <= c; ++i) colsum_r[c] += std::abs(a[c * ld + i]), colsum_i[c] += std::abs(rinv[c * usable + i]);
    if (c > 0) colsum_r[c] = std::max(colsum_r[c], colsum_r[c - 1]), colsum_i[c] = std::max(colsum_i[c], colsum_i[c - 1]);
  }
  auto cols_of = [&](int degree) { return NumCoefficients(degree) - first_col; };
  int degree = S.degree;
  for (; degree >= 1; --degree) {
    const int k = cols_of(degree);
    if (k > usable) continue;
    sol.condition = colsum_r[k - 1] * colsum_i[k - 1];
    if (sol.condition <= S.cond_threshold[degree]) break;
  }
  sol.condition_downgraded = degree < S.degree;
  if (degree < 1) return sol;

  // Scaled solutions y (coefficients of the column-scaled, radius-scaled problem).
  double y[3][kMaxCoef];
  auto solve = [&](int deg, double out[3][kMaxCoef]) {
    for (int d = 0; d < dims; ++d) BackSubstitute(a, ld, cols_of(deg), B + d * ld, out[d]);
  };
  solve(degree, y);
  // Oscillation safeguard (4.1.3), made scale-free. In heights at the stencil radius
  // (c h^p), a resolved degree-p fit's degree-p coefficients differ from the degree-d
  // fit's by the aliased degree-(p+1) term: a derivative of order p+1 of a surface whose
  // curvature radius is h / t, ~ (p+1)! h t^p with t = |c^_2| h the stencil radius over
  // the curvature radius (from the degree-2 fit). The text's test
  // |c^_p - c_p| <= max(|c^_p|, eps) with an absolute eps = 0.01 instead downgrades
  // resolved fits whose c_p vanish by symmetry (odd orders on a sphere), costing up to
  // 100x at mid resolutions; so eps becomes tolerance * (p+1)!/3! * h t^p (without the
  // factorial, degree-6 fits of marching-cubes tori whose stencils reach t ~ 1 were
  // lowered to 5 at 2.4x the normal error; bench/README.md, issue 16). That alone lets
  // the unresolved fits of coarse meshes through (t ~ 1), so a second test bounds the
  // fit where WALF uses it: at the nearest rows (about the one-ring) and half-way to
  // them, the degree-d fit may not leave the degree-2 fit by more than deviation times
  // the distance of the farthest of those rows. (Comparing on the disc of half the
  // stencil radius instead cost up to 8x on anisotropic meshes, whose stencils reach
  // around a thin tube where no height function of the tangent plane exists.)
  if (S.oscillation_safeguard && degree > 2) {
    double y2[3][kMaxCoef];
    solve(2, y2);
    double t2 = 0;  // |c^_2|^2 h^4
    for (int c = cols_of(1); c < cols_of(2); ++c)
      for (int d = 0; d < dims; ++d) t2 += scale[c] * y2[d][c] * scale[c] * y2[d][c];
    const double t = std::sqrt(t2) / h;
    // Taylor coefficients in heights at the stencil radius, for EvalTaylor on the unit disc.
    auto unscaled = [&](const double yy[3][kMaxCoef], int deg, double out[3][kMaxCoef]) {
      for (int d = 0; d < dims; ++d) std::fill(out[d], out[d] + kMaxCoef, 0.0);
      int c = 0;
      for (int p = first_col; p <= deg; ++p)
        for (int kk = 0; kk <= p; ++kk, ++c)
          for (int d = 0; d < dims; ++d) out[d][TaylorIdx(p - kk, kk)] = scale[c] * yy[d][c];
    };
    double c2[3][kMaxCoef];
    unscaled(y2, 2, c2);
    // The nearest rows (in the unit disc) and the radius they reach.
    constexpr int kNear = 6;
    int near[kMaxStencil];
    for (int i = 0; i < rows; ++i) near[i] = keep[i];
    const int num_near = std::min(rows, kNear);
    auto dist2 = [&](int r) { return P.u[r] * P.u[r] + P.v[r] * P.v[r]; };
    std::partial_sort(near, near + num_near, near + rows, [&](int x, int z) { return dist2(x) < dist2(z); });
    const double near_radius = std::sqrt(dist2(near[num_near - 1]));
    while (degree > 2) {
      bool ok = true;
      for (int p = 2; p < degree && ok; ++p) {
        double yp[3][kMaxCoef];
        solve(p, yp);
        double diff2 = 0, ref2 = 0;
        for (int c = cols_of(p - 1); c < cols_of(p); ++c)
          for (int d = 0; d < dims; ++d) {
            const double lo = scale[c] * yp[d][c], hi = scale[c] * y[d][c];
            diff2 += (lo - hi) * (lo - hi);
            ref2 += lo * lo;
          }
        const double eps =
            S.oscillation_tolerance * kFactorial[p + 1] / kFactorial[3] * h * std::pow(t, p) + 1e-12 * h;
        ok = std::sqrt(diff2) <= std::max(std::sqrt(ref2), eps);
      }
      if (ok) {
        double cd[3][kMaxCoef];
        unscaled(y, degree, cd);
        double dev = 0;
        for (int k = 0; k < num_near; ++k)
          for (double f : {0.5, 1.0}) {
            const double u = f * P.u[near[k]] / h, v = f * P.v[near[k]] / h;
            double e2 = 0;
            for (int d = 0; d < dims; ++d) {
              double fd, f2;
              EvalTaylor(cd[d], degree, u, v, &fd, nullptr, nullptr);
              EvalTaylor(c2[d], 2, u, v, &f2, nullptr, nullptr);
              e2 += (fd - f2) * (fd - f2);
            }
            dev = std::max(dev, std::sqrt(e2));
          }
        ok = dev <= S.oscillation_deviation * near_radius;
      }
      if (ok) break;
      --degree;
      sol.oscillation_downgraded = true;
      solve(degree, y);
    }
  }
  const int k = cols_of(degree);
  sol.degree_used = degree;
  sol.rank = k + first_col;

  // Undo the column and radius scaling: c_jk = s_c y_c / h^(j+k).
  double hp[kMaxDegree + 1] = {1};
  for (int p = 1; p <= degree; ++p) hp[p] = hp[p - 1] * h;
  for (int d = 0; d < dims; ++d) {
    int c = 0;
    for (int p = first_col; p <= degree; ++p)
      for (int kk = 0; kk <= p; ++kk, ++c) coefficients[d * ncoef + TaylorIdx(p - kk, kk)] = scale[c] * y[d][c] / hp[p];
  }

  if (op) {
    // Operator rows: coefficients = S R_k^-1 Q_k^T Omega g, i.e. row c of the operator
    // is s_c / h^p * (Q z_c)^T Omega with z_c = (R_k^-T e_c; 0): one application of Q
    // per row, and only for the rows asked for.
    const int op_rows = S.op_rows < 0 ? ncoef : std::min(S.op_rows, ncoef);
    double z[kMaxStencil];
    int c = 0;
    for (int p = first_col; p <= degree; ++p)
      for (int kk = 0; kk <= p; ++kk, ++c) {
        const int t = TaylorIdx(p - kk, kk);
        if (t >= op_rows) continue;
        std::fill(z, z + rows, 0.0);
        for (int l = c; l < k; ++l) z[l] = rinv[l * usable + c];
        ApplyQ(a, ld, rows, kq, tau, z);
        double* row = op + static_cast<size_t>(t) * P.rows;
        for (int i = 0; i < rows; ++i) row[keep[i]] = weight[i] * z[i] * scale[c] / hp[p];
      }
  }
  return sol;
}

}  // namespace geomfit
