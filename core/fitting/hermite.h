#pragma once
#include <cmath>

namespace geomfit {

/// One stencil point's row of the Hermite Hessian fit (FitOptions::hermite_hessian and
/// the slope refinement's curvature pass, core/fitting/slopes.h). Along the ray to a
/// point at parameter distance r in direction e, the height is
/// h = Q r^2/2 + C r^3/6 + D r^4/24 + ... and the radial slope g = Q r + C r^2/2 + D r^3/6
/// + ..., with Q = e^T Hess e and C, D the cubic and quartic forms, so
/// 4h/r^2 - g/r = Q + C r/6 + O(r^3): the quartic term cancels (it dominates the degree-2
/// error on every mesh measured). g comes from the point's normal n in the vertex's frame
/// (t1, t2, m): (f_u, f_v) = -(n.t1, n.t2) / n.m.
///
/// The point is at (u, w) with height h, its normal's components are nt1 = n.t1,
/// nt2 = n.t2, nm = n.m, its safeguard weight gamma ((2.2.1): n.m, or 0 beyond the
/// cut-off), and inv_radius2 = 1 / radius^2 of the stencil. Out: `value` = 4h/r^2 - g/r,
/// `col` the columns (u^2, 2uw, w^2) / r^2 of (c20, c11, c02) in e^T Hess e,
/// `inv_r2` = 1 / r^2, and `weight` = gamma s / (s + eps)^2.5 in s = r^2 / radius^2, which
/// ~ s^-1.5 favours near points (the remaining errors grow with r) but ~ s below
/// r ~ sqrt(eps) radius, where the normals' error over r dominates. A point with gamma = 0
/// or r = 0 gets weight 0, inv_r2 = 0 and finite entries. Branch-free with scalar outputs
/// (vector lanes: struct locals keep GCC from vectorizing a simd loop).
__attribute__((always_inline)) inline void HermiteRowOf(double u, double w, double h, double nt1, double nt2, double nm,
                                                       double gamma, double inv_radius2, double eps, double& value,
                                                       double& c0, double& c1, double& c2, double& inv_r2,
                                                       double& weight) {
  const double r2 = u * u + w * w;
  const double g = r2 > 0 ? gamma : 0.0;
  const double inv = 1 / (g > 0 ? nm * r2 : 1.0);
  value = (4 * h * nm + (nt1 * u + nt2 * w)) * inv;
  inv_r2 = g > 0 ? nm * inv : 0.0;
  c0 = u * u * inv_r2, c1 = 2 * u * w * inv_r2, c2 = w * w * inv_r2;
  const double s = r2 * inv_radius2, root = std::sqrt(s + eps);
  weight = g * s / (root * root * root * root * root);
}

}  // namespace geomfit
