#pragma once
#include <vector>

namespace geomfit {

/// A quadrature rule on a reference face: points (xi, eta) and weights.
struct QuadratureRule {
  int degree = 0;  ///< exact for polynomials up to this total degree
  std::vector<double> xi, eta, weight;
  int size() const { return static_cast<int>(weight.size()); }
};

inline constexpr int kMaxQuadratureDegree = 30;

/// Gauss-Legendre rule with n points on [0, 1] (exact to degree 2n - 1).
QuadratureRule GaussLegendre01(int n);

/// Rule on the reference triangle {xi, eta >= 0, xi + eta <= 1} (weights sum to 1/2),
/// exact to `degree` (1..30): the collapsed (Duffy) product of Gauss-Legendre rules,
/// xi = a, eta = (1 - a) b, with positive weights and interior points.
QuadratureRule TriangleRule(int degree);

/// Tensor Gauss-Legendre rule on the unit square [0, 1]^2 (weights sum to 1), exact to
/// `degree` in each variable.
QuadratureRule QuadRule(int degree);

}  // namespace geomfit
