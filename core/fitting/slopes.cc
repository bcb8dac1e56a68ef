#include "core/fitting/slopes.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <vector>

#include "core/fitting/hermite.h"
#include "core/fitting/record_lanes.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

// The passes run kLanes vertices at a time, one per vector lane: each lane sums its own
// stencil's rows in stencil order and solves its own system, so a vertex's result does
// not depend on its batch or on the instruction set (no fused multiply-adds,
// core/CMakeLists.txt).
constexpr int kLanes = 8;
// One slot's record in the normal copies: one aligned 64-byte line, read whole by a row's
// gather. kRadius2: the stencil's squared radius from the last normal pass (0: the pass
// failed); kFitted: 1 for a degree-2 fit to refine, else 0. After the Hessian pass the
// other copy holds per slot (c20, c11, c02, ok, the refined normal, kFitted).
constexpr int kRec = 8, kRadius2 = 6, kFitted = 7;
// Work::centre's doubles per slot: the frame normal, then the fit's derivatives of degree 3..5
// in Taylor order (f30 f21 f12 f03, f40 .. f04, f50 .. f05; those above the fit's degree absent).
constexpr int kMaxJet = 15;
using Lanes = double[kLanes];

// Solves kLanes symmetric positive definite N x N systems (upper triangles of `a` used,
// one per lane) in place by Cholesky; ok[l] = 0 where a pivot is not positive relative to
// the lane's largest diagonal entry (`rel`); such lanes' results are meaningless but finite.
template <int N>
__attribute__((always_inline)) inline void SolveSpdLanes(double (&a)[N][N][kLanes], double (&b)[N][kLanes],
                                                         double rel, Lanes& ok) {
  alignas(64) Lanes scale = {}, d, inv[N];  // inv: 1 / R_kk
#pragma GCC unroll 16
  for (int i = 0; i < N; ++i)
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) scale[l] = std::max(scale[l], a[i][i][l]);
#pragma GCC unroll 16
  for (int k = 0; k < N; ++k) {
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) d[l] = a[k][k][l];
#pragma GCC unroll 16
    for (int p = 0; p < k; ++p)
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) d[l] -= a[p][k][l] * a[p][k][l];
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) {
      const bool good = d[l] > rel * scale[l] && scale[l] > 0;
      ok[l] = good ? ok[l] : 0.0;
      inv[k][l] = 1 / std::sqrt(good ? d[l] : 1.0);
    }
#pragma GCC unroll 16
    for (int j = k + 1; j < N; ++j) {
#pragma GCC unroll 16
      for (int p = 0; p < k; ++p)
#pragma omp simd
        for (int l = 0; l < kLanes; ++l) a[k][j][l] -= a[p][k][l] * a[p][j][l];
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) a[k][j][l] *= inv[k][l];
    }
  }
#pragma GCC unroll 16
  for (int k = 0; k < N; ++k) {  // R^T y = b
#pragma GCC unroll 16
    for (int p = 0; p < k; ++p)
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) b[k][l] -= a[p][k][l] * b[p][l];
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) b[k][l] *= inv[k][l];
  }
#pragma GCC unroll 16
  for (int k = N - 1; k >= 0; --k) {  // R x = y
#pragma GCC unroll 16
    for (int p = k + 1; p < N; ++p)
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) b[k][l] -= a[k][p][l] * b[p][l];
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) b[k][l] *= inv[k][l];
  }
}

// The passes' work arrays, in visiting order (slot k: the k-th vertex visited).
struct Work {
  int64_t nv = 0;
  const int32_t* order = nullptr;    // vertex at each slot (null: the slot itself)
  const int32_t* offsets = nullptr;  // slot k's stencil: points[offsets[k] .. offsets[k+1]) as slots,
  const int32_t* points = nullptr;   //   centre first
  double* xn[2] = {};                // kRec doubles per slot; normals of the previous / next pass
  std::vector<int32_t> walk;         // the slots in batch order: each chunk's sorted by stencil size
  double cos_cut = 0;
  bool own_radius = false;           // no normal pass: the Hessian pass measures the stencils' radii
  double* centre = nullptr;          // with own_radius: per slot the fit's frame normal (the Hessians
                                     //   stay in the fits' frames) and derivatives of degree 3..`degree`
                                     //   (degree 3: the fit's cubic, then each normal pass's)
  double weight_epsilon = 0.01;      // the operator passes: eps of the fits' weights (2.2.1)
  int degree = 2;                    // the fits' degree (centre_stride = 3 + its derivatives of degree >= 3)
  int centre_stride = 0;
  // Degrees 4-5 (the jets): the fits read in place (frame normal, Hessian, derivatives of degree
  // 3..) instead of a copy in centre, and written in place by the Hessian pass (no second record copy).
  const LocalFrame* frames = nullptr;
  double* coefficients = nullptr;
  int num_coefficients = 0;
  int Vertex(int64_t k) const { return order ? order[k] : static_cast<int>(k); }
  int Size(int64_t k) const { return std::min(offsets[k + 1] - offsets[k], kMaxStencil); }
};

// kLanes doubles as one generic vector (one AVX-512 register; pairs / quads of narrower
// ones in the other clones).
typedef double V __attribute__((vector_size(kLanes * sizeof(double))));

// q[c] = component c (x y z nx ny nz) of the records of slots at[0..7], each one aligned
// line (record_lanes.h). Data movement only: exact.
__attribute__((always_inline)) inline void Transpose(const double* xn, const int32_t (&at)[kLanes], V* q) {
  static_assert(kLanes == 8, "TransposeRecords8 fills 8 lanes");
  const double* rec[kLanes];
  for (int l = 0; l < kLanes; ++l) rec[l] = xn + kRec * static_cast<int64_t>(at[l]);
  TransposeRecords8(rec, q);
}

// A batch of kLanes vertices: their centres, frames (FrameFromNormal's, in lanes) and
// stencils' rows, transposed (row i of every lane together, as the slot of the point).
// Lanes past `count`, and rows past a lane's stencil, name the centre with live = 0.
struct alignas(64) Batch {
  int count = 0, rows = 0;  // vertices; rows = the largest stencil less its centre
  int lanes = kLanes;       // (not a constant: GCC unrolls a constant 8 before vectorizing)
  const double* xn = nullptr;
  int32_t slot[kLanes];
  alignas(64) Lanes x, y, z, m[3], t1[3], t2[3];  // aligned: loaded as vectors
  alignas(64) Lanes g1, g2;  // the fitted gradient (c10, c01) in the frame (0 below degree 3)
  alignas(64) Lanes h2[3];   // the fit's Hessian (c20, c11, c02) with Work::coefficients, else 0
  alignas(64) Lanes f3[kMaxJet];  // the fit's derivatives of degree 3.. (f30 f21 f12 f03 ...; 0 below degree 3)
  int32_t idx[kMaxStencil][kLanes];
  alignas(64) Lanes dx[kMaxStencil], dy[kMaxStencil], dz[kMaxStencil], nx[kMaxStencil], ny[kMaxStencil], nz[kMaxStencil],
      live[kMaxStencil];

