#include "core/fitting/slopes.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/util/parallel.h"

namespace geomfit {
namespace {

inline double Dot(const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// Solves the symmetric positive definite N x N system (upper triangle of `a` used) in place
// by Cholesky; false when a pivot is not positive relative to the diagonal (`rel`).
template <int N>
bool SolveSpd(double (&a)[N][N], double (&b)[N], double rel) {
  double scale = 0;
  for (int i = 0; i < N; ++i) scale = std::max(scale, a[i][i]);
  if (!(scale > 0)) return false;
  for (int k = 0; k < N; ++k) {
    double d = a[k][k];
    for (int p = 0; p < k; ++p) d -= a[p][k] * a[p][k];
    if (!(d > rel * scale)) return false;
    const double r = std::sqrt(d);
    a[k][k] = r;
    for (int j = k + 1; j < N; ++j) {
      double s = a[k][j];
      for (int p = 0; p < k; ++p) s -= a[p][k] * a[p][j];
      a[k][j] = s / r;
    }
  }
  for (int k = 0; k < N; ++k) {  // R^T y = b
    double s = b[k];
    for (int p = 0; p < k; ++p) s -= a[p][k] * b[p];
    b[k] = s / a[k][k];
  }
  for (int k = N - 1; k >= 0; --k) {  // R x = y
    double s = b[k];
    for (int p = k + 1; p < N; ++p) s -= a[k][p] * b[p];
    b[k] = s / a[k][k];
  }
  return true;
}

// Positions and normals of every vertex, 6 doubles each, in visiting order (slot).
struct Slots {
  std::vector<double> xn;     // x, y, z, nx, ny, nz per slot
  std::vector<int32_t> slot;  // slot of each vertex
  const double* At(int v) const { return xn.data() + 6 * static_cast<int64_t>(slot[v]); }
  double* At(int v) { return xn.data() + 6 * static_cast<int64_t>(slot[v]); }
};

// Pass 1 at vertex v (see slopes.h): the refined normal, written to `out` (3 doubles), and
// the stencil's squared radius; false (out untouched) when the fit is ill-posed. The 5x5
// normal equations are built from the 12 moments of (u, w) of degrees 2-4.
__attribute__((always_inline)) inline bool SlopeNormal(int v, const Neighborhoods& nb, const Slots& s, double cos_cut,
                                                       double* out, double* radius2) {
  const int32_t* pts = nb.Points(v);
  const int n = nb.Size(v);
  const double* self = s.At(v);
  const LocalFrame fr = FrameFromNormal(Eigen::Vector3d(self[0], self[1], self[2]),
                                        Eigen::Vector3d(self[3], self[4], self[5]));
  const double t1[3] = {fr.t1[0], fr.t1[1], fr.t1[2]}, t2[3] = {fr.t2[0], fr.t2[1], fr.t2[2]};
  const double* m = self + 3;
  double m20 = 0, m11 = 0, m02 = 0, m30 = 0, m21 = 0, m12 = 0, m03 = 0, m40 = 0, m31 = 0, m22 = 0, m13 = 0, m04 = 0;
  double b0 = 0, b1 = 0, b2 = 0, b3 = 0, b4 = 0;
  double r2max = 0, scale = 0;
  for (int i = 1; i < n; ++i) {
    const double* q = s.At(pts[i]);
    const double d[3] = {q[0] - self[0], q[1] - self[1], q[2] - self[2]};
    if (scale == 0) {  // lengths in units of the first neighbour's distance (conditioning)
      const double l2 = Dot(d, d);
      if (l2 == 0) continue;
      scale = 1 / std::sqrt(l2);
    }
    const double nm = Dot(q + 3, m);
    if (!(nm >= cos_cut)) continue;
    const double u = Dot(d, t1) * scale, w = Dot(d, t2) * scale, h = Dot(d, m) * scale;
    const double r2 = u * u + w * w;
    r2max = std::max(r2max, r2);
    // h - p.G / 3 with G = -(n.t1, n.t2) / n.m
    const double rhs = h + (u * Dot(q + 3, t1) + w * Dot(q + 3, t2)) / (3 * nm);
    const double wt = nm / (r2 + 0.01);  // (2.2.1)'s degree-2 weights, squared
    const double uu = u * u, uw = u * w, ww = w * w;
    const double wu = wt * u, wv = wt * w, wuu = wt * uu, wuw = wt * uw, www = wt * ww;
    m20 += wu * u, m11 += wu * w, m02 += wv * w;
    m30 += wuu * u, m21 += wuu * w, m12 += wuw * w, m03 += www * w;
    m40 += wuu * uu, m31 += wuu * uw, m22 += wuu * ww, m13 += wuw * ww, m04 += www * ww;
    b0 += wu * rhs, b1 += wv * rhs, b2 += wuu * rhs, b3 += wuw * rhs, b4 += www * rhs;
  }
  if (r2max == 0) return false;
  // Columns u, w, u^2/2, uw, w^2/2 (Taylor).
  double a[5][5] = {{m20, m11, 0.5 * m30, m21, 0.5 * m12},
                    {0, m02, 0.5 * m21, m12, 0.5 * m03},
                    {0, 0, 0.25 * m40, 0.5 * m31, 0.25 * m22},
                    {0, 0, 0, m22, 0.5 * m13},
                    {0, 0, 0, 0, 0.25 * m04}};
  double b[5] = {b0, b1, 0.5 * b2, b3, 0.5 * b4};
  if (!SolveSpd<5>(a, b, 1e-10)) return false;
  // The fitted linear term itself (2/3 of the gradient it estimates): see slopes.h.
  double nn[3];
  for (int c = 0; c < 3; ++c) nn[c] = m[c] - b[0] * t1[c] - b[1] * t2[c];
  const double len = std::sqrt(Dot(nn, nn));
  if (!(len > 0) || !std::isfinite(len)) return false;
  for (int c = 0; c < 3; ++c) out[c] = nn[c] / len;
  *radius2 = r2max / (scale * scale);
  return true;
}

// Pass 2 at vertex v: the Hermite Hessian (c20, c11, c02) in `fr`, the refined frame;
// false when the directions are too few or too clustered.
__attribute__((always_inline)) inline bool HermiteHessian(int v, const Neighborhoods& nb, const Slots& s,
                                                          const LocalFrame& fr, double radius2, double cos_cut,
                                                          double* hess) {
  const int32_t* pts = nb.Points(v);
  const int n = nb.Size(v);
  const double* self = s.At(v);
  const double t1[3] = {fr.t1[0], fr.t1[1], fr.t1[2]}, t2[3] = {fr.t2[0], fr.t2[1], fr.t2[2]},
               m[3] = {fr.normal[0], fr.normal[1], fr.normal[2]};
  // Row weights s / (s + 0.1)^2.5 in s = r^2 / radius^2, as FitOptions::hermite_hessian.
  constexpr double kEps = 0.1;
  const double inv_radius2 = 1 / radius2;
  double a00 = 0, a01 = 0, a02 = 0, a11 = 0, a12 = 0, a22 = 0, b0 = 0, b1 = 0, b2 = 0;
  for (int i = 1; i < n; ++i) {
    const double* q = s.At(pts[i]);
    const double d[3] = {q[0] - self[0], q[1] - self[1], q[2] - self[2]};
    const double nm = Dot(q + 3, m);
    if (!(nm >= cos_cut)) continue;
    const double u = Dot(d, t1), w = Dot(d, t2), h = Dot(d, m), r2 = u * u + w * w;
    if (r2 == 0) continue;
    const double inv = 1 / (nm * r2);
    // (4 h - (f_u u + f_v w)) / r^2 with (f_u, f_v) = -(n.t1, n.t2) / n.m
    const double val = (4 * h * nm + (Dot(q + 3, t1) * u + Dot(q + 3, t2) * w)) * inv;
    const double inv_r2 = nm * inv;
    const double c0 = u * u * inv_r2, c1 = 2 * u * w * inv_r2, c2 = w * w * inv_r2;
    const double sr = r2 * inv_radius2, root = std::sqrt(sr + kEps);
    const double wt = nm * sr / (root * root * root * root * root);
    const double w0 = wt * c0, w1 = wt * c1, w2 = wt * c2;
    a00 += w0 * c0, a01 += w0 * c1, a02 += w0 * c2, a11 += w1 * c1, a12 += w1 * c2, a22 += w2 * c2;
    b0 += w0 * val, b1 += w1 * val, b2 += w2 * val;
  }
  double a[3][3] = {{a00, a01, a02}, {0, a11, a12}, {0, 0, a22}};
  double b[3] = {b0, b1, b2};
  if (!SolveSpd<3>(a, b, 1e-3)) return false;
  for (int k = 0; k < 3; ++k) hess[k] = b[k];
  return true;
}

// Everything the passes read and write; slots k in [0, nv) in visiting order.
struct Passes {
  const Neighborhoods& nb;
  const Slots& s;
  const int32_t* order;  // vertex at slot k (null: k)
  const VertexDiagnostics* diag;
  double cos_cut;
  double* refined;  // 3 per slot
  double* radius2;  // per slot
  LocalFrame* frames;
  double* coefficients;  // 6 per vertex
  int Vertex(int64_t k) const { return order ? order[k] : static_cast<int>(k); }
  // The stencil slots of the vertex at slot k + ahead, into cache.
  void Prefetch(int64_t k, int64_t end) const {
    if (k + 8 < end) {
      const int32_t* p = nb.Points(Vertex(k + 8));
      __builtin_prefetch(p);
      __builtin_prefetch(p + 16);
    }
    if (k + 4 < end) {
      const int w = Vertex(k + 4);
      const int32_t* p = nb.Points(w);
      for (int i = 0, n = nb.Size(w); i < n; ++i) __builtin_prefetch(s.slot.data() + p[i]);
    }
    if (k + 2 < end) {  // and their positions and normals
      const int w = Vertex(k + 2);
      const int32_t* p = nb.Points(w);
      for (int i = 0, n = nb.Size(w); i < n; ++i) {
        const double* q = s.xn.data() + 6 * static_cast<int64_t>(s.slot[p[i]]);
        __builtin_prefetch(q);
        __builtin_prefetch(q + 5);
      }
    }
  }
};

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void NormalsRange(const Passes& P, int64_t k0,
                                                                                       int64_t k1) {
  for (int64_t k = k0; k < k1; ++k) {
    P.Prefetch(k, k1);
    const int v = P.Vertex(k);
    double* out = P.refined + 3 * k;
    const double* own = P.s.xn.data() + 6 * k + 3;
    if (!(P.diag[v].degree_used >= 2) || !SlopeNormal(v, P.nb, P.s, P.cos_cut, out, &P.radius2[k]))
      out[0] = own[0], out[1] = own[1], out[2] = own[2];
  }
}

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void HessiansRange(const Passes& P, int64_t k0,
                                                                                        int64_t k1) {
  constexpr int kCoef = 6;  // NumCoefficients(2)
  for (int64_t k = k0; k < k1; ++k) {
    P.Prefetch(k, k1);
    const int v = P.Vertex(k);
    if (!(P.diag[v].degree_used >= 2)) continue;
    const double* self = P.s.xn.data() + 6 * k;
    const LocalFrame fr = FrameFromNormal(Eigen::Vector3d(self[0], self[1], self[2]),
                                          Eigen::Vector3d(self[3], self[4], self[5]));
    double* c = P.coefficients + static_cast<int64_t>(v) * kCoef;
    double hess[3];
    if (P.radius2[k] > 0 && HermiteHessian(v, P.nb, P.s, fr, P.radius2[k], P.cos_cut, hess))
      c[TaylorIndex(2, 0)] = hess[0], c[TaylorIndex(1, 1)] = hess[1], c[TaylorIndex(0, 2)] = hess[2];
    c[TaylorIndex(1, 0)] = c[TaylorIndex(0, 1)] = 0;
    P.frames[v] = fr;
  }
}

}  // namespace

void RefineSlopes(const Mesh& mesh, const Topology& topo, const Neighborhoods& nb, double cos_cut, int threads,
                  const VertexDiagnostics* diagnostics, LocalFrame* frames, double* coefficients) {
  const int nv = mesh.NumVertices();
  constexpr int kCoef = 6;  // NumCoefficients(2)
  const bool local = static_cast<int>(topo.locality_order.size()) == nv;
  auto vertex_at = [&](int64_t k) { return local ? topo.locality_order[k] : static_cast<int32_t>(k); };
  // Positions and the plain fits' normals, in visiting order.
  Slots s;
  s.xn.resize(6 * static_cast<size_t>(nv));
  s.slot.resize(nv);
  ParallelFor(nv, threads, [&](int64_t k) {
    const int v = vertex_at(k);
    s.slot[v] = static_cast<int32_t>(k);
    double* dst = s.xn.data() + 6 * k;
    const LocalFrame& fr = frames[v];
    const double* c = coefficients + static_cast<int64_t>(v) * kCoef;
    const Eigen::Vector3d n = (fr.normal - c[TaylorIndex(1, 0)] * fr.t1 - c[TaylorIndex(0, 1)] * fr.t2).normalized();
    for (int i = 0; i < 3; ++i) dst[i] = mesh.positions(v, i), dst[3 + i] = n[i];
  }, 4096);
  // Pass 1: refined normals (into a copy: every vertex reads its neighbours' plain ones).
  std::vector<double> refined(3 * static_cast<size_t>(nv));
  std::vector<double> radius2(nv, 0.0);
  const Passes P{nb, s, local ? topo.locality_order.data() : nullptr, diagnostics, cos_cut,
                 refined.data(), radius2.data(), frames, coefficients};
  constexpr int64_t kGrain = 1024;
  const int64_t chunks = (nv + kGrain - 1) / kGrain;
  ParallelFor(chunks, threads, [&](int64_t c) { NormalsRange(P, c * kGrain, std::min<int64_t>(nv, (c + 1) * kGrain)); }, 1);
  ParallelFor(nv, threads, [&](int64_t k) {
    for (int i = 0; i < 3; ++i) s.xn[6 * k + 3 + i] = refined[3 * k + i];
  }, 4096);
  // Pass 2: frames of the refined normals, Hermite Hessians.
  ParallelFor(chunks, threads, [&](int64_t c) { HessiansRange(P, c * kGrain, std::min<int64_t>(nv, (c + 1) * kGrain)); }, 1);
}

}  // namespace geomfit
