#include "core/fitting/slopes.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

inline double Dot(const double* a, const double* b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

// Solves the symmetric positive definite N x N system (upper triangle of `a` used) in place
// by Cholesky; false when a pivot is not positive relative to the diagonal (`rel`).
template <int N>
__attribute__((always_inline)) inline bool SolveSpd(double (&a)[N][N], double (&b)[N], double rel) {
  double scale = 0;
  for (int i = 0; i < N; ++i) scale = std::max(scale, a[i][i]);
  if (!(scale > 0)) return false;
  double inv[N];  // 1 / R_kk
  for (int k = 0; k < N; ++k) {
    double d = a[k][k];
    for (int p = 0; p < k; ++p) d -= a[p][k] * a[p][k];
    if (!(d > rel * scale)) return false;
    inv[k] = 1 / std::sqrt(d);
    for (int j = k + 1; j < N; ++j) {
      double s = a[k][j];
      for (int p = 0; p < k; ++p) s -= a[p][k] * a[p][j];
      a[k][j] = s * inv[k];
    }
  }
  for (int k = 0; k < N; ++k) {  // R^T y = b
    double s = b[k];
    for (int p = 0; p < k; ++p) s -= a[p][k] * b[p];
    b[k] = s * inv[k];
  }
  for (int k = N - 1; k >= 0; --k) {  // R x = y
    double s = b[k];
    for (int p = k + 1; p < N; ++p) s -= a[k][p] * b[p];
    b[k] = s * inv[k];
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

// A stencil's points relative to its centre (d) and their normals (n), in lanes of
// kLanes: the passes below run on whole lanes (vector instructions) and sum each lane
// separately, then the lanes in a fixed order, so every instruction set gives the same bits.
constexpr int kLanes = 8;
struct alignas(64) Stencil {
  int count = 0;  // points (the centre excluded)
  double dx[kMaxStencil + kLanes], dy[kMaxStencil + kLanes], dz[kMaxStencil + kLanes];
  double nx[kMaxStencil + kLanes], ny[kMaxStencil + kLanes], nz[kMaxStencil + kLanes];
  double live[kMaxStencil + kLanes];  // 1 for the points, 0 for the padding
};

__attribute__((always_inline)) inline void Gather(int v, const Neighborhoods& nb, const Slots& s, Stencil& st) {
  const int32_t* pts = nb.Points(v);
  const int n = std::min(nb.Size(v), kMaxStencil);
  const double* self = s.At(v);
  st.count = n - 1;
  for (int i = 1; i < n; ++i) {
    const double* q = s.At(pts[i]);
    st.dx[i - 1] = q[0] - self[0], st.dy[i - 1] = q[1] - self[1], st.dz[i - 1] = q[2] - self[2];
    st.nx[i - 1] = q[3], st.ny[i - 1] = q[4], st.nz[i - 1] = q[5], st.live[i - 1] = 1;
  }
  for (int i = n - 1; i < (n - 1 + kLanes - 1) / kLanes * kLanes; ++i)
    st.dx[i] = st.dy[i] = st.dz[i] = st.nx[i] = st.ny[i] = st.nz[i] = st.live[i] = 0;
}

// Sum of the kLanes partial sums, in a fixed order.
inline double LaneSum(const double* a) {
  return ((a[0] + a[4]) + (a[2] + a[6])) + ((a[1] + a[5]) + (a[3] + a[7]));
}

// Pass 1 at vertex v (see slopes.h): the refined normal, written to `out` (3 doubles), and
// the stencil's squared radius; false (out untouched) when the fit is ill-posed. The 5x5
// normal equations are built from the 12 moments of (u, w) of degrees 2-4.
__attribute__((always_inline)) inline bool SlopeNormal(const double* self, const Stencil& st, double cos_cut,
                                                       double* out, double* radius2) {
  const LocalFrame fr = FrameFromNormal(Eigen::Vector3d(self[0], self[1], self[2]),
                                        Eigen::Vector3d(self[3], self[4], self[5]));
  const double t1x = fr.t1[0], t1y = fr.t1[1], t1z = fr.t1[2], t2x = fr.t2[0], t2y = fr.t2[1], t2z = fr.t2[2];
  const double mx = self[3], my = self[4], mz = self[5];
  double scale = 0;  // lengths in units of the first neighbour's distance (conditioning)
  for (int i = 0; i < st.count && scale == 0; ++i) {
    const double l2 = st.dx[i] * st.dx[i] + st.dy[i] * st.dy[i] + st.dz[i] * st.dz[i];
    if (l2 > 0) scale = 1 / std::sqrt(l2);
  }
  if (scale == 0) return false;
  enum { k20, k11, k02, k30, k21, k12, k03, k40, k31, k22, k13, k04, kb0, kb1, kb2, kb3, kb4, kSums };
  alignas(64) double acc[kSums][kLanes] = {};
  alignas(64) double r2max[kLanes] = {};
  for (int b = 0; b < st.count; b += kLanes) {
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) {
      const int i = b + l;
      const double dx = st.dx[i], dy = st.dy[i], dz = st.dz[i], nx = st.nx[i], ny = st.ny[i], nz = st.nz[i];
      const double nm = nx * mx + ny * my + nz * mz;
      const double ok = nm >= cos_cut ? st.live[i] : 0.0;  // the safeguard gamma of (2.2.1), 0 or 1
      const double u = (dx * t1x + dy * t1y + dz * t1z) * scale, w = (dx * t2x + dy * t2y + dz * t2z) * scale,
                   h = (dx * mx + dy * my + dz * mz) * scale;
      const double r2 = u * u + w * w;
      // h - p.G / 3 with G = -(n.t1, n.t2) / n.m
      const double rhs = h + (u * (nx * t1x + ny * t1y + nz * t1z) + w * (nx * t2x + ny * t2y + nz * t2z)) /
                                 (3 * (ok > 0 ? nm : 1.0));
      const double wt = ok * nm / (r2 + 0.01);  // (2.2.1)'s degree-2 weights, squared
      r2max[l] = std::max(r2max[l], ok * r2);
      const double uu = u * u, uw = u * w, ww = w * w;
      const double wu = wt * u, wv = wt * w, wuu = wt * uu, wuw = wt * uw, www = wt * ww;
      acc[k20][l] += wu * u, acc[k11][l] += wu * w, acc[k02][l] += wv * w;
      acc[k30][l] += wuu * u, acc[k21][l] += wuu * w, acc[k12][l] += wuw * w, acc[k03][l] += www * w;
      acc[k40][l] += wuu * uu, acc[k31][l] += wuu * uw, acc[k22][l] += wuu * ww, acc[k13][l] += wuw * ww;
      acc[k04][l] += www * ww;
      acc[kb0][l] += wu * rhs, acc[kb1][l] += wv * rhs, acc[kb2][l] += wuu * rhs, acc[kb3][l] += wuw * rhs;
      acc[kb4][l] += www * rhs;
    }
  }
  double r2m = 0;
  for (int l = 0; l < kLanes; ++l) r2m = std::max(r2m, r2max[l]);
  if (r2m == 0) return false;
  double m[kSums];
  for (int k = 0; k < kSums; ++k) m[k] = LaneSum(acc[k]);
  // Columns u, w, u^2/2, uw, w^2/2 (Taylor).
  double a[5][5] = {{m[k20], m[k11], 0.5 * m[k30], m[k21], 0.5 * m[k12]},
                    {0, m[k02], 0.5 * m[k21], m[k12], 0.5 * m[k03]},
                    {0, 0, 0.25 * m[k40], 0.5 * m[k31], 0.25 * m[k22]},
                    {0, 0, 0, m[k22], 0.5 * m[k13]},
                    {0, 0, 0, 0, 0.25 * m[k04]}};
  double rhs[5] = {m[kb0], m[kb1], 0.5 * m[kb2], m[kb3], 0.5 * m[kb4]};
  if (!SolveSpd<5>(a, rhs, 1e-10)) return false;
  // The fitted linear term itself (2/3 of the gradient it estimates): see slopes.h.
  const double nn[3] = {mx - rhs[0] * t1x - rhs[1] * t2x, my - rhs[0] * t1y - rhs[1] * t2y,
                        mz - rhs[0] * t1z - rhs[1] * t2z};
  const double len = std::sqrt(Dot(nn, nn));
  if (!(len > 0) || !std::isfinite(len)) return false;
  for (int c = 0; c < 3; ++c) out[c] = nn[c] / len;
  *radius2 = r2m / (scale * scale);
  return true;
}

// Pass 2 at a vertex: the Hermite Hessian (c20, c11, c02) in `fr`, the refined frame;
// false when the directions are too few or too clustered.
__attribute__((always_inline)) inline bool HermiteHessian(const Stencil& st, const LocalFrame& fr, double radius2,
                                                          double cos_cut, double* hess) {
  const double t1x = fr.t1[0], t1y = fr.t1[1], t1z = fr.t1[2], t2x = fr.t2[0], t2y = fr.t2[1], t2z = fr.t2[2];
  const double mx = fr.normal[0], my = fr.normal[1], mz = fr.normal[2];
  // Row weights s / (s + 0.1)^2.5 in s = r^2 / radius^2, as FitOptions::hermite_hessian.
  constexpr double kEps = 0.1;
  const double inv_radius2 = 1 / radius2;
  enum { a00, a01, a02, a11, a12, a22, b0, b1, b2, kSums };
  alignas(64) double acc[kSums][kLanes] = {};
  for (int b = 0; b < st.count; b += kLanes) {
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) {
      const int i = b + l;
      const double dx = st.dx[i], dy = st.dy[i], dz = st.dz[i], nx = st.nx[i], ny = st.ny[i], nz = st.nz[i];
      const double nm = nx * mx + ny * my + nz * mz;
      const double u = dx * t1x + dy * t1y + dz * t1z, w = dx * t2x + dy * t2y + dz * t2z,
                   h = dx * mx + dy * my + dz * mz, r2 = u * u + w * w;
      const double ok = nm >= cos_cut && r2 > 0 ? st.live[i] : 0.0;
      const double inv = 1 / (ok > 0 ? nm * r2 : 1.0);
      // (4 h - (f_u u + f_v w)) / r^2 with (f_u, f_v) = -(n.t1, n.t2) / n.m
      const double val = (4 * h * nm + ((nx * t1x + ny * t1y + nz * t1z) * u + (nx * t2x + ny * t2y + nz * t2z) * w)) * inv;
      const double inv_r2 = nm * inv;
      const double c0 = u * u * inv_r2, c1 = 2 * u * w * inv_r2, c2 = w * w * inv_r2;
      const double sr = r2 * inv_radius2, root = std::sqrt(sr + kEps);
      const double wt = ok * nm * sr / (root * root * root * root * root);
      const double w0 = wt * c0, w1 = wt * c1, w2 = wt * c2;
      acc[a00][l] += w0 * c0, acc[a01][l] += w0 * c1, acc[a02][l] += w0 * c2;
      acc[a11][l] += w1 * c1, acc[a12][l] += w1 * c2, acc[a22][l] += w2 * c2;
      acc[b0][l] += w0 * val, acc[b1][l] += w1 * val, acc[b2][l] += w2 * val;
    }
  }
  double m[kSums];
  for (int k = 0; k < kSums; ++k) m[k] = LaneSum(acc[k]);
  double a[3][3] = {{m[a00], m[a01], m[a02]}, {0, m[a11], m[a12]}, {0, 0, m[a22]}};
  double rhs[3] = {m[b0], m[b1], m[b2]};
  if (!SolveSpd<3>(a, rhs, 1e-3)) return false;
  for (int k = 0; k < 3; ++k) hess[k] = rhs[k];
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
  Stencil st;
  for (int64_t k = k0; k < k1; ++k) {
    P.Prefetch(k, k1);
    const int v = P.Vertex(k);
    double* out = P.refined + 3 * k;
    const double* self = P.s.xn.data() + 6 * k;
    bool ok = P.diag[v].degree_used >= 2;
    if (ok) {
      Gather(v, P.nb, P.s, st);
      ok = SlopeNormal(self, st, P.cos_cut, out, &P.radius2[k]);
    }
    if (!ok) out[0] = self[3], out[1] = self[4], out[2] = self[5];
  }
}

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void HessiansRange(const Passes& P, int64_t k0,
                                                                                        int64_t k1) {
  constexpr int kCoef = 6;  // NumCoefficients(2)
  Stencil st;
  for (int64_t k = k0; k < k1; ++k) {
    P.Prefetch(k, k1);
    const int v = P.Vertex(k);
    if (!(P.diag[v].degree_used >= 2)) continue;
    const double* self = P.s.xn.data() + 6 * k;
    const LocalFrame fr = FrameFromNormal(Eigen::Vector3d(self[0], self[1], self[2]),
                                          Eigen::Vector3d(self[3], self[4], self[5]));
    double* c = P.coefficients + static_cast<int64_t>(v) * kCoef;
    double hess[3];
    bool ok = P.radius2[k] > 0;
    if (ok) {
      Gather(v, P.nb, P.s, st);
      ok = HermiteHessian(st, fr, P.radius2[k], P.cos_cut, hess);
    }
    if (ok)
      c[TaylorIndex(2, 0)] = hess[0], c[TaylorIndex(1, 1)] = hess[1], c[TaylorIndex(0, 2)] = hess[2];
    c[TaylorIndex(1, 0)] = c[TaylorIndex(0, 1)] = 0;
    P.frames[v] = fr;
  }
}

}  // namespace