  __attribute__((always_inline)) void Load(const Work& W, const double* from, const int32_t* slots, int n) {
    xn = from, count = n, rows = 0;
    for (int l = 0; l < kLanes; ++l) {
      const int64_t k = slot[l] = slots[l < n ? l : 0];
      const double* self = xn + kRec * k;
      const double* fit = W.coefficients ? W.coefficients + W.num_coefficients * static_cast<int64_t>(W.Vertex(k)) : nullptr;
      const double* frame = W.centre ? W.centre + W.centre_stride * k : fit ? W.frames[W.Vertex(k)].normal.data() : self + 3;
      for (int c = 0; c < W.centre_stride - 3; ++c) f3[c][l] = fit ? fit[6 + c] : frame[3 + c];
      for (int c = 0; c < 3; ++c) h2[c][l] = fit ? fit[3 + c] : 0.0;
      for (int c = std::max(0, W.centre_stride - 3); c < 4; ++c) f3[c][l] = 0.0;
      x[l] = self[0], y[l] = self[1], z[l] = self[2], m[0][l] = frame[0], m[1][l] = frame[1], m[2][l] = frame[2];
      if (l < n) rows = std::max(rows, W.Size(k) - 1);
    }
#pragma omp simd
    for (int l = 0; l < kLanes; ++l)
      FrameTangents(m[0][l], m[1][l], m[2][l], t1[0][l], t1[1][l], t1[2][l], t2[0][l], t2[1][l], t2[2][l]);
    for (int l = 0; l < kLanes; ++l) {  // the record's (fitted) normal n in the frame: (c10, c01) = -(n.t1, n.t2) / n.m
      const double* nf = xn + kRec * static_cast<int64_t>(slot[l]) + 3;
      const double nm = nf[0] * m[0][l] + nf[1] * m[1][l] + nf[2] * m[2][l];
      const bool tilt = W.own_radius && nm > 0;
      g1[l] = tilt ? -(nf[0] * t1[0][l] + nf[1] * t1[1][l] + nf[2] * t1[2][l]) / nm : 0.0;
      g2[l] = tilt ? -(nf[0] * t2[0][l] + nf[1] * t2[1][l] + nf[2] * t2[2][l]) / nm : 0.0;
    }
    for (int l = 0; l < kLanes; ++l) {
      const int32_t* pts = W.points + W.offsets[slot[l]];
      const int size = l < n ? std::max(1, W.Size(slot[l])) : 1;
      for (int i = 1; i < size; ++i) idx[i - 1][l] = pts[i], live[i - 1][l] = 1;
      for (int i = size - 1; i < rows; ++i) idx[i][l] = slot[l], live[i][l] = 0;
    }
    // Row i's 8 records (one aligned line each) loaded whole and transposed in registers.
    const V cx = *reinterpret_cast<const V*>(x), cy = *reinterpret_cast<const V*>(y),
            cz = *reinterpret_cast<const V*>(z);
    for (int i = 0; i < rows; ++i) {
      V q[6];
      Transpose(xn, idx[i], q);
      *reinterpret_cast<V*>(dx[i]) = q[0] - cx, *reinterpret_cast<V*>(dy[i]) = q[1] - cy,
      *reinterpret_cast<V*>(dz[i]) = q[2] - cz;
      *reinterpret_cast<V*>(nx[i]) = q[3], *reinterpret_cast<V*>(ny[i]) = q[4], *reinterpret_cast<V*>(nz[i]) = q[5];
    }
  }
};

// Row i of lane l in the lane's frame: tangent coordinates (u, w), height h, and the
// point's normal's components nm = n.m, nt1 = n.t1, nt2 = n.t2. (Scalars, not a struct:
// struct locals in a simd loop keep GCC from vectorizing it.)
__attribute__((always_inline)) inline void Project(const Batch& B, int i, int l, double& u, double& w, double& h,
                                                   double& nm, double& nt1, double& nt2) {
  const double dx = B.dx[i][l], dy = B.dy[i][l], dz = B.dz[i][l], nx = B.nx[i][l], ny = B.ny[i][l], nz = B.nz[i][l];
  u = dx * B.t1[0][l] + dy * B.t1[1][l] + dz * B.t1[2][l];
  w = dx * B.t2[0][l] + dy * B.t2[1][l] + dz * B.t2[2][l];
  h = dx * B.m[0][l] + dy * B.m[1][l] + dz * B.m[2][l];
  nm = nx * B.m[0][l] + ny * B.m[1][l] + nz * B.m[2][l];
  nt1 = nx * B.t1[0][l] + ny * B.t1[1][l] + nz * B.t1[2][l];
  nt2 = nx * B.t2[0][l] + ny * B.t2[1][l] + nz * B.t2[2][l];
}

// The degree-2 normal passes' sums per lane: weighted moments u^p w^q (p + q = 2..4) and the
// right-hand side's against u, w, u^2, uw, w^2.
enum { k20, k11, k02, k30, k21, k12, k03, k40, k31, k22, k13, k04, kb0, kb1, kb2, kb3, kb4, kSums };

// Their normal equations in the columns u, w, u^2/2, uw, w^2/2 (Taylor; upper triangle).
__attribute__((always_inline)) inline void QuadraticSystem(const double (&acc)[kSums][kLanes], double (&a)[5][5][kLanes],
                                                           double (&b)[5][kLanes]) {
#pragma omp simd
  for (int l = 0; l < kLanes; ++l) {
    a[0][0][l] = acc[k20][l], a[0][1][l] = acc[k11][l], a[0][2][l] = 0.5 * acc[k30][l], a[0][3][l] = acc[k21][l],
    a[0][4][l] = 0.5 * acc[k12][l];
    a[1][1][l] = acc[k02][l], a[1][2][l] = 0.5 * acc[k21][l], a[1][3][l] = acc[k12][l], a[1][4][l] = 0.5 * acc[k03][l];
    a[2][2][l] = 0.25 * acc[k40][l], a[2][3][l] = 0.5 * acc[k31][l], a[2][4][l] = 0.25 * acc[k22][l];
    a[3][3][l] = acc[k22][l], a[3][4][l] = 0.5 * acc[k13][l];
    a[4][4][l] = 0.25 * acc[k04][l];
    b[0][l] = acc[kb0][l], b[1][l] = acc[kb1][l], b[2][l] = 0.5 * acc[kb2][l], b[3][l] = acc[kb3][l],
    b[4][l] = 0.5 * acc[kb4][l];
  }
}

