#include "core/integration/quadrature.h"

#include <algorithm>
#include <cmath>

namespace geomfit {

QuadratureRule GaussLegendre01(int n) {
  QuadratureRule r;
  r.degree = 2 * n - 1;
  for (int i = 0; i < n; ++i) {
    // Newton on P_n from the Chebyshev-like guess; (x, w) on [-1, 1].
    double x = std::cos(M_PI * (i + 0.75) / (n + 0.5)), dp = 0;
    for (int it = 0; it < 100; ++it) {
      double p0 = 1, p1 = x;
      for (int k = 2; k <= n; ++k) {
        const double p2 = ((2 * k - 1) * x * p1 - (k - 1) * p0) / k;
        p0 = p1;
        p1 = p2;
      }
      dp = n * (x * p1 - p0) / (x * x - 1);
      const double dx = p1 / dp;
      x -= dx;
      if (std::abs(dx) < 1e-16) break;
    }
    r.xi.push_back(0.5 * (1 - x));
    r.eta.push_back(0);
    r.weight.push_back(1.0 / ((1 - x * x) * dp * dp));  // 2 / ((1-x^2) P'^2), halved for [0, 1]
  }
  return r;
}

QuadratureRule TriangleRule(int degree) {
  degree = std::clamp(degree, 1, kMaxQuadratureDegree);
  // The Jacobian (1 - a) raises the degree in a by one.
  const QuadratureRule a = GaussLegendre01((degree + 3) / 2), b = GaussLegendre01((degree + 2) / 2);
  QuadratureRule r;
  r.degree = degree;
  for (int i = 0; i < a.size(); ++i)
    for (int j = 0; j < b.size(); ++j) {
      r.xi.push_back(a.xi[i]);
      r.eta.push_back((1 - a.xi[i]) * b.xi[j]);
      r.weight.push_back(a.weight[i] * b.weight[j] * (1 - a.xi[i]));
    }
  return r;
}

QuadratureRule QuadRule(int degree) {
  degree = std::clamp(degree, 1, kMaxQuadratureDegree);
  const QuadratureRule g = GaussLegendre01((degree + 2) / 2);
  QuadratureRule r;
  r.degree = degree;
  for (int i = 0; i < g.size(); ++i)
    for (int j = 0; j < g.size(); ++j) {
      r.xi.push_back(g.xi[i]);
      r.eta.push_back(g.xi[j]);
      r.weight.push_back(g.weight[i] * g.weight[j]);
    }
  return r;
}

}  // namespace geomfit
