#pragma once
#include "core/fitting/options.h"

namespace geomfit {

inline constexpr int kMaxCoefficients = NumCoefficients(kMaxDegree);

/// A local weighted-least-squares polynomial fit (2.3.4): rows (u_i, v_i) in a local
/// frame, a safeguard factor gamma_i per row (0 drops the row), and up to three
/// right-hand sides. Shared by vertex fits, CMF points and function fits.
struct WlsProblem {
  int rows = 0;
  int dims = 1;
  double u[kMaxStencil], v[kMaxStencil], gamma[kMaxStencil];
  double rhs[3][kMaxStencil];
};

struct WlsSettings {
  int degree = 2;
  bool interpolate = true;  ///< the origin is a data point of value 0: no c00 column
  double weight_epsilon = 0.01;
  const double* cond_threshold = nullptr;  ///< per degree, index 1..6
  bool oscillation_safeguard = false;      ///< (4.1.3)
  /// Coefficient test: |c^_p - c_p| <= max(|c^_p|, tolerance (p+1)!/3! h t^p) (see SolveWls).
  double oscillation_tolerance = 10;
  /// Deviation test: |f_d - f_2| <= deviation r at the nearest rows and half-way to
  /// them, r the distance of the farthest of those rows (about the one-ring).
  double oscillation_deviation = 0.2;
  /// Operator rows to build (leading Taylor coefficients); -1 builds all.
  int op_rows = -1;
};

struct WlsSolution {
  int degree_used = 0;  ///< 0: no usable fit
  int rank = 0;         ///< coefficients solved for (c00 included when interpolating)
  double condition = 0;
  bool condition_downgraded = false;    ///< (2.4)
  bool oscillation_downgraded = false;  ///< (4.1.3)
  double radius = 0;                    ///< stencil radius that scaled (u, v)
};

/// Solves the fit: weights (2.2.1) with distances scaled by the stencil radius, Taylor
/// Vandermonde (2.3.2), column scaling (2.6.6), Householder QR with the condition
/// safeguard dropping whole trailing degrees (2.4), and optionally the oscillation
/// safeguard (4.1.3). Writes `coefficients[d * NumCoefficients(degree) + TaylorIndex]`
/// (derivatives in (u, v) units, zero above the degree used, c00 = 0 when
/// interpolating). If `op` is non-null, also writes the operator
/// op[TaylorIndex * rows + r] with coefficient = sum_r op * value_r (values relative to
/// the origin's when interpolating).
WlsSolution SolveWls(const WlsProblem& problem, const WlsSettings& settings, double* coefficients,
                     double* op = nullptr);

/// Value and first derivatives of the Taylor polynomial sum c_jk u^j v^k / (j! k!).
void EvalTaylor(const double* c, int degree, double u, double v, double* value, double* du,
                double* dv);

}  // namespace geomfit