// Pass 1 on a batch (see slopes.h): each lane's record into `out`: the position copied, the
// refined normal (the centre's own where the fit is ill-posed or the vertex not refinable),
// its stencil's squared radius (0 then) and the fitted flag copied.
__attribute__((always_inline)) inline void SlopeNormals(const Work& W, const Batch& B, double* out) {
  // Lengths in units of the first (nonzero) neighbour's distance (conditioning).
  alignas(64) Lanes scale;
#pragma omp simd
  for (int l = 0; l < B.lanes; ++l) {
    const double l2 = B.dx[0][l] * B.dx[0][l] + B.dy[0][l] * B.dy[0][l] + B.dz[0][l] * B.dz[0][l];
    scale[l] = 1 / std::sqrt(l2 > 0 ? l2 : 1.0) * (l2 > 0 ? 1.0 : 0.0);
  }
  for (int l = 0; l < kLanes; ++l)  // a first point on the centre (rare)
    for (int i = 1; i < B.rows && scale[l] == 0; ++i) {
      const double l2 = B.dx[i][l] * B.dx[i][l] + B.dy[i][l] * B.dy[i][l] + B.dz[i][l] * B.dz[i][l];
      if (l2 > 0) scale[l] = 1 / std::sqrt(l2);
    }
  alignas(64) double acc[kSums][kLanes] = {};
  alignas(64) Lanes r2max = {};
  const double cos_cut = W.cos_cut;
  for (int i = 0; i < B.rows; ++i) {
#pragma omp simd
    for (int l = 0; l < B.lanes; ++l) {
      double pu, pw, ph, nm, nt1, nt2;
      Project(B, i, l, pu, pw, ph, nm, nt1, nt2);
      const double ok = (nm >= cos_cut ? 1.0 : 0.0) * B.live[i][l];  // the safeguard gamma of (2.2.1), 0 or 1
      const double u = pu * scale[l], w = pw * scale[l], h = ph * scale[l], r2 = u * u + w * w;
      // h - p.G / 3 with G = -(n.t1, n.t2) / n.m
      const double rhs = h + (u * nt1 + w * nt2) / (3 * (ok > 0 ? nm : 1.0));
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
  // Columns u, w, u^2/2, uw, w^2/2 (Taylor).
  alignas(64) double a[5][5][kLanes], b[5][kLanes];
  alignas(64) Lanes ok;
  QuadraticSystem(acc, a, b);
#pragma omp simd
  for (int l = 0; l < kLanes; ++l) ok[l] = r2max[l] > 0 && scale[l] > 0 ? 1.0 : 0.0;
  SolveSpdLanes<5>(a, b, 1e-10, ok);
  // The fitted linear term itself (2/3 of the gradient it estimates): see slopes.h.
  alignas(64) double nn[3][kLanes], radius2[kLanes];
#pragma omp simd
  for (int l = 0; l < B.lanes; ++l) {
    double v[3];
    for (int c = 0; c < 3; ++c) v[c] = B.m[c][l] - b[0][l] * B.t1[c][l] - b[1][l] * B.t2[c][l];
    const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    const bool good = ok[l] > 0 && len > 0 && len < HUGE_VAL;
    for (int c = 0; c < 3; ++c) nn[c][l] = good ? v[c] / len : B.m[c][l];
    radius2[l] = good ? r2max[l] / (scale[l] * scale[l]) : 0.0;
  }
  for (int l = 0; l < B.count; ++l) {
    const int64_t k = B.slot[l];
    const double fitted = B.xn[kRec * k + kFitted];
    const bool refined = fitted != 0;  // else its own normal
    double* dst = out + kRec * k;
    dst[0] = B.x[l], dst[1] = B.y[l], dst[2] = B.z[l];
    for (int c = 0; c < 3; ++c) dst[3 + c] = refined ? nn[c][l] : B.m[c][l];
    dst[kRadius2] = refined ? radius2[l] : 0.0;
    dst[kFitted] = fitted;
  }
}

// Pass 1 at degree 3 (Work::centre; see slopes.h): in the fit's frame, with G_j the
// gradient of the height at p_j from the point's normal, h_j - p_j.G_j / 4 =
// sum_k (1 - k/4) T_k(p_j) (Euler: p.grad T_k = k T_k for the homogeneous Taylor terms T_k
// of (2.3.1)), so the quartic term, the leading error of a degree-3 fit's gradient (§2.5),
// cancels and the rest lies in the degree-3 fit's columns (u, w, the quadratics, the
// cubics) up to the quintic's O(p^5). Fitted: the rows less a quarter of the current cubic
// term C_0 (the fit's, then the previous pass's), so the four cubic unknowns are
// (C - C_0) / 24 and get a ridge (kRidge, relative to the Jacobi-scaled diagonal) towards C_0: on marching-cubes stencils whose
// points lie on two circles about the vertex, u (u^2 + w^2) nearly repeats u and the
// neighbours' slope errors would otherwise reach the gradient magnified (mc N = 128:
// normal Linf 1.5x CGAL's without the ridge, bench/README.md `d3nrm`). The fitted linear
// term L = (3/4) a - mean(e_j) / 4 (a: the gradient, e_j: the neighbours' slope errors);
// the pass reports L + g_0 / 4 (g_0: the vertex's current gradient, error e_0), whose error
// (e_0 - mean e_j) / 4 loses the smooth part of the bias, as the degree-2 pass's
// (e_0 - mean e_j) / 3 does. Row weights gamma n.m / (s + 0.01)^2 in s = r^2 / radius^2
// (the safeguard gamma of (2.2.1) as 0 or 1). Each lane's record into `out` as
// SlopeNormals' (kRadius2 unused: the Hessian pass measures its own radius), and the
// fitted cubic into Work::centre (the lane's own slot only), so the Hessian pass subtracts
// a gradient and a cubic that were fitted together.
__attribute__((always_inline)) inline void CubicSlopeNormals(const Work& W, const Batch& B, double* out) {
  // Lengths in units of the stencil's radius (its farthest point in space).
  alignas(64) Lanes scale = {};
  for (int i = 0; i < B.rows; ++i)
#pragma omp simd
    for (int l = 0; l < B.lanes; ++l)
      scale[l] = std::max(scale[l], B.live[i][l] * (B.dx[i][l] * B.dx[i][l] + B.dy[i][l] * B.dy[i][l] +
                                                    B.dz[i][l] * B.dz[i][l]));
#pragma omp simd
  for (int l = 0; l < B.lanes; ++l) scale[l] = scale[l] > 0 ? 1 / std::sqrt(scale[l]) : 0.0;
  // Moments u^p w^q of degrees 2..6 (degree d's at kBase[d] + q), then the right-hand sides.
  static constexpr int kBase[7] = {0, 0, 0, 3, 7, 12, 18}, kMoments = 25;
  alignas(64) double acc[kMoments + 9][kLanes] = {};
  alignas(64) Lanes used = {};
  const double cos_cut = W.cos_cut;
  constexpr double kEps = 0.01, kRidge = 0.01;
  for (int i = 0; i < B.rows; ++i) {
#pragma omp simd
    for (int l = 0; l < B.lanes; ++l) {
      double pu, pw, ph, nm, nt1, nt2;
      Project(B, i, l, pu, pw, ph, nm, nt1, nt2);
      const double ok = (nm >= cos_cut ? 1.0 : 0.0) * B.live[i][l];  // the safeguard gamma of (2.2.1), 0 or 1
      const double u = pu * scale[l], w = pw * scale[l], h = ph * scale[l], r2 = u * u + w * w;
      const double cubic = B.f3[0][l] * pu * pu * pu + 3 * B.f3[1][l] * pu * pu * pw + 3 * B.f3[2][l] * pu * pw * pw +
                           B.f3[3][l] * pw * pw * pw;
      // h - p.G / 4 less a quarter of the current cubic term
      const double rhs = h + (u * nt1 + w * nt2) / (4 * (ok > 0 ? nm : 1.0)) - scale[l] * cubic / 24;
      const double q = r2 + kEps, wt = ok * nm / (q * q);
      used[l] += ok;
      // (Scalars, not arrays: arrays in a simd loop keep GCC from vectorizing it.)
      const double uu = u * u, uw = u * w, ww = w * w, u3 = uu * u, u2w = uu * w, uw2 = u * ww, w3 = ww * w;
      const double p20 = wt * uu, p11 = wt * uw, p02 = wt * ww, wr = wt * rhs;
      acc[0][l] += p20, acc[1][l] += p11, acc[2][l] += p02;
      acc[3][l] += wt * u3, acc[4][l] += wt * u2w, acc[5][l] += wt * uw2, acc[6][l] += wt * w3;
      acc[7][l] += p20 * uu, acc[8][l] += p20 * uw, acc[9][l] += p20 * ww, acc[10][l] += p11 * ww,
          acc[11][l] += p02 * ww;
      acc[12][l] += p20 * u3, acc[13][l] += p20 * u2w, acc[14][l] += p20 * uw2, acc[15][l] += p20 * w3,
          acc[16][l] += p11 * w3, acc[17][l] += p02 * w3;
      acc[18][l] += p20 * uu * uu, acc[19][l] += p20 * uu * uw, acc[20][l] += p20 * uu * ww,
          acc[21][l] += p20 * uw * ww, acc[22][l] += p20 * ww * ww, acc[23][l] += p11 * ww * ww,
          acc[24][l] += p02 * ww * ww;
      acc[25][l] += wr * u, acc[26][l] += wr * w, acc[27][l] += wr * uu, acc[28][l] += wr * uw,
          acc[29][l] += wr * ww, acc[30][l] += wr * u3, acc[31][l] += wr * u2w, acc[32][l] += wr * uw2,
          acc[33][l] += wr * w3;
    }
  }
  // Columns u^p w^q, 1 <= p + q <= 3: entry (i, j) the moment of the summed exponents.
  static constexpr int kP[9] = {1, 0, 2, 1, 0, 3, 2, 1, 0}, kQ[9] = {0, 1, 0, 1, 2, 0, 1, 2, 3};
  alignas(64) double a[9][9][kLanes], b[9][kLanes], jacobi[9][kLanes];
  alignas(64) Lanes ok;
  static constexpr int kDiag[9] = {0, 2, 7, 9, 11, 18, 20, 22, 24};  // moments u^2p w^2q (kBase)
#pragma omp simd
  for (int l = 0; l < B.lanes; ++l)
    for (int i = 0; i < 9; ++i) {
      const double d = acc[kDiag[i]][l];
      jacobi[i][l] = 1 / std::sqrt(d > 0 ? d : 1.0);
    }
  for (int i = 0; i < 9; ++i) {
    for (int j = i; j < 9; ++j) {
      const int k = kBase[kP[i] + kP[j] + kQ[i] + kQ[j]] + kQ[i] + kQ[j];
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) a[i][j][l] = acc[k][l] * jacobi[i][l] * jacobi[j][l];
    }
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) b[i][l] = acc[kMoments + i][l] * jacobi[i][l];
  }
#pragma omp simd
  for (int l = 0; l < kLanes; ++l) ok[l] = used[l] >= 9 && scale[l] > 0 ? 1.0 : 0.0;
  for (int i = 5; i < 9; ++i)
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) a[i][i][l] += kRidge;
  SolveSpdLanes<9>(a, b, 1e-12, ok);
  alignas(64) double nn[3][kLanes];