absl::Status RefineSlopes(const Mesh& mesh, const Topology& topo, const Neighborhoods& nb, double cos_cut, int passes,
                          const RunContext& ctx, const VertexDiagnostics* diagnostics, LocalFrame* frames,
                          double* coefficients) {
  const int threads = ctx.threads();
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
  // Normal passes (into a copy: every vertex reads its neighbours' previous normals).
  std::vector<double> refined(3 * static_cast<size_t>(nv));
  std::vector<double> radius2(nv, 0.0);
  const Passes P{nb, s, local ? topo.locality_order.data() : nullptr, diagnostics, cos_cut,
                 refined.data(), radius2.data(), frames, coefficients};
  constexpr int64_t kGrain = 1024;
  const int64_t chunks = (nv + kGrain - 1) / kGrain;
  for (int pass = 0; pass < passes; ++pass) {
    GF_RETURN_IF_ERROR(ParallelFor(
        chunks, ctx, [&](int64_t c) { NormalsRange(P, c * kGrain, std::min<int64_t>(nv, (c + 1) * kGrain)); }, 1));
    ParallelFor(nv, threads, [&](int64_t k) {
      for (int i = 0; i < 3; ++i) s.xn[6 * k + 3 + i] = refined[3 * k + i];
    }, 4096);
  }
  // Pass 2: frames of the refined normals, Hermite Hessians.
  return ParallelFor(
      chunks, ctx, [&](int64_t c) { HessiansRange(P, c * kGrain, std::min<int64_t>(nv, (c + 1) * kGrain)); }, 1);
}

}  // namespace geomfit
