#pragma once
// The per-vertex membrane model of §6.1-6.2 on the derivatives of the reference (x) and
// deformed (y) positions in the reference fit's frame (u, v) (the convected coordinates):
// both surfaces are parametrized by the same (u, v), their derivatives come from the same
// reference stencil. Templated on the scalar so that the pressure-load solve can take its
// exact local Jacobian by forward-mode automatic differentiation.
//
//   G = J_ref^T J_ref, g = J_def^T J_def,
//   E^ = G^{-1} (g - G) / 2            Green strain (6.1.5) in the (u, v) basis: J_ref^+ eps* J_ref
//   tau^ = lambda* tr(E^) I + 2 mu E^  (6.2.8), lambda* of (6.1.14)
//   S = tau^ g^{-1} = lambda* tr(E^) g^{-1} + mu (G^{-1} - g^{-1})   (symmetric)
//   sigma = J_def tau^ J_def^+ = J_def S J_def^T                    (6.1.13)
//   W = -g^{-1} b, b_ab = n . y_ab     (positive when convex)
//   p = tr(W tau^) = -n . div sigma    (6.2.9)-(6.2.10)
#include <Eigen/Core>

namespace geomfit {
namespace mechanics_internal {

template <typename T>
using V3 = Eigen::Matrix<T, 3, 1>;
template <typename T>
using M2 = Eigen::Matrix<T, 2, 2>;

/// First and second derivatives of a position field along the frame (u, v) of a vertex.
template <typename T>
struct Jet5 {
  V3<T> d[5];  ///< u, v, uu, uv, vv
  const V3<T>& Second(int a, int c) const { return d[2 + a + c]; }
};

template <typename T>
M2<T> Metric(const Jet5<T>& y) {
  M2<T> g;
  g(0, 0) = y.d[0].dot(y.d[0]);
  g(0, 1) = g(1, 0) = y.d[0].dot(y.d[1]);
  g(1, 1) = y.d[1].dot(y.d[1]);
  return g;
}

/// d g_ab / d c = y_ac . y_b + y_a . y_bc
template <typename T>
M2<T> MetricDerivative(const Jet5<T>& y, int c) {
  M2<T> dg;
  for (int a = 0; a < 2; ++a)
    for (int b = 0; b < 2; ++b) dg(a, b) = y.Second(a, c).dot(y.d[b]) + y.d[a].dot(y.Second(b, c));
  return dg;
}

template <typename T>
M2<T> Inverse2(const M2<T>& m) {
  const T det = m(0, 0) * m(1, 1) - m(0, 1) * m(1, 0);
  M2<T> r;
  r << m(1, 1) / det, -m(0, 1) / det, -m(1, 0) / det, m(0, 0) / det;
  return r;
}

/// The reference side of a vertex, fixed during a solve.
struct ReferenceGeometry {
  Jet5<double> x;
  Eigen::Matrix2d G, Ginv, dG[2], dGinv[2];
};

inline ReferenceGeometry MakeReference(const Jet5<double>& x) {
  ReferenceGeometry r;
  r.x = x;
  r.G = Metric(x);
  r.Ginv = Inverse2<double>(r.G);
  for (int c = 0; c < 2; ++c) {
    r.dG[c] = MetricDerivative(x, c);
    r.dGinv[c] = -r.Ginv * r.dG[c] * r.Ginv;
  }
  return r;
}

/// Membrane state at a vertex: metric, strain, stress in the (u, v) basis, normal.
template <typename T>
struct MembraneState {
  M2<T> g, ginv, strain, tau, S;
  T tr_strain;
  V3<T> normal;
};

template <typename T>
MembraneState<T> State(const ReferenceGeometry& ref, const Jet5<T>& y, double lambda, double mu) {
  MembraneState<T> s;
  s.g = Metric(y);
  s.ginv = Inverse2<T>(s.g);
  const M2<T> Gi = ref.Ginv.template cast<T>();
  s.strain = Gi * (s.g - ref.G.template cast<T>()) * T(0.5);
  s.tr_strain = s.strain.trace();
  s.tau = s.strain * T(2 * mu);
  s.tau(0, 0) += lambda * s.tr_strain;
  s.tau(1, 1) += lambda * s.tr_strain;
  s.S = s.ginv * (lambda * s.tr_strain) + (Gi - s.ginv) * T(mu);
  s.normal = y.d[0].cross(y.d[1]);
  s.normal /= s.normal.norm();
  return s;
}

/// Interface pressure p = tr(W tau^) (6.2.10), inside minus outside.
template <typename T>
T InterfacePressureAt(const MembraneState<T>& s, const Jet5<T>& y) {
  T p = T(0);  // tr(W tau^) = -tr(b S)
  for (int a = 0; a < 2; ++a)
    for (int c = 0; c < 2; ++c) p -= s.normal.dot(y.Second(a, c)) * s.S(a, c);
  return p;
}

/// div sigma (6.2.1) with sigma = y_a S^{ab} y_b^T: sum_c (d_c sigma) y^c
///   = y_ac S^{ac} + y_a (d_b S^{ab} + S^{ab} Gamma^c_{bc}),  Gamma^c_{bc} = y_bc . y^c.
template <typename T>
V3<T> StressDivergence(const ReferenceGeometry& ref, const MembraneState<T>& s, const Jet5<T>& y,
                       double lambda, double mu) {
  const M2<T> Gi = ref.Ginv.template cast<T>();
  M2<T> dS[2];
  for (int c = 0; c < 2; ++c) {
    const M2<T> dg = MetricDerivative(y, c);
    const M2<T> dginv = -s.ginv * dg * s.ginv;
    const M2<T> dGi = ref.dGinv[c].template cast<T>();
    const T dtr =
        T(0.5) * ((dGi * (s.g - ref.G.template cast<T>())).trace() + (Gi * (dg - ref.dG[c].template cast<T>())).trace());
    dS[c] = s.ginv * (lambda * dtr) + dginv * (lambda * s.tr_strain) + (dGi - dginv) * T(mu);
  }
  V3<T> dual[2];
  for (int c = 0; c < 2; ++c) dual[c] = y.d[0] * s.ginv(c, 0) + y.d[1] * s.ginv(c, 1);
  T gamma[2];
  for (int b = 0; b < 2; ++b) gamma[b] = y.Second(b, 0).dot(dual[0]) + y.Second(b, 1).dot(dual[1]);
  V3<T> div = V3<T>::Zero();
  for (int a = 0; a < 2; ++a) {
    for (int c = 0; c < 2; ++c) div += y.Second(a, c) * s.S(a, c);
    const T coef = dS[0](a, 0) + dS[1](a, 1) + s.S(a, 0) * gamma[0] + s.S(a, 1) * gamma[1];
    div += y.d[a] * coef;
  }
  return div;
}

}  // namespace mechanics_internal
}  // namespace geomfit