#pragma omp simd
  for (int l = 0; l < B.lanes; ++l) {
    const double l1 = b[0][l] * jacobi[0][l], l2 = b[1][l] * jacobi[1][l];
    const double a1 = l1 + B.g1[l] / 4, a2 = l2 + B.g2[l] / 4;  // the new gradient
    double v[3];
    for (int c = 0; c < 3; ++c) v[c] = B.m[c][l] - a1 * B.t1[c][l] - a2 * B.t2[c][l];
    const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    const bool good = ok[l] > 0 && len > 0 && len < HUGE_VAL;
    for (int c = 0; c < 3; ++c) nn[c][l] = good ? v[c] / len : 0.0;
    ok[l] = good ? 1.0 : 0.0;
  }
  for (int l = 0; l < B.count; ++l) {
    const int64_t k = B.slot[l];
    const double* self = B.xn + kRec * k;
    const bool refined = self[kFitted] != 0 && ok[l] > 0;  // else its own normal
    double* dst = out + kRec * k;
    dst[0] = B.x[l], dst[1] = B.y[l], dst[2] = B.z[l];
    for (int c = 0; c < 3; ++c) dst[3 + c] = refined ? nn[c][l] : self[3 + c];
    dst[kRadius2] = 0.0;
    dst[kFitted] = self[kFitted];
    if (refined) {  // the cubic with it: the unknowns are (C - C_0) / 24 in monomials, radius units
      double* f3 = W.centre + W.centre_stride * k + 3;
      const double s2 = scale[l] * scale[l];
      f3[0] += 24 * b[5][l] * jacobi[5][l] * s2, f3[1] += 8 * b[6][l] * jacobi[6][l] * s2;
      f3[2] += 8 * b[7][l] * jacobi[7][l] * s2, f3[3] += 24 * b[8][l] * jacobi[8][l] * s2;
    }
  }
}

// The stencils' squared radii of a batch (the normal pass's, or with Work::own_radius those
// of the rows kept), their inverses, and ok[l] = 1 for the lanes to refit.
__attribute__((always_inline)) inline void StencilRadii(const Work& W, const Batch& B, Lanes& radius2, Lanes& inv_radius2,
                                                        Lanes& inv_radius, Lanes& ok) {
  alignas(64) Lanes r2max = {};
  if (W.own_radius) {  // the squared radius of the rows kept, as the normal pass measures it (in vector lanes)
    auto ld = [](const Lanes& x) { return *reinterpret_cast<const V*>(x); };
    const V m0 = ld(B.m[0]), m1 = ld(B.m[1]), m2 = ld(B.m[2]), t10 = ld(B.t1[0]), t11 = ld(B.t1[1]),
            t12 = ld(B.t1[2]), t20 = ld(B.t2[0]), t21 = ld(B.t2[1]), t22 = ld(B.t2[2]);
    const V zero = {};
    V r2 = zero;
    for (int i = 0; i < B.rows; ++i) {
      const V dx = ld(B.dx[i]), dy = ld(B.dy[i]), dz = ld(B.dz[i]);
      const V nm = ld(B.nx[i]) * m0 + ld(B.ny[i]) * m1 + ld(B.nz[i]) * m2;
      const V pu = dx * t10 + dy * t11 + dz * t12, pw = dx * t20 + dy * t21 + dz * t22;
      const V keep = (nm >= W.cos_cut ? zero + 1 : zero) * ld(B.live[i]), x = keep * (pu * pu + pw * pw);
      r2 = r2 > x ? r2 : x;
    }
    *reinterpret_cast<V*>(r2max) = r2;
  }
  for (int l = 0; l < kLanes; ++l) {
    const double* self = B.xn + kRec * static_cast<int64_t>(B.slot[l]);
    const double r2 = W.own_radius ? r2max[l] : self[kRadius2];
    ok[l] = l < B.count && r2 > 0 && self[kFitted] != 0 ? 1.0 : 0.0;
    radius2[l] = r2 > 0 ? r2 : 1.0;
  }
#pragma omp simd
  for (int l = 0; l < kLanes; ++l) {
    inv_radius2[l] = 1 / radius2[l];
    inv_radius[l] = std::sqrt(inv_radius2[l]);
  }
}

// Pass 2 on a batch: each lane's Hessian (c20, c11, c02) in its frame (the refined
// normal's), fitted to the Hermite rows (hermite.h) together with the cubic form C of
// their remainder C r / 6 (four more unknowns; the rows' value is
// e^T Hess e + C(p) / (6 r^2) + O(r^3)), so the cubic term no longer enters through the
// stencil's odd moments. The cubic unknowns get a ridge of 1% of the Hessian block's
// trace: on stencils whose directions barely determine them (marching-cubes meshes, points
// at 1% of h) the fit falls back smoothly towards the three-unknown one. `hess` gets 3
// values per lane; ok[l] = 0 where the lane keeps its plain Hessian.
__attribute__((always_inline)) inline void HermiteHessians(const Work& W, const Batch& B, double (&hess)[3][kLanes], Lanes& ok) {
  (void)W;
  // Row weights s / (s + 0.3)^2.5 (hermite.h; FitOptions::hermite_hessian uses 0.1): with the
  // cubic unknowns the near rows, whose normals' error over r is largest, are weighed less.
  // Degree 3 (Work::centre): s / (s + 0.5)^2.5 and the ridge 0.3% towards the fit's cubic
  // (scanned on gmsh, marching-cubes and generated meshes: bench/README.md, `clean4`).
  const double kEps = W.centre ? 0.5 : 0.3, kRidge = W.centre ? 0.003 : 0.01;
  alignas(64) Lanes radius2, inv_radius2, inv_radius;
  const double cos_cut = W.cos_cut;
  StencilRadii(W, B, radius2, inv_radius2, inv_radius, ok);
  // Moments of (u, w) / radius: weights wt / r^4 at degrees 4-6 (the normal matrix), wt v / r^2
  // at degrees 2-3 (the right-hand side).
  enum { m40, m31, m22, m13, m04, m50, m41, m32, m23, m14, m05, m60, m51, m42, m33, m24, m15, m06,
         v20, v11, v02, v30, v21, v12, v03, kSums };
  alignas(64) double acc[kSums][kLanes] = {};
  for (int i = 0; i < B.rows; ++i) {
#pragma omp simd
    for (int l = 0; l < B.lanes; ++l) {
      double pu, pw, ph, nm, nt1, nt2, value, c0, c1, c2, inv_r2, weight;
      Project(B, i, l, pu, pw, ph, nm, nt1, nt2);
      const double gamma = (nm >= cos_cut ? nm : 0.0) * B.live[i][l];
      HermiteRowOf(pu, pw, ph, nt1, nt2, nm, gamma, inv_radius2[l], kEps, value, c0, c1, c2, inv_r2,
                   weight);
      // In a tilted frame (height a.p + p^T Hess p / 2 + ...), 4h - p.grad h = 3 a.p + p^T Hess p + ...
      // With the fit's cubic form C too: the rows' remainder is then the cubic's error, whose
      // unknowns' ridge pulls them towards the fit's cubic rather than towards zero.
      const double cubic = B.f3[0][l] * pu * pu * pu + 3 * B.f3[1][l] * pu * pu * pw + 3 * B.f3[2][l] * pu * pw * pw +
                           B.f3[3][l] * pw * pw * pw;
      value -= (3 * (B.g1[l] * pu + B.g2[l] * pw) + cubic / 6) * inv_r2;
      const double u = pu * inv_radius[l], w = pw * inv_radius[l];
      const double s = inv_r2 * radius2[l];  // radius^2 / r^2 (0 when excluded)
      const double wm = weight * s * s, wv = weight * value * s;
      const double u2 = u * u, uw = u * w, w2 = w * w, u3 = u2 * u, u2w = u2 * w, uw2 = u * w2, w3 = w2 * w;
      const double p20 = wm * u2, p11 = wm * uw, p02 = wm * w2;
      acc[m40][l] += p20 * u2, acc[m31][l] += p20 * uw, acc[m22][l] += p20 * w2, acc[m13][l] += p11 * w2,
          acc[m04][l] += p02 * w2;
      acc[m50][l] += p20 * u3, acc[m41][l] += p20 * u2w, acc[m32][l] += p20 * uw2, acc[m23][l] += p20 * w3,
          acc[m14][l] += p11 * w3, acc[m05][l] += p02 * w3;
      acc[m60][l] += p20 * u2 * u2, acc[m51][l] += p20 * u2 * uw, acc[m42][l] += p20 * u2 * w2,
          acc[m33][l] += p20 * uw * w2, acc[m24][l] += p20 * w2 * w2, acc[m15][l] += p11 * w2 * w2,
          acc[m06][l] += p02 * w2 * w2;
      acc[v20][l] += wv * u2, acc[v11][l] += wv * uw, acc[v02][l] += wv * w2;
      acc[v30][l] += wv * u3, acc[v21][l] += wv * u2w, acc[v12][l] += wv * uw2, acc[v03][l] += wv * w3;
    }
  }
  // Columns (u^2, 2uw, w^2, u^3, u^2 w, u w^2, w^3) / r^2 in units of the radius: entry
  // (i, j) is the moment of the summed exponents, times 2 for each uw column.
  static constexpr int kP[7] = {2, 1, 0, 3, 2, 1, 0}, kQ[7] = {0, 1, 2, 0, 1, 2, 3};
  static constexpr double kF[7] = {1, 2, 1, 1, 1, 1, 1};
  // Index of the moment u^p w^q (p + q = 4..6) in acc.
  auto moment = [](int p, int q) {
    const int d = p + q;
    return (d == 4 ? m40 : d == 5 ? m50 : m60) + q;
  };
  alignas(64) double a[7][7][kLanes], b[7][kLanes];
  for (int i = 0; i < 7; ++i) {
    for (int j = i; j < 7; ++j) {
      const int k = moment(kP[i] + kP[j], kQ[i] + kQ[j]);
      const double f = kF[i] * kF[j];
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) a[i][j][l] = f * acc[k][l];
    }
    const int k = kP[i] + kQ[i] == 2 ? v20 + kQ[i] : v30 + kQ[i];
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) b[i][l] = kF[i] * acc[k][l];
  }
#pragma omp simd
  for (int l = 0; l < kLanes; ++l) {
    const double ridge = kRidge * (a[0][0][l] + a[1][1][l] + a[2][2][l]);
    for (int i = 3; i < 7; ++i) a[i][i][l] += ridge;
  }
  SolveSpdLanes<7>(a, b, 1e-3, ok);
  for (int c = 0; c < 3; ++c)
    for (int l = 0; l < kLanes; ++l) hess[c][l] = b[c][l];
}

// The degree-2 operator pass (FitOptions::quadratic_hermite; slopes.h): the plain fit's own
// least-squares operator (its frame, columns u, w, u^2/2, uw, w^2/2 and weights (2.2.1))
// applied to r_j = h_j - p_j.G_j / 3 = (2/3) a.p + (1/3) T2(p) - T4(p) / 3 + ..., in which the
// cubic Taylor term cancels (Euler: p.grad T_k = k T_k). The new gradient is the fitted
// linear term plus a third of the vertex's current one (error (e_0 - mean e_j) / 3), the
// Hessian three times the fitted quadratic part. With `last`, each lane's result record
// (c20 c11 c02, ok, the normal, kFitted) into `out`, else its normal record.
__attribute__((always_inline)) inline void OperatorPass(const Work& W, const Batch& B, double* out, bool last) {
  alignas(64) Lanes radius2, inv_radius2, inv_radius, ok;
  StencilRadii(W, B, radius2, inv_radius2, inv_radius, ok);
  alignas(64) double acc[kSums][kLanes] = {};
  const double cos_cut = W.cos_cut, eps = W.weight_epsilon;
  for (int i = 0; i < B.rows; ++i) {
#pragma omp simd
    for (int l = 0; l < B.lanes; ++l) {
      double pu, pw, ph, nm, nt1, nt2;
      Project(B, i, l, pu, pw, ph, nm, nt1, nt2);
      const double gamma = (nm >= cos_cut ? nm : 0.0) * B.live[i][l];  // the safeguard of (2.2.1)
      const double u = pu * inv_radius[l], w = pw * inv_radius[l], h = ph * inv_radius[l];
      const double s2 = u * u + w * w + eps, wt = gamma * gamma / (s2 * s2);  // (2.2.1)'s degree-2 weight, squared
      const double rhs = h + (u * nt1 + w * nt2) / (3 * (gamma > 0 ? nm : 1.0));  // h - p.G / 3
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
  alignas(64) double a[5][5][kLanes], b[5][kLanes];
  QuadraticSystem(acc, a, b);
  SolveSpdLanes<5>(a, b, 1e-10, ok);
  alignas(64) double nn[3][kLanes];
#pragma omp simd
  for (int l = 0; l < B.lanes; ++l) {
    const double a1 = b[0][l] + B.g1[l] / 3, a2 = b[1][l] + B.g2[l] / 3;
    double v[3];
    for (int c = 0; c < 3; ++c) v[c] = B.m[c][l] - a1 * B.t1[c][l] - a2 * B.t2[c][l];
    const double len = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    const bool good = ok[l] > 0 && len > 0 && len < HUGE_VAL;
    for (int c = 0; c < 3; ++c) nn[c][l] = good ? v[c] / len : 0.0;
    ok[l] = good ? 1.0 : 0.0;
    for (int c = 0; c < 3; ++c) b[2 + c][l] *= 3 * inv_radius[l];  // Hessian: 3 x the quadratic part, real units
  }
  for (int l = 0; l < B.count; ++l) {
    const int64_t k = B.slot[l];
    const double* self = B.xn + kRec * k;
    const bool refined = self[kFitted] != 0 && ok[l] > 0;  // else its own normal
    double* dst = out + kRec * k;
    if (last) {
      for (int c = 0; c < 3; ++c) dst[c] = b[2 + c][l], dst[4 + c] = refined ? nn[c][l] : self[3 + c];
      dst[3] = refined ? 1.0 : 0.0;
    } else {
      dst[0] = B.x[l], dst[1] = B.y[l], dst[2] = B.z[l];
      for (int c = 0; c < 3; ++c) dst[3 + c] = refined ? nn[c][l] : self[3 + c];
      dst[kRadius2] = 0.0;
    }
    dst[kFitted] = self[kFitted];
  }
}

// The Hermite jets' constants per degree (scanned on the clean meshes of bench/README.md, `d45k`):
// the combination a (a = D + 1 cancels the fit's leading bias T_{D+1}), the row weights'
// eps (hermite.h: s / (s + eps)^2.5), and the share of the Hermite Hessian in the one
// reported (degree 5: 0.6, the rest the fit's own; on marching-cubes meshes the two errors
// partly cancel). The unknowns of degrees 3..D get a ridge of 0.3% of the Hessian block's
// trace towards the fit's terms, as at degree 3.
struct JetConstants {
  double a, eps, share;
};
constexpr JetConstants kJet[2] = {{5, 0.5, 1.0}, {6, 0.2, 0.6}};
constexpr double kJetRidge = 0.003;

// The sums of HermiteJets<D> for the powers u^p, P0 <= p <= P1, of its rows' (u, w): the
// moments w u^p w^q of degrees 2..2D into acc, the right-hand sides wv u^p w^q of degrees 1..D
// into rhs (Taylor order), each over the rows in order.
template <int D, int P0, int P1>
__attribute__((always_inline)) inline void JetSums(int rows, const Lanes* su, const Lanes* sw, const Lanes* swm,
                                                   const Lanes* swv, V* acc, V* rhs) {
  V a[NumCoefficients(2 * D) - 3] = {}, r[NumCoefficients(D) - 1] = {};
  for (int i = 0; i < rows; ++i) {
    const V u = *reinterpret_cast<const V*>(su[i]), w = *reinterpret_cast<const V*>(sw[i]);
    const V wm = *reinterpret_cast<const V*>(swm[i]), wv = *reinterpret_cast<const V*>(swv[i]);
    V wp[2 * D + 1];
    wp[0] = u * 0 + 1;
#pragma GCC unroll 16
    for (int k = 1; k <= 2 * D - P0; ++k) wp[k] = wp[k - 1] * w;
    V up = wp[0];
#pragma GCC unroll 16
    for (int p = 1; p <= P0; ++p) up = up * u;
#pragma GCC unroll 16
    for (int p = P0; p <= P1; ++p) {
      if (p > P0) up = up * u;
      const V t = wm * up;
#pragma GCC unroll 16
      for (int q = std::max(0, 2 - p); p + q <= 2 * D; ++q) a[TaylorIndex(p, q) - 3] += t * wp[q];
      if (p > D) continue;
      const V rv = wv * up;
#pragma GCC unroll 16
      for (int q = std::max(0, 1 - p); p + q <= D; ++q) r[TaylorIndex(p, q) - 1] += rv * wp[q];
    }
  }
#pragma GCC unroll 16
  for (int p = P0; p <= P1; ++p) {
#pragma GCC unroll 16
    for (int q = std::max(0, 2 - p); p + q <= 2 * D; ++q) acc[TaylorIndex(p, q) - 3] = a[TaylorIndex(p, q) - 3];
    if (p > D) continue;
#pragma GCC unroll 16
    for (int q = std::max(0, 1 - p); p + q <= D; ++q) rhs[TaylorIndex(p, q) - 1] = r[TaylorIndex(p, q) - 1];
  }
}

// The Hermite pass of degree-D fits (D = 4, 5; FitOptions::jet_hermite, slopes.h). Along the
// ray to stencil point p (height h, the neighbour's fitted slopes G), Euler's identity
// p.grad T_k = k T_k for the fit's homogeneous Taylor terms T_k gives
// a h - p.G = sum_k (a - k) T_k(p): with a = D + 1 the term T_{D+1}, the leading bias of a
// degree-D fit, cancels (hermite.h is a = 4). The rows (a h - p.G) 2 / ((a - 2) r^2) less the
// fit's own terms of degrees 1 and 3..D are fitted with the monomials of degrees 1..D / r^2:
// the Hessian (degree 2) directly, the others as corrections of the fit's (a ridge towards
// it on degrees >= 3). out: c20 c11 c02, then the gradient's correction (c10, c01).
template <int D>
__attribute__((always_inline)) inline void HermiteJets(const Work& W, const Batch& B, double (&out)[5][kLanes],
                                                      Lanes& ok) {
  constexpr int kN = NumCoefficients(D) - 1;      // unknowns: the monomials of degrees 1..D
  constexpr int kM = NumCoefficients(2 * D) - 3;  // moments of degrees 2..2D
  constexpr JetConstants kc = kJet[D - 4];
  constexpr double a = kc.a, norm = 2 / (a - 2), eps = kc.eps;
  alignas(64) Lanes radius2, inv_radius2, inv_radius;
  const double cos_cut = W.cos_cut;
  StencilRadii(W, B, radius2, inv_radius2, inv_radius, ok);
  // The fit's terms of degrees 3..D in the rows: (a - k) f_pq / (p! q!) per monomial u^p w^q.
  V fit[kMaxJet];
  for (int k = 3, c = 0; k <= D; ++k)
    for (int q = 0; q <= k; ++q, ++c) {
      static constexpr double kFactorial[6] = {1, 1, 2, 6, 24, 120};
      const double f = (a - k) / (kFactorial[k - q] * kFactorial[q]);
      for (int l = 0; l < kLanes; ++l) fit[c][l] = f * B.f3[c][l];
    }
  auto ld = [](const Lanes& x) { return *reinterpret_cast<const V*>(x); };
  const V big_r = *reinterpret_cast<const V*>(radius2), inv_big_r = *reinterpret_cast<const V*>(inv_radius);
  const V m0 = ld(B.m[0]), m1 = ld(B.m[1]), m2 = ld(B.m[2]), t10 = ld(B.t1[0]), t11 = ld(B.t1[1]), t12 = ld(B.t1[2]),
          t20 = ld(B.t2[0]), t21 = ld(B.t2[1]), t22 = ld(B.t2[2]), g1 = ld(B.g1), g2 = ld(B.g2), ir = ld(inv_radius2);
  const V zero = {}, one = zero + 1;
  // Per row: (u, w) / radius, the weights of its moments and of its value (JetSums).
  alignas(64) Lanes su[kMaxStencil], sw[kMaxStencil], swm[kMaxStencil], swv[kMaxStencil];
  for (int i = 0; i < B.rows; ++i) {
    // The row in vector lanes (Project and hermite.h's HermiteRowOf): (a h - p.G - (a - 1) g.p) / r^2,
    // 1 / r^2 and the weight gamma s / (s + eps)^2.5.
    const V dx = ld(B.dx[i]), dy = ld(B.dy[i]), dz = ld(B.dz[i]), nx = ld(B.nx[i]), ny = ld(B.ny[i]), nz = ld(B.nz[i]);
    const V u0 = dx * t10 + dy * t11 + dz * t12, w0 = dx * t20 + dy * t21 + dz * t22, ph = dx * m0 + dy * m1 + dz * m2;
    const V nm = nx * m0 + ny * m1 + nz * m2, nt1 = nx * t10 + ny * t11 + nz * t12, nt2 = nx * t20 + ny * t21 + nz * t22;
    const V gamma = (nm >= cos_cut ? nm : zero) * ld(B.live[i]);
    const V r2 = u0 * u0 + w0 * w0;
    const V g = r2 > 0 ? gamma : zero;
    const V inv = one / (g > 0 ? nm * r2 : one);
    const V inv_r2 = g > 0 ? nm * inv : zero;
    const V sr = r2 * ir;
    alignas(64) Lanes root;
    const V se = sr + eps;
#pragma omp simd
    for (int l = 0; l < kLanes; ++l) root[l] = std::sqrt(se[l]);
    const V rt = ld(root), weight = g * sr / (rt * rt * rt * rt * rt);
    const V row = (a * ph * nm + (nt1 * u0 + nt2 * w0)) * inv - (a - 1) * (g1 * u0 + g2 * w0) * inv_r2;
    V up[D + 1], wp[D + 1];
    up[0] = u0 * 0 + 1, wp[0] = up[0];
#pragma GCC unroll 16
    for (int k = 1; k <= D; ++k) up[k] = up[k - 1] * u0, wp[k] = wp[k - 1] * w0;
    V known = u0 * 0;
#pragma GCC unroll 32
    for (int k = 3, c = 0; k <= D; ++k)
#pragma GCC unroll 8
      for (int q = 0; q <= k; ++q, ++c) known += fit[c] * up[k - q] * wp[q];
    const V value = norm * (row - known * inv_r2);
    const V s = inv_r2 * big_r;
    *reinterpret_cast<V*>(su[i]) = u0 * inv_big_r, *reinterpret_cast<V*>(sw[i]) = w0 * inv_big_r;
    *reinterpret_cast<V*>(swm[i]) = weight * s * s, *reinterpret_cast<V*>(swv[i]) = weight * value * s;
  }
  // The moments, a few powers of u at a time: each group's sums stay in registers (one
  // loop over all 42 / 63 spilled them), each sum still in row order (the same bits).
  V acc[kM] = {}, rhs[kN] = {};
  if constexpr (D == 4) {
    JetSums<D, 0, 0>(B.rows, su, sw, swm, swv, acc, rhs), JetSums<D, 1, 1>(B.rows, su, sw, swm, swv, acc, rhs);
    JetSums<D, 2, 3>(B.rows, su, sw, swm, swv, acc, rhs), JetSums<D, 4, 8>(B.rows, su, sw, swm, swv, acc, rhs);
  } else {
    JetSums<D, 0, 0>(B.rows, su, sw, swm, swv, acc, rhs), JetSums<D, 1, 1>(B.rows, su, sw, swm, swv, acc, rhs);
    JetSums<D, 2, 2>(B.rows, su, sw, swm, swv, acc, rhs), JetSums<D, 3, 3>(B.rows, su, sw, swm, swv, acc, rhs);
    JetSums<D, 4, 5>(B.rows, su, sw, swm, swv, acc, rhs), JetSums<D, 6, 10>(B.rows, su, sw, swm, swv, acc, rhs);
  }
  // Unknown j is the monomial (p_j, q_j) of degree 1..D in Taylor order; entry (i, j) the moment
  // of the summed exponents.
  int P[kN], Q[kN];
  for (int k = 1, c = 0; k <= D; ++k)
    for (int q = 0; q <= k; ++q, ++c) P[c] = k - q, Q[c] = q;
  alignas(64) double m[kN][kN][kLanes], b[kN][kLanes];
  for (int i = 0; i < kN; ++i) {
    for (int j = i; j < kN; ++j) {
      const int k = TaylorIndex(P[i] + P[j], Q[i] + Q[j]) - 3;
#pragma omp simd
      for (int l = 0; l < kLanes; ++l) m[i][j][l] = acc[k][l];
    }
    for (int l = 0; l < kLanes; ++l) b[i][l] = rhs[i][l];
  }
#pragma omp simd
  for (int l = 0; l < kLanes; ++l) {
    const double trace = m[2][2][l] + 4 * m[3][3][l] + m[4][4][l];
    for (int i = 5; i < kN; ++i) m[i][i][l] += kJetRidge * trace;
  }
  SolveSpdLanes<kN>(m, b, 1e-9, ok);
  // The gradient's correction in real units: its columns are 2 (a - 1) / (a - 2) p / r^2.
  constexpr double mu = (a - 1) / a;
  for (int l = 0; l < kLanes; ++l) {
    const double radius = std::sqrt(radius2[l]), g = mu * radius * (a - 2) / (2 * (a - 1));
    out[0][l] = b[2][l], out[1][l] = 0.5 * b[3][l], out[2][l] = b[4][l];
    if (kc.share < 1)
      for (int c = 0; c < 3; ++c) out[c][l] = kc.share * out[c][l] + (1 - kc.share) * B.h2[c][l];
    out[3][l] = g * b[0][l], out[4][l] = g * b[1][l];
  }
}

// The slots [k0, k1) sorted by stencil size (a stable counting sort), so the lanes of a
// batch (kLanes consecutive entries) differ little in size.
// Written to walk[k0, k1); every pass visits the batches in this order.
void BatchOrder(const Work& W, int64_t k0, int64_t k1, int32_t* walk) {
  int at[kMaxStencil + 2] = {};
  for (int64_t k = k0; k < k1; ++k) ++at[W.Size(k) + 1];
  for (int c = 1; c <= kMaxStencil + 1; ++c) at[c] += at[c - 1];
  for (int64_t k = k0; k < k1; ++k) walk[k0 + at[W.Size(k)]++] = static_cast<int32_t>(k);
}

// Prefetches the records of the stencils of walk[j, j + kLanes) (the next batch's rows,
// whose loads otherwise miss while the current batch computes).
__attribute__((always_inline)) inline void PrefetchBatch(const Work& W, const double* xn, int64_t j, int64_t k1) {
  for (int64_t e = std::min<int64_t>(j + kLanes, k1); j < e; ++j) {
    const int32_t k = W.walk[j];
    const int32_t* pts = W.points + W.offsets[k];
    for (int i = 0, n = W.Size(k); i < n; ++i) __builtin_prefetch(xn + kRec * static_cast<int64_t>(pts[i]));
    if (W.coefficients) {  // degrees 4-5: the fit read in place (Batch::Load)
      const double* fit = W.coefficients + W.num_coefficients * static_cast<int64_t>(W.Vertex(k));
      __builtin_prefetch(fit), __builtin_prefetch(fit + W.num_coefficients - 1), __builtin_prefetch(&W.frames[W.Vertex(k)].normal);
    }
  }
}

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void NormalsRange(const Work& W, int from,
                                                                                       int64_t k0, int64_t k1) {
  std::unique_ptr<Batch> B(new Batch);
  PrefetchBatch(W, W.xn[from], k0, k1);
  for (int64_t j = k0; j < k1; j += kLanes) {
    PrefetchBatch(W, W.xn[from], j + kLanes, k1);
    B->Load(W, W.xn[from], W.walk.data() + j, static_cast<int>(std::min<int64_t>(kLanes, k1 - j)));
    SlopeNormals(W, *B, W.xn[1 - from]);
  }
}

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void CubicNormalsRange(const Work& W, int from,
                                                                                            int64_t k0, int64_t k1) {
  std::unique_ptr<Batch> B(new Batch);
  PrefetchBatch(W, W.xn[from], k0, k1);
  for (int64_t j = k0; j < k1; j += kLanes) {
    PrefetchBatch(W, W.xn[from], j + kLanes, k1);
    B->Load(W, W.xn[from], W.walk.data() + j, static_cast<int>(std::min<int64_t>(kLanes, k1 - j)));
    CubicSlopeNormals(W, *B, W.xn[1 - from]);
  }
}

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void OperatorRange(const Work& W, int from,
                                                                                        int64_t k0, int64_t k1, bool last) {
  std::unique_ptr<Batch> B(new Batch);
  PrefetchBatch(W, W.xn[from], k0, k1);
  for (int64_t j = k0; j < k1; j += kLanes) {
    PrefetchBatch(W, W.xn[from], j + kLanes, k1);
    B->Load(W, W.xn[from], W.walk.data() + j, static_cast<int>(std::min<int64_t>(kLanes, k1 - j)));
    OperatorPass(W, *B, W.xn[1 - from], last);
  }
}

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void HessiansRange(const Work& W, int from,
                                                                                        int64_t k0, int64_t k1) {
  std::unique_ptr<Batch> B(new Batch);
  PrefetchBatch(W, W.xn[from], k0, k1);
  for (int64_t j = k0; j < k1; j += kLanes) {
    PrefetchBatch(W, W.xn[from], j + kLanes, k1);
    const int n = static_cast<int>(std::min<int64_t>(kLanes, k1 - j));
    B->Load(W, W.xn[from], W.walk.data() + j, n);
    alignas(64) double hess[5][kLanes];
    alignas(64) Lanes ok;
    if (W.degree == 4)
      HermiteJets<4>(W, *B, hess, ok);
    else if (W.degree == 5)
      HermiteJets<5>(W, *B, hess, ok);
    else
      HermiteHessians(W, *B, reinterpret_cast<double(&)[3][kLanes]>(hess), ok);
    if (W.coefficients) {  // degrees 4-5: the new Hessian and the gradient's correction into the fits
      for (int l = 0; l < n; ++l) {
        if (!(ok[l] > 0)) continue;
        double* c = W.coefficients + W.num_coefficients * static_cast<int64_t>(W.Vertex(B->slot[l]));
        c[TaylorIndex(2, 0)] = hess[0][l], c[TaylorIndex(1, 1)] = hess[1][l], c[TaylorIndex(0, 2)] = hess[2][l];
        c[TaylorIndex(1, 0)] += hess[3][l], c[TaylorIndex(0, 1)] += hess[4][l];
      }
      continue;
    }
    // The results into the other copy (no pass reads it any more): one line per slot.
    for (int l = 0; l < n; ++l) {
      const int64_t k = B->slot[l];
      double* out = W.xn[1 - from] + kRec * k;
      for (int c = 0; c < 3; ++c) out[c] = hess[c][l], out[4 + c] = B->xn[kRec * k + 3 + c];
      out[3] = ok[l];
      out[kFitted] = B->xn[kRec * k + kFitted];
    }
  }
}

}  // namespace

absl::Status RefineSlopes(const Mesh& mesh, const Topology& topo, const Neighborhoods& nb, double cos_cut, int passes,
                          const RunContext& ctx, const VertexDiagnostics* diagnostics, LocalFrame* frames,
                          double* coefficients, int num_coefficients, int operator_passes, double weight_epsilon) {
  const int threads = ctx.threads();
  const int nv = mesh.NumVertices();
  Work W;
  W.nv = nv;
  W.cos_cut = cos_cut;
  const bool op = operator_passes > 0 && num_coefficients == 6;  // the degree-2 operator passes
  W.own_radius = num_coefficients >= 10 || op;  // no kRadius2 from the normal passes
  W.weight_epsilon = weight_epsilon;
  // Stencils as slots: the neighbourhoods' own in the topology's locality order (built
  // with them, else here), or their CSR in vertex order.
  const bool local = static_cast<int>(topo.locality_order.size()) == nv;
  OrderedStencils own;
  if (local && static_cast<int>(nb.ordered.order.size()) != nv) own = OrderStencils(nb, topo.locality_order, threads);
  const OrderedStencils* os = !local ? nullptr : own.empty() ? &nb.ordered : &own;
  W.order = os ? os->order.data() : nullptr;
  W.offsets = os ? os->offsets.data() : nb.offsets.data();
  W.points = os ? os->points.data() : nb.indices.data();
  // Both copies in one allocation of aligned lines, left uninitialised (every slot is
  // written before it is read).
  struct alignas(64) Line {
    double d[kRec];
  };
  const bool jets = num_coefficients >= 15;  // degrees 4-5: one copy, the fits written in place
  const std::unique_ptr<Line[]> lines(new Line[(jets ? 1 : 2) * static_cast<size_t>(nv)]);
  W.xn[0] = lines[0].d, W.xn[1] = jets ? nullptr : lines[nv].d;
  // Positions and the plain fits' normals, in visiting order. Here and at the end, the
  // loops run in the input numbering (the fits' arrays read and written in sequence, the
  // slots at random: one line a vertex instead of three).
  const int32_t* rank = os ? os->rank.data() : nullptr;
  auto slot_of = [&](int64_t v) -> int64_t { return rank ? rank[v] : v; };
  W.degree = num_coefficients >= 21 ? 5 : num_coefficients >= 15 ? 4 : num_coefficients >= 10 ? 3 : 2;
  W.centre_stride = W.own_radius ? 3 + num_coefficients - 6 : 0;  // degree 2 (op): the frame normal alone
  std::unique_ptr<double[]> centre(W.own_radius && !jets ? new double[W.centre_stride * static_cast<size_t>(nv)] : nullptr);
  W.centre = centre.get();
  if (jets) W.frames = frames, W.coefficients = coefficients, W.num_coefficients = num_coefficients;
  ParallelFor(nv, threads, [&](int64_t v) {
    if (v + 16 < nv) __builtin_prefetch(W.xn[0] + kRec * slot_of(v + 16), 1);
    const int64_t k = slot_of(v);
    double* dst = W.xn[0] + kRec * k;
    const LocalFrame& fr = frames[v];
    const double* c = coefficients + v * num_coefficients;
    const Eigen::Vector3d n = (fr.normal - c[TaylorIndex(1, 0)] * fr.t1 - c[TaylorIndex(0, 1)] * fr.t2).normalized();
    for (int i = 0; i < 3; ++i) dst[i] = mesh.positions(v, i), dst[3 + i] = n[i];
    dst[kRadius2] = 0, dst[kFitted] = diagnostics[v].degree_used >= 2 ? 1.0 : 0.0;
    if (W.centre) {
      double* to = centre.get() + W.centre_stride * k;
      for (int i = 0; i < 3; ++i) to[i] = fr.normal[i];
      for (int j = 6; j < num_coefficients; ++j) to[3 + j - 6] = c[j];
    }
  }, 4096);
  // Normal passes, from one copy of the normals into the other (every vertex reads its
  // neighbours' previous normals), then the Hessians in the refined frames.
  constexpr int64_t kGrain = 1024;
  const int64_t chunks = (nv + kGrain - 1) / kGrain;
  W.walk.resize(nv);
  // Degrees 4-5 sort each 64 slots apart: their batches read the fits in place, which then
  // stay near in memory (a vertex's result does not depend on its batch).
  const int64_t window = jets ? 64 : kGrain;
  ParallelFor(chunks, threads, [&](int64_t c) {
    for (int64_t k0 = c * kGrain, k1 = std::min<int64_t>(nv, (c + 1) * kGrain); k0 < k1; k0 += window)
      BatchOrder(W, k0, std::min<int64_t>(k1, k0 + window), W.walk.data());
  }, 1);
  int from = 0;
  if (op) passes = 0;
  for (int pass = 0; op && pass < operator_passes; ++pass, from = pass < operator_passes ? 1 - from : from) {
    const bool last = pass == operator_passes - 1;
    GF_RETURN_IF_ERROR(ParallelFor(
        chunks, ctx,
        [&](int64_t c) { OperatorRange(W, from, c * kGrain, std::min<int64_t>(nv, (c + 1) * kGrain), last); }, 1));
  }
  for (int pass = 0; pass < passes; ++pass, from = 1 - from)
    GF_RETURN_IF_ERROR(ParallelFor(
        chunks, ctx,
        [&](int64_t c) {
          const int64_t k0 = c * kGrain, k1 = std::min<int64_t>(nv, (c + 1) * kGrain);
          W.centre ? CubicNormalsRange(W, from, k0, k1) : NormalsRange(W, from, k0, k1);
        },
        1));
  if (!op) GF_RETURN_IF_ERROR(ParallelFor(
      chunks, ctx, [&](int64_t c) { HessiansRange(W, from, c * kGrain, std::min<int64_t>(nv, (c + 1) * kGrain)); },
      1));
  if (jets) return absl::OkStatus();  // written by the Hessian pass
  // The refined frames and Hessians into the fits (the tangent plane is the frame's): the
  // Hessian pass's records, the positions the mesh's own.
  const double* refined = W.xn[1 - from];
  ParallelFor(nv, threads, [&](int64_t v) {
    if (v + 16 < nv) __builtin_prefetch(refined + kRec * slot_of(v + 16));
    const double* x = refined + kRec * slot_of(v);
    if (x[kFitted] == 0) return;
    double* c = coefficients + v * num_coefficients;
    if (W.centre) {  // the fit's frame and cubic terms kept; the refined normal as its gradient
      if (x[3] > 0 && op)  // degree 2: kQuadraticShare of the operator's Hessian, the rest the fit's own
        for (int t = TaylorIndex(2, 0); t <= TaylorIndex(0, 2); ++t)
          c[t] = kQuadraticShare * x[t - TaylorIndex(2, 0)] + (1 - kQuadraticShare) * c[t];
      else if (x[3] > 0)
        c[TaylorIndex(2, 0)] = x[0], c[TaylorIndex(1, 1)] = x[1], c[TaylorIndex(0, 2)] = x[2];
      const LocalFrame& fr = frames[v];
      const Eigen::Vector3d n(x[4], x[5], x[6]);
      const double nm = n.dot(fr.normal);
      if ((passes > 0 || op) && nm > 0) c[TaylorIndex(1, 0)] = -n.dot(fr.t1) / nm, c[TaylorIndex(0, 1)] = -n.dot(fr.t2) / nm;
      return;
    }
    frames[v] = FrameFromNormal(Eigen::Vector3d(mesh.positions(v, 0), mesh.positions(v, 1), mesh.positions(v, 2)),
                                Eigen::Vector3d(x[4], x[5], x[6]));
    if (x[3] > 0) c[TaylorIndex(2, 0)] = x[0], c[TaylorIndex(1, 1)] = x[1], c[TaylorIndex(0, 2)] = x[2];
    c[TaylorIndex(1, 0)] = c[TaylorIndex(0, 1)] = 0;
  }, 4096);
  return absl::OkStatus();
}

}  // namespace geomfit
