#include "core/fitting/wls_batch.h"

#include <cstdint>
#include <type_traits>

#if defined(__x86_64__) && defined(__GNUC__)
#include <immintrin.h>
#endif

#include "core/fitting/fit.h"
#include "core/fitting/record_lanes.h"
#include "core/util/parallel.h"

// Compiled with -fno-math-errno (core/CMakeLists.txt) so that square roots of vectors
// become vector instructions, and with -ffp-contract=off: every lane performs SolveWls's
// operations in SolveWls's order (sequential sums, no fused multiply-adds), so on x86-64
// a lane's results are SolveWls's bit for bit.

namespace geomfit {
namespace {

// W doubles in one vector: 8 (AVX-512), 4 (AVX2; SSE2 pairs in the portable build).
template <int W>
struct Lanes {
  typedef double V __attribute__((vector_size(W * sizeof(double))));
  typedef long long VI __attribute__((vector_size(W * sizeof(double))));  // comparison masks
};

#define GEOMFIT_INLINE inline __attribute__((always_inline))
#define GEOMFIT_INLINE_LAMBDA __attribute__((always_inline))

template <class V>
GEOMFIT_INLINE V Splat(double x) { return V{} + x; }
template <class V>
GEOMFIT_INLINE V Sqrt(V x) {
  V r;
  for (int l = 0; l < static_cast<int>(sizeof(V) / sizeof(double)); ++l) r[l] = __builtin_sqrt(x[l]);
  return r;
}
template <class V>
GEOMFIT_INLINE V Abs(V x) { return x < 0 ? -x : x; }
// mask ? a : b lane by lane on the bits (a comparison's mask): GCC 12 compiles some
// vector ?: with constant or shared operands to scalar code per lane at AVX-512.
template <class V, class M>
GEOMFIT_INLINE V Select(M mask, V a, V b) {
  return reinterpret_cast<V>((reinterpret_cast<M>(a) & mask) | (reinterpret_cast<M>(b) & ~mask));
}
template <class V>
GEOMFIT_INLINE V Max(V a, V b) { return a < b ? b : a; }

// (p[0][c], p[1][c], ...) built in registers (lane by lane stores go through the stack).
template <class V>
GEOMFIT_INLINE V Gather(const double* const* p, int c, V /*type*/) {
  if constexpr (sizeof(V) == 8 * sizeof(double))
    return V{p[0][c], p[1][c], p[2][c], p[3][c], p[4][c], p[5][c], p[6][c], p[7][c]};
  else
    return V{p[0][c], p[1][c], p[2][c], p[3][c]};
}

// FitHeights's row set-up per instruction set: Records(at, q) sets q[c] = (at[0][c],
// at[1][c], ...), c = 0..5, from the lanes' PointRecords (each an aligned cache line:
// full-width loads transposed in registers where the CPU has the shuffles), Gamma(g, cut, i, rows) = g where
// g >= cut and i < rows[l], else +0, IfPositive(gamma, x) = x where gamma > 0, else +0
// (comparisons on vectors in registers: GCC 12 turns the generic code's vector selects
// into scalar code).
template <int W>
struct PortableRows {
  static constexpr int kW = W;
  using V = typename Lanes<W>::V;
  using VI = typename Lanes<W>::VI;
  GEOMFIT_INLINE static void Records(const double* const* at, V* q) {
    for (int c = 0; c < 6; ++c) q[c] = Gather(at, c, V{});
  }
  GEOMFIT_INLINE static V Gamma(V g, V cut, int i, const int32_t* rows) {
    V r;
    for (int l = 0; l < W; ++l) r[l] = g[l] >= cut[l] && i < rows[l] ? g[l] : 0.0;
    return r;
  }
  GEOMFIT_INLINE static V IfPositive(V gamma, V x) {
    return reinterpret_cast<V>(reinterpret_cast<VI>(x) & (gamma > 0));
  }
};

#if defined(__x86_64__) && defined(__GNUC__)
#define GEOMFIT_AVX2 __attribute__((target("avx2")))
#define GEOMFIT_AVX512 __attribute__((target("avx512f,avx512dq,avx512vl,avx512bw")))
// Not always_inline (its callers are compiled for any CPU): flatten inlines them into the
// kernels of their instruction set.
struct Avx2Rows {
  static constexpr int kW = 4;
  using V = Lanes<4>::V;
  // The pairs (x, y), (z, nx), (ny, nz) of lanes 0 and 2 in one vector, of lanes 1 and 3
  // in another: their unpacks are the pair's two components across the 4 lanes.
  GEOMFIT_AVX2 static inline void Records(const double* const* at, V* q) {
    for (int k = 0; k < 3; ++k) {
      const __m256d a = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_pd(at[0] + 2 * k)),
                                             _mm_load_pd(at[2] + 2 * k), 1);
      const __m256d b = _mm256_insertf128_pd(_mm256_castpd128_pd256(_mm_load_pd(at[1] + 2 * k)),
                                             _mm_load_pd(at[3] + 2 * k), 1);
      q[2 * k] = reinterpret_cast<V>(_mm256_unpacklo_pd(a, b));
      q[2 * k + 1] = reinterpret_cast<V>(_mm256_unpackhi_pd(a, b));
    }
  }
  GEOMFIT_AVX2 static inline V Gamma(V g, V cut, int i, const int32_t* rows) {
    const __m128i valid = _mm_cmpgt_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(rows)), _mm_set1_epi32(i));
    const __m256d keep = _mm256_and_pd(_mm256_cmp_pd(reinterpret_cast<__m256d>(g), reinterpret_cast<__m256d>(cut), _CMP_GE_OQ),
                                       _mm256_castsi256_pd(_mm256_cvtepi32_epi64(valid)));
    return reinterpret_cast<V>(_mm256_and_pd(keep, reinterpret_cast<__m256d>(g)));
  }
  GEOMFIT_AVX2 static inline V IfPositive(V gamma, V x) {
    const __m256d keep = _mm256_cmp_pd(reinterpret_cast<__m256d>(gamma), _mm256_setzero_pd(), _CMP_GT_OQ);
    return reinterpret_cast<V>(_mm256_and_pd(keep, reinterpret_cast<__m256d>(x)));
  }
};
struct Avx512Rows {
  static constexpr int kW = 8;
  using V = Lanes<8>::V;
  // 8 records transposed in registers (record_lanes.h).
  GEOMFIT_AVX512 static inline void Records(const double* const* at, V* q) { TransposeRecords8(at, q); }
  GEOMFIT_AVX512 static inline V Gamma(V g, V cut, int i, const int32_t* rows) {
    const __mmask8 valid =
        _mm256_cmpgt_epi32_mask(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(rows)), _mm256_set1_epi32(i));
    const __mmask8 keep =
        _mm512_mask_cmp_pd_mask(valid, reinterpret_cast<__m512d>(g), reinterpret_cast<__m512d>(cut), _CMP_GE_OQ);
    return reinterpret_cast<V>(_mm512_maskz_mov_pd(keep, reinterpret_cast<__m512d>(g)));
  }
  GEOMFIT_AVX512 static inline V IfPositive(V gamma, V x) {
    const __mmask8 keep = _mm512_cmp_pd_mask(reinterpret_cast<__m512d>(gamma), _mm512_setzero_pd(), _CMP_GT_OQ);
    return reinterpret_cast<V>(_mm512_maskz_mov_pd(keep, reinterpret_cast<__m512d>(x)));
  }
};
#endif

constexpr double Factorial(int n) { return n <= 1 ? 1.0 : n * Factorial(n - 1); }

// y <- (I - tau x x^T) y over rows j..m-1 (x_j = 1 implied), lane by lane.
// Reflect on N columns y[0..N) at once: each x[i] is loaded once for the N columns, and
// every column sees Reflect's operations in Reflect's order (bit-equal results).
template <int N, class V>
GEOMFIT_INLINE void ReflectColumns(const V* x, V tau, int j, int m, V* const* y) {
  V w[N];
  for (int c = 0; c < N; ++c) w[c] = y[c][j];
  for (int i = j + 1; i < m; ++i) {
    const V xi = x[i];
    for (int c = 0; c < N; ++c) w[c] += xi * y[c][i];
  }
  for (int c = 0; c < N; ++c) {
    w[c] *= tau;
    y[c][j] -= w[c];
  }
  for (int i = j + 1; i < m; ++i) {
    const V xi = x[i];
    for (int c = 0; c < N; ++c) y[c][i] -= w[c] * xi;
  }
}

template <class V>
GEOMFIT_INLINE void Reflect(const V* x, V tau, int j, int m, V* y) {
  V w = y[j];
  for (int i = j + 1; i < m; ++i) w += x[i] * y[i];
  w *= tau;
  y[j] -= w;
  for (int i = j + 1; i < m; ++i) y[i] -= w * x[i];
}

bool& NormalEquationsFlag() {
  static bool enabled = true;
  return enabled;
}
bool NormalEquationsEnabled() { return NormalEquationsFlag(); }

// Lanes solved by the normal equations (SolveNormal): a condition (2.4) of the
// column-scaled matrix up to kPlainCondition is solved directly (forward error of order
// condition^2 eps < 1e-13 relative), up to kRefinedCondition with one step of refinement
// on the residual (then of order condition eps, as the QR's; computed for the whole group
// when one lane needs it, applied to the lanes above kPlainCondition only, so that a
// lane's result does not depend on its neighbours in the batch); above, or within a factor 2
// of the degree's cut-off, the lane takes the QR. Equality with the QR's results:
// bench/README.md, "Issue 15, fourth round".
constexpr double kPlainCondition = 30, kRefinedCondition = 1e3;

// hp[p] = h^p, p = 0..D.
template <int D, class V>
GEOMFIT_INLINE void Powers(V h, V* hp) {
  hp[0] = Splat<V>(1);
  for (int p = 1; p <= D; ++p) hp[p] = hp[p - 1] * h;
}

// coefficients[l][at] = value[l] for the lanes in `mask`.
template <int W, class V>
GEOMFIT_INLINE void StoreLanes(V value, int mask, int at, double* const coefficients[]) {
  for (int l = 0; l < W; ++l)
    if (mask >> l & 1) coefficients[l][at] = value[l];
}

// The lanes in `mask` solved at full degree D and rank: their first `First` coefficients
// of each dimension are zero (fixed columns), their diagnostics set.
template <int W, int D, int First, class V>
GEOMFIT_INLINE void FinishLanes(int mask, int dims, V condition, const double* h, double* const coefficients[],
                                WlsSolution solutions[]) {
  constexpr int kN = NumCoefficients(D);
  for (int l = 0; l < W; ++l) {
    if (!(mask >> l & 1)) continue;
    for (int d = 0; d < dims; ++d)
      for (int t = 0; t < First; ++t) coefficients[l][d * kN + t] = 0;
    WlsSolution& sol = solutions[l];
    sol = WlsSolution{};
    sol.degree_used = D;
    sol.rank = kN;
    sol.condition = condition[l];
    sol.radius = h[l];
  }
}

// Weight (2.2.1) of a row at scaled distance (u, v) with safeguard factor g (0: dropped).
template <int D, class V>
GEOMFIT_INLINE V Weight(V u, V v, V g, double epsilon) {
  constexpr int kPowers = D % 2 == 0 ? D / 2 : D;
  const V s2 = u * u + v * v + epsilon;
  const V root = D % 2 == 0 ? Sqrt(s2) : Sqrt(Sqrt(s2));
  V denom = root;
  for (int e = 1; e < kPowers; ++e) denom *= root;
  return g > 0 ? g / denom : V{};
}

// x <- R^-1 R^-T x for the upper-triangular R (column-major, kCols x kCols) with the
// reciprocals of its diagonal in `inv` (a vector division costs ~10 multiplications).
template <int kCols, class V>
GEOMFIT_INLINE void SolveGram(const V* r, const V* inv, V* x) {
  for (int i = 0; i < kCols; ++i) {  // R^T y = x
    V sum = x[i];
    for (int k = 0; k < i; ++k) sum -= r[i * kCols + k] * x[k];
    x[i] = sum * inv[i];
  }
  for (int i = kCols - 1; i >= 0; --i) {  // R x = y
    V sum = x[i];
    for (int k = i + 1; k < kCols; ++k) sum -= r[k * kCols + i] * x[k];
    x[i] = sum * inv[i];
  }
}

// The fit by the normal equations of the column-scaled weighted Vandermonde matrix A
// ((2.3.5), (2.6.6)), for the lanes of `mask` (rows gathered as in Solve, `m` of them).
// A^T A is never formed column by column: its entry (i, j) is the weighted moment
// sum_r w_r^2 u^(a_i + a_j) v^(b_i + b_j) over the product of the two columns' norms, so
// one pass over the rows accumulates the NumCoefficients(2D) moments and the moments of
// the right-hand sides. Its Cholesky factor R is the QR's R up to row signs, so the
// condition (2.4) is computed from it as the QR path does. Writes and returns the lanes
// whose pivots are positive and whose condition is below the limits above; `r`
// (kCols^2 vectors) is scratch.
template <int W, int D, int First, class V>
GEOMFIT_INLINE int SolveNormal(const V* gu, const V* gv, const V* gg, const V* grhs, int m, int dims, V hv,
                               const double* h, int mask, const WlsSettings& S, double* const coefficients[],
                               WlsSolution solutions[], V* r) {
  constexpr int kN = NumCoefficients(D), kCols = kN - First, kMoments = NumCoefficients(2 * D);
  V mom[kMoments], rmom[3][kN];  // moment of u^a v^b at TaylorIndex(a, b)
  for (int t = 0; t < kMoments; ++t) mom[t] = V{};
  for (int d = 0; d < dims; ++d)
    for (int t = 0; t < kN; ++t) rmom[d][t] = V{};
  for (int i = 0; i < m; ++i) {
    const V u = gu[i] / hv, v = gv[i] / hv;
    const V w = Weight<D>(u, v, gg[i], S.weight_epsilon);
    V wu[2 * D + 1], vp[2 * D + 1];
    wu[0] = w * w;
    vp[0] = Splat<V>(1);
    for (int e = 1; e <= 2 * D; ++e) wu[e] = wu[e - 1] * u, vp[e] = vp[e - 1] * v;
    for (int p = 0, t = 0; p <= 2 * D; ++p)
      for (int k = 0; k <= p; ++k, ++t) mom[t] += wu[p - k] * vp[k];
    for (int d = 0; d < dims; ++d) {
      const V b = grhs[d * m + i];
      for (int p = 0, t = 0; p <= D; ++p)
        for (int k = 0; k <= p; ++k, ++t) rmom[d][t] += wu[p - k] * vp[k] * b;
    }
  }
  // Column c is the monomial (ea[c], eb[c]); f[c] = 1 / its norm (the scaling (2.6.6)
  // with the factorials cancelled).
  int ea[kCols], eb[kCols];
  V f[kCols];
  for (int p = First, c = 0; p <= D; ++p)
    for (int k = 0; k <= p; ++k, ++c) ea[c] = p - k, eb[c] = k;
  for (int c = 0; c < kCols; ++c) {
    const V norm2 = mom[TaylorIndex(2 * ea[c], 2 * eb[c])];
    f[c] = norm2 > 0 ? 1.0 / Sqrt(norm2) : Splat<V>(1);
  }
  // Cholesky factor of the scaled A^T A in place (upper, column-major).
  V ok = Splat<V>(1), inv[kCols];  // inv: reciprocals of R's diagonal
  for (int j = 0; j < kCols; ++j) {
    V* rj = r + j * kCols;
    for (int i = 0; i <= j; ++i) rj[i] = mom[TaylorIndex(ea[i] + ea[j], eb[i] + eb[j])] * f[i] * f[j];
    for (int i = 0; i < j; ++i) {
      const V* ri = r + i * kCols;
      V sum = rj[i];
      for (int k = 0; k < i; ++k) sum -= ri[k] * rj[k];
      rj[i] = sum * inv[i];
    }
    V d = rj[j];
    for (int k = 0; k < j; ++k) d -= rj[k] * rj[k];
    // A pivot lost to cancellation (a condition near 1/sqrt(eps)) leaves the lane to the QR.
    ok = d > 1e-10 ? ok : V{};
    rj[j] = d > 1e-10 ? Sqrt(d) : Splat<V>(1);
    inv[j] = 1.0 / rj[j];
  }
  // Condition (2.4): 1-norms of R and R^-1 (column by column, as InvertUpper).
  V norm_r = V{}, norm_i = V{};
  for (int c = 0; c < kCols; ++c) {
    V x[kCols];
    for (int i = 0; i < kCols; ++i) x[i] = V{};
    x[c] = Splat<V>(1);
    for (int i = c; i >= 0; --i) {
      const V* ri = r + i * kCols;
      const V xi = x[i] *= inv[i];
      for (int l = 0; l < i; ++l) x[l] -= xi * ri[l];
    }
    V sr = V{}, si = V{};
    for (int i = 0; i <= c; ++i) sr += Abs(r[c * kCols + i]), si += Abs(x[i]);
    norm_r = Max(norm_r, sr);
    norm_i = Max(norm_i, si);
  }
  const V condition = norm_r * norm_i;
  const double limit = S.cond_threshold[D] / 2 < kRefinedCondition ? S.cond_threshold[D] / 2 : kRefinedCondition;
  ok = condition <= limit ? ok : V{};
  bool refine = false;
  for (int l = 0; l < W; ++l)
    if (!(ok[l] != 0))
      mask &= ~(1 << l);
    else if (mask >> l & 1)
      refine |= condition[l] > kPlainCondition;
  if (mask == 0) return 0;

  // y = R^-1 R^-T (scaled A^T b); with refinement, y += R^-1 R^-T A^T (b - A y), the
  // residual's moments accumulated row by row like the right-hand sides'.
  V y[3][kCols];
  for (int d = 0; d < dims; ++d) {
    for (int c = 0; c < kCols; ++c) y[d][c] = rmom[d][TaylorIndex(ea[c], eb[c])] * f[c];
    SolveGram<kCols>(r, inv, y[d]);
  }
  if (refine) {
    V g[3][kCols];
    for (int d = 0; d < dims; ++d)
      for (int c = 0; c < kCols; ++c) g[d][c] = V{};
    for (int i = 0; i < m; ++i) {
      const V u = gu[i] / hv, v = gv[i] / hv;
      const V w = Weight<D>(u, v, gg[i], S.weight_epsilon);
      V up[D + 1], vp[D + 1];
      up[0] = vp[0] = Splat<V>(1);
      for (int e = 1; e <= D; ++e) up[e] = up[e - 1] * u, vp[e] = vp[e - 1] * v;
      for (int d = 0; d < dims; ++d) {
        V e = grhs[d * m + i];
        for (int c = 0; c < kCols; ++c) e -= f[c] * y[d][c] * up[ea[c]] * vp[eb[c]];
        e *= w * w;
        for (int c = 0; c < kCols; ++c) g[d][c] += e * up[ea[c]] * vp[eb[c]];
      }
    }
    // Only the lanes above kPlainCondition take the correction: a lane's result must not
    // depend on the other lanes of its batch.
    // (1 or 0 per lane, set lane by lane: GCC 12 fails on this vector comparison here.)
    V refined;
    for (int l = 0; l < W; ++l) refined[l] = condition[l] > kPlainCondition ? 1.0 : 0.0;
    for (int d = 0; d < dims; ++d) {
      for (int c = 0; c < kCols; ++c) g[d][c] *= f[c];
      SolveGram<kCols>(r, inv, g[d]);
      for (int c = 0; c < kCols; ++c) y[d][c] += refined * g[d][c];  // y + 0 = y exactly
    }
  }

  // Unscaling as in Solve: c_ab = a! b! f_c y_c / h^(a+b).
  V hp[D + 1];
  Powers<D>(hv, hp);
  for (int d = 0; d < dims; ++d) {
    for (int c = 0; c < kCols; ++c) {
      const V coef = Factorial(ea[c]) * Factorial(eb[c]) * f[c] * y[d][c] / hp[ea[c] + eb[c]];
      const int t = TaylorIndex(ea[c], eb[c]);
      StoreLanes<W>(coef, mask, d * kN + t, coefficients);
    }
  }
  FinishLanes<W, D, First>(mask, dims, condition, h, coefficients, solutions);
  return mask;
}

// SolveWls (wls.cc) at degree D with the first First Taylor columns fixed, for the lanes
// of `problems`; the order of operations follows SolveWls so results agree to round-off.
template <int W, int D, int First>
GEOMFIT_INLINE int Solve(const WlsProblem* const problems[], int count, const WlsSettings& S,
                         double* const coefficients[], double* const ops[], WlsSolution solutions[],
                         WlsBatchWorkspace& work) {
  using V = typename Lanes<W>::V;
  constexpr int kN = NumCoefficients(D), kCols = kN - First;
  const int dims = problems[0]->dims;
  // Rows with a positive safeguard factor, per lane; lanes the plain path cannot take
  // (too few rows for the columns: SolveWls's rank-deficient path) stay out of `mask`.
  int keep[W][kMaxStencil], rows[W] = {};
  double h[W];
  int mask = 0, m = 0;
  for (int l = 0; l < count; ++l) {
    const WlsProblem& P = *problems[l];
    if (P.dims != dims) continue;
    double radius2 = 0;
    int n = 0;
    for (int r = 0; r < P.rows; ++r) {  // branch-free compaction
      const bool kept = P.gamma[r] > 0;
      const double d2 = P.u[r] * P.u[r] + P.v[r] * P.v[r];
      keep[l][n] = r;
      n += kept;
      radius2 = kept && radius2 < d2 ? d2 : radius2;
    }
    rows[l] = n;
    if (rows[l] < kCols || radius2 == 0) {
      rows[l] = 0;
      continue;
    }
    h[l] = __builtin_sqrt(radius2);
    mask |= 1 << l;
    m = m < rows[l] ? rows[l] : m;
  }
  if (mask == 0) return 0;
  for (int l = 0; l < W; ++l)
    if (!(mask >> l & 1)) rows[l] = 0, h[l] = 1;

  // Workspace: [A | B] column-major with ld = m, then weights, gathered rows, Q's
  // scratch column, R^-1 (k x k).
  V* a = reinterpret_cast<V*>(work.data);
  V* B = a + kCols * m;
  V* weight = a + (kCols + 3) * m;
  V* gu = weight + m;
  V* gv = gu + m;
  V* gg = gv + m;
  V* grhs = gg + m;  // 3 x m
  V* z = grhs + 3 * m;
  V* rinv = z + m;
  for (int i = 0; i < m; ++i) {
    gu[i] = gv[i] = gg[i] = V{};
    for (int d = 0; d < dims; ++d) grhs[d * m + i] = V{};
  }
  for (int l = 0; l < W; ++l) {
    if (!(mask >> l & 1)) continue;
    const WlsProblem& P = *problems[l];
    for (int i = 0; i < rows[l]; ++i) {
      const int r = keep[l][i];
      gu[i][l] = P.u[r];
      gv[i][l] = P.v[r];
      gg[i][l] = P.gamma[r];
      for (int d = 0; d < dims; ++d) grhs[d * m + i][l] = P.rhs[d][r];
    }
  }
  V hv;
  for (int l = 0; l < W; ++l) hv[l] = h[l];

  // Normal equations first, for fits without operator rows; the lanes they leave go on
  // to the QR below.
  int done = 0;
  bool any_op = false;
  for (int l = 0; l < count; ++l) any_op |= ops[l] != nullptr;
  if (!any_op && NormalEquationsEnabled()) {
    done = SolveNormal<W, D, First>(gu, gv, gg, grhs, m, dims, hv, h, mask, S, coefficients, solutions, rinv);
    mask &= ~done;
    if (mask == 0) return done;
  }

  // Weighted Vandermonde (2.3.5) with weights (2.2.1); padded rows get weight 0.
  double inv_fact[kCols];
  {
    int c = 0;
    for (int p = First; p <= D; ++p)
      for (int k = 0; k <= p; ++k) inv_fact[c++] = 1.0 / (Factorial(p - k) * Factorial(k));
  }
  for (int i = 0; i < m; ++i) {
    const V u = gu[i] / hv, v = gv[i] / hv;
    const V w = weight[i] = Weight<D>(u, v, gg[i], S.weight_epsilon);
    V up[D + 1], vp[D + 1];
    up[0] = vp[0] = Splat<V>(1);
    for (int e = 1; e <= D; ++e) up[e] = up[e - 1] * u, vp[e] = vp[e - 1] * v;
    int c = 0;
    for (int p = First; p <= D; ++p)
      for (int k = 0; k <= p; ++k, ++c) a[c * m + i] = w * inv_fact[c] * up[p - k] * vp[k];
    for (int d = 0; d < dims; ++d) B[d * m + i] = w * grhs[d * m + i];
  }
  // Column scaling (2.6.6).
  V scale[kCols];
  for (int c = 0; c < kCols; ++c) {
    V norm2 = V{};
    for (int i = 0; i < m; ++i) norm2 += a[c * m + i] * a[c * m + i];
    scale[c] = norm2 > 0 ? 1.0 / Sqrt(norm2) : Splat<V>(1);
    for (int i = 0; i < m; ++i) a[c * m + i] *= scale[c];
  }
  // Householder QR, [A | B] -> [R | Q^T B] (small_qr.h, lane by lane).
  V tau[kCols];
  for (int j = 0; j < kCols; ++j) {
    V* x = a + j * m;
    V sigma = V{};
    for (int i = j + 1; i < m; ++i) sigma += x[i] * x[i];
    const V alpha = x[j];
    const V norm = Sqrt(alpha * alpha + sigma);
    const V beta = alpha >= 0 ? -norm : norm;
    // sigma == 0: already triangular in this column, H = I. (The three selects come
    // before any loop: GCC 12 fails on a vector comparison kept across blocks at AVX-512.)
    const V inv = sigma == 0 ? Splat<V>(1) : 1.0 / (alpha - beta);
    tau[j] = sigma == 0 ? V{} : (beta - alpha) / beta;
    const V xj = sigma == 0 ? alpha : beta;
    for (int i = j + 1; i < m; ++i) x[i] *= inv;
    x[j] = xj;
    int c = j + 1;
    for (; c + 4 <= kCols + dims; c += 4) {
      V* const y[4] = {a + c * m, a + (c + 1) * m, a + (c + 2) * m, a + (c + 3) * m};
      ReflectColumns<4>(x, tau[j], j, m, y);
    }
    for (; c < kCols + dims; ++c) Reflect(x, tau[j], j, m, a + c * m);
  }
  // Zero pivots and the condition cut-off (2.4) at degree D leave the plain path.
  V amax = Abs(a[0]);
  amax = amax < 1 ? Splat<V>(1) : amax;
  const V tiny = 1e-13 * amax;
  V ok = Splat<V>(1);  // 1 in lanes still on the plain path
  for (int c = 0; c < kCols; ++c) ok = Abs(a[c * m + c]) > tiny ? ok : V{};
  for (int c = 0; c < kCols; ++c) {  // R^-1 column by column (InvertUpper)
    V* x = rinv + c * kCols;
    for (int i = 0; i < kCols; ++i) x[i] = V{};
    x[c] = Splat<V>(1);
    for (int i = c; i >= 0; --i) {
      const V* ri = a + i * m;
      const V xi = x[i] /= ri[i];
      for (int l = 0; l < i; ++l) x[l] -= xi * ri[l];
    }
  }
  V norm_r = V{}, norm_i = V{};  // 1-norms of R and R^-1
  for (int c = 0; c < kCols; ++c) {
    V sr = V{}, si = V{};
    for (int i = 0; i <= c; ++i) sr += Abs(a[c * m + i]), si += Abs(rinv[c * kCols + i]);
    norm_r = Max(norm_r, sr);
    norm_i = Max(norm_i, si);
  }
  const V condition = norm_r * norm_i;
  ok = condition <= S.cond_threshold[D] ? ok : V{};
  for (int l = 0; l < W; ++l)
    if (!(ok[l] != 0)) mask &= ~(1 << l);
  if (mask == 0) return done;

  // Back substitution and unscaling: c_jk = s_c y_c / h^(j+k).
  V hp[D + 1];
  Powers<D>(hv, hp);
  for (int d = 0; d < dims; ++d) {
    V y[kCols];
    const V* qtb = B + d * m;
    for (int i = kCols - 1; i >= 0; --i) {
      V sum = qtb[i];
      for (int l = i + 1; l < kCols; ++l) sum -= a[l * m + i] * y[l];
      y[i] = sum / a[i * m + i];
    }
    int c = 0;
    for (int p = First; p <= D; ++p)
      for (int kk = 0; kk <= p; ++kk, ++c) {
        const V coef = scale[c] * y[c] / hp[p];
        const int t = TaylorIndex(p - kk, kk);
        StoreLanes<W>(coef, mask, d * kN + t, coefficients);
      }
  }
  FinishLanes<W, D, First>(mask, dims, condition, h, coefficients, solutions);

  // Operator rows (SolveWls): row c = s_c / h^p * (Q z_c)^T Omega, z_c = R^-T e_c.
  if (any_op) {
    const int op_rows = S.op_rows < 0 ? kN : (S.op_rows < kN ? S.op_rows : kN);
    for (int l = 0; l < W; ++l)
      if (mask >> l & 1 && ops[l])
        for (int i = 0, n = kN * problems[l]->rows; i < n; ++i) ops[l][i] = 0;
    int c = 0;
    for (int p = First; p <= D; ++p)
      for (int kk = 0; kk <= p; ++kk, ++c) {
        const int t = TaylorIndex(p - kk, kk);
        if (t >= op_rows) continue;
        for (int i = 0; i < m; ++i) z[i] = V{};
        for (int l = c; l < kCols; ++l) z[l] = rinv[l * kCols + c];
        for (int j = kCols - 1; j >= 0; --j) Reflect(a + j * m, tau[j], j, m, z);
        for (int l = 0; l < W; ++l) {
          if (!(mask >> l & 1) || !ops[l]) continue;
          double* row = ops[l] + static_cast<size_t>(t) * problems[l]->rows;
          for (int i = 0; i < rows[l]; ++i) row[keep[l][i]] = weight[i][l] * z[i][l] * scale[c][l] / hp[p][l];
        }
      }
  }
  return mask | done;
}


// FitHeightsBatch at degree D with the first First Taylor columns fixed, for up to W
// lanes: fit.cc's SetUpVertex (FrameFromNormal, then per stencil point u, v, the height
// and the safeguard factor, each with Eigen's operations in Eigen's order: a dot product
// of 3-vectors is (x0 y0 + x1 y1) + x2 y2), then Solve's row compaction and radius, then
// SolveNormal. Rows are not compacted: a row with gamma 0 has weight 0, so it adds
// exact zeros to every moment (sums that start at +0 never become -0) and the lane's
// bits are those of the compacted rows.
template <class R, int D, int First>
GEOMFIT_INLINE int FitHeights(const HeightLanesInput& in, const HeightLane* lanes, int count, const WlsSettings& S,
                              WlsSolution solutions[], int used[], WlsBatchWorkspace& work) {
  constexpr int W = R::kW;
  using V = typename Lanes<W>::V;
  constexpr int kCols = NumCoefficients(D) - First;
  int32_t self[W];
  const int32_t* pts[W];
  int32_t nrows[W];
  int m = 0;
  for (int l = 0; l < W; ++l) {
    const HeightLane& L = lanes[l < count ? l : 0];
    self[l] = L.slot;
    pts[l] = L.points + First;
    nrows[l] = l < count ? L.size - First : 0;
    m = m < nrows[l] ? nrows[l] : m;
  }
  // Every row's record requested up front (the row loop's window holds ~3 rows' loads).
  for (int l = 0; l < count; ++l)
    for (int i = 0; i < nrows[l]; ++i) __builtin_prefetch(in.points + pts[l][i]);
  const V one = Splat<V>(1);
  V x0[3], n[3];
  {
    const double* at[W];
    V q[6];
    for (int l = 0; l < W; ++l) at[l] = in.points[self[l]].p;
    R::Records(at, q);
    for (int c = 0; c < 3; ++c) x0[c] = q[c], n[c] = q[3 + c];
  }
  // FrameFromNormal (frames.h), lane by lane.
  V t1[3], t2[3];
  {
    const V a0 = Abs(n[0]), a1 = Abs(n[1]), a2 = Abs(n[2]);
    // One comparison per select, masks combined in 0/1 arithmetic (exact): GCC 12 turns
    // nested selects and combined comparison masks into scalar code.
    const V c10 = Select(a1 < a0, one, V{}), c21 = Select(a2 < a1, one, V{}), c20 = Select(a2 < a0, one, V{});
    const V is2 = c10 * c21 + (one - c10) * c20;
    const V is1 = c10 * (one - c21);
    const V is0 = one - is1 - is2;
    const V s12 = Select(is1 != 0, n[1], n[2]);
    const V s = Select(is0 != 0, n[0], s12);
    const V e0 = is0 - s * n[0], e1 = is1 - s * n[1], e2 = is2 - s * n[2];
    const V z = e0 * e0 + e1 * e1 + e2 * e2;
    const V r = Select(z > 0, Sqrt(z), one);  // e / 1 = e exactly where z is not positive
    t1[0] = e0 / r;
    t1[1] = e1 / r;
    t1[2] = e2 / r;
    t2[0] = n[1] * t1[2] - n[2] * t1[1];
    t2[1] = n[2] * t1[0] - n[0] * t1[2];
    t2[2] = n[0] * t1[1] - n[1] * t1[0];
  }
  for (int l = 0; l < count; ++l) {
    LocalFrame& fr = *lanes[l].frame;
    fr.origin = Eigen::Vector3d(x0[0][l], x0[1][l], x0[2][l]);
    fr.t1 = Eigen::Vector3d(t1[0][l], t1[1][l], t1[2][l]);
    fr.t2 = Eigen::Vector3d(t2[0][l], t2[1][l], t2[2][l]);
    fr.normal = Eigen::Vector3d(n[0][l], n[1][l], n[2][l]);
  }

  // Rows in lanes; padded rows (past a lane's stencil) read the lane's own centre and
  // get gamma 0.
  V* gu = reinterpret_cast<V*>(work.data);
  V* gv = gu + m;
  V* gg = gv + m;
  V* grhs = gg + m;
  V* r = grhs + m;  // kCols^2 vectors: SolveNormal's scratch
  V kept = V{}, radius2 = V{};
  const V cos_cut = Splat<V>(in.cos_cut);
  for (int i = 0; i < m; ++i) {
    const double* at[W];
    for (int l = 0; l < W; ++l) at[l] = in.points[i < nrows[l] ? pts[l][i] : self[l]].p;
    V q[6];
    R::Records(at, q);
    const V d0 = q[0] - x0[0], d1 = q[1] - x0[1], d2 = q[2] - x0[2];
    const V u = d0 * t1[0] + d1 * t1[1] + d2 * t1[2];
    const V v = d0 * t2[0] + d1 * t2[1] + d2 * t2[2];
    const V g = First == 0 && i == 0 ? one : q[3] * n[0] + q[4] * n[1] + q[5] * n[2];
    const V gamma = R::Gamma(g, cos_cut, i, nrows);
    gu[i] = u;
    gv[i] = v;
    gg[i] = gamma;
    grhs[i] = d0 * n[0] + d1 * n[1] + d2 * n[2];
    kept += R::IfPositive(gamma, one);
    const V kept_dd = R::IfPositive(gamma, u * u + v * v);  // radius2 >= 0: the kept rows' maximum
    radius2 = radius2 < kept_dd ? kept_dd : radius2;
  }
  int mask = 0;
  double h[W];
  V hv;
  double* coefficients[W];
  for (int l = 0; l < W; ++l) {
    coefficients[l] = lanes[l < count ? l : 0].coefficients;
    if (l < count) used[l] = static_cast<int>(kept[l]) + First;
    const bool plain = l < count && kept[l] >= kCols && radius2[l] != 0;
    h[l] = plain ? __builtin_sqrt(radius2[l]) : 1.0;
    hv[l] = h[l];
    mask |= plain << l;
  }
  if (mask == 0) return 0;
  return SolveNormal<W, D, First>(gu, gv, gg, grhs, m, 1, hv, h, mask, S, coefficients, solutions, r);
}

// f(integral_constant<D>, integral_constant<First>) at the settings' degree, interpolating or not.
template <int D>
using Int = std::integral_constant<int, D>;
template <class F>
GEOMFIT_INLINE int ForDegree(const WlsSettings& S, F&& f) {
  if (S.interpolate) {
    switch (S.degree) {
      case 1: return f(Int<1>{}, Int<1>{});
      case 2: return f(Int<2>{}, Int<1>{});
      case 3: return f(Int<3>{}, Int<1>{});
      case 4: return f(Int<4>{}, Int<1>{});
      case 5: return f(Int<5>{}, Int<1>{});
      case 6: return f(Int<6>{}, Int<1>{});
      default: return 0;
    }
  }
  switch (S.degree) {
    case 1: return f(Int<1>{}, Int<0>{});
    case 2: return f(Int<2>{}, Int<0>{});
    case 3: return f(Int<3>{}, Int<0>{});
    case 4: return f(Int<4>{}, Int<0>{});
    case 5: return f(Int<5>{}, Int<0>{});
    case 6: return f(Int<6>{}, Int<0>{});
    default: return 0;
  }
}

// The problems in groups of W lanes.
template <int W>
GEOMFIT_INLINE int SolveAny(const WlsProblem* const problems[], int count, const WlsSettings& S,
                            double* const coefficients[], double* const ops[], WlsSolution solutions[],
                            WlsBatchWorkspace& work) {
  if (count <= 0 || count > kWlsLanes || S.oscillation_safeguard) return 0;
  int mask = 0;
  for (int g = 0; g < count; g += W) {
    const int n = count - g < W ? count - g : W;
    mask |= ForDegree(S, [&](auto d, auto first) GEOMFIT_INLINE_LAMBDA {
              return Solve<W, decltype(d)::value, decltype(first)::value>(problems + g, n, S, coefficients + g,
                                                                          ops + g, solutions + g, work);
            })
            << g;
  }
  return mask;
}

// The height fits in groups of W lanes.
template <class R>
GEOMFIT_INLINE int FitHeightsAny(const HeightLanesInput& in, const HeightLane lanes[], int count,
                                 const WlsSettings& S, WlsSolution solutions[], int used[], WlsBatchWorkspace& work) {
  if (count <= 0 || count > kWlsLanes || S.oscillation_safeguard || !NormalEquationsEnabled()) return 0;
  constexpr int W = R::kW;
  int mask = 0;
  for (int g = 0; g < count; g += W) {
    const int n = count - g < W ? count - g : W;
    mask |= ForDegree(S, [&](auto d, auto first) GEOMFIT_INLINE_LAMBDA {
              return FitHeights<R, decltype(d)::value, decltype(first)::value>(in, lanes + g, n, S, solutions + g,
                                                                               used + g, work);
            })
            << g;
  }
  return mask;
}

// One copy of the kernel per instruction set; `flatten` inlines the whole kernel into each.
__attribute__((flatten)) int SolvePortable(const WlsProblem* const problems[], int count, const WlsSettings& S,
                                           double* const coefficients[], double* const ops[],
                                           WlsSolution solutions[], WlsBatchWorkspace& work) {
  return SolveAny<4>(problems, count, S, coefficients, ops, solutions, work);
}
__attribute__((flatten)) int FitHeightsPortable(const HeightLanesInput& in, const HeightLane lanes[], int count,
                                                const WlsSettings& S, WlsSolution solutions[], int used[],
                                                WlsBatchWorkspace& work) {
  return FitHeightsAny<PortableRows<4>>(in, lanes, count, S, solutions, used, work);
}

#if defined(__x86_64__) && defined(__GNUC__)
#define GEOMFIT_HAVE_X86_KERNELS 1
__attribute__((flatten, target("avx2"))) int SolveAvx2(const WlsProblem* const problems[], int count,
                                                           const WlsSettings& S, double* const coefficients[],
                                                           double* const ops[], WlsSolution solutions[],
                                                           WlsBatchWorkspace& work) {
  return SolveAny<4>(problems, count, S, coefficients, ops, solutions, work);
}
__attribute__((flatten, target("avx512f,avx512dq,avx512vl,avx512bw,prefer-vector-width=512"))) int SolveAvx512(
    const WlsProblem* const problems[], int count, const WlsSettings& S, double* const coefficients[],
    double* const ops[], WlsSolution solutions[], WlsBatchWorkspace& work) {
  return SolveAny<8>(problems, count, S, coefficients, ops, solutions, work);
}
__attribute__((flatten, target("avx2"))) int FitHeightsAvx2(const HeightLanesInput& in, const HeightLane lanes[],
                                                            int count, const WlsSettings& S,
                                                            WlsSolution solutions[], int used[],
                                                            WlsBatchWorkspace& work) {
  return FitHeightsAny<Avx2Rows>(in, lanes, count, S, solutions, used, work);
}
__attribute__((flatten, target("avx512f,avx512dq,avx512vl,avx512bw,prefer-vector-width=512"))) int FitHeightsAvx512(
    const HeightLanesInput& in, const HeightLane lanes[], int count, const WlsSettings& S, WlsSolution solutions[],
    int used[], WlsBatchWorkspace& work) {
  return FitHeightsAny<Avx512Rows>(in, lanes, count, S, solutions, used, work);
}
#endif

using Kernel = int (*)(const WlsProblem* const[], int, const WlsSettings&, double* const[], double* const[],
                       WlsSolution[], WlsBatchWorkspace&);

using HeightsKernel = int (*)(const HeightLanesInput&, const HeightLane[], int, const WlsSettings&, WlsSolution[],
                              int[], WlsBatchWorkspace&);

struct Isa {
  const char* name;
  Kernel kernel;
  HeightsKernel heights;
  bool (*supported)();
};

const Isa kIsas[] = {
#ifdef GEOMFIT_HAVE_X86_KERNELS
    {"avx512", SolveAvx512, FitHeightsAvx512,
     [] {
       __builtin_cpu_init();
       return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
              __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw");
     }},
    {"avx2", SolveAvx2, FitHeightsAvx2,
     [] {
       __builtin_cpu_init();
       return static_cast<bool>(__builtin_cpu_supports("avx2"));
     }},
#endif
    {"portable", SolvePortable, FitHeightsPortable, [] { return true; }},
};

// The best kernel this CPU runs (first supported in kIsas), unless SetWlsBatchIsa chose.
const Isa*& Selected() {
  static const Isa* selected = [] {
    for (const Isa& isa : kIsas)
      if (isa.supported()) return &isa;
    return &kIsas[0];
  }();
  return selected;
}

}  // namespace

int SolveWlsBatch(const WlsProblem* const problems[], int count, const WlsSettings& settings,
                  double* const coefficients[], double* const ops[], WlsSolution solutions[],
                  WlsBatchWorkspace& work) {
  return Selected()->kernel(problems, count, settings, coefficients, ops, solutions, work);
}

int FitHeightsBatch(const HeightLanesInput& in, const HeightLane lanes[], int count, const WlsSettings& settings,
                    WlsSolution solutions[], int used[], WlsBatchWorkspace& work) {
  return Selected()->heights(in, lanes, count, settings, solutions, used, work);
}

PointRecords MakePointRecords(const Positions& positions, const Positions& normals, const int32_t* order,
                              int threads) {
  const int64_t nv = positions.rows();
  PointRecords records(nv);
  ParallelFor(nv, threads, [&](int64_t k) {
    const int64_t v = order ? order[k] : k;
    if (order && k + 16 < nv) {  // random reads in the input numbering
      const int64_t w = order[k + 16];
      __builtin_prefetch(positions.data() + 3 * w);
      __builtin_prefetch(normals.data() + 3 * w);
    }
    PointRecord& r = records[k];
    for (int c = 0; c < 3; ++c) r.p[c] = positions(v, c), r.n[c] = normals(v, c);
    r.pad[0] = r.pad[1] = 0;
  }, 4096);
  return records;
}

bool WlsBatchNormalEquations() { return NormalEquationsEnabled(); }

const char* WlsBatchIsa() { return Selected()->name; }

void SetWlsBatchNormalEquations(bool enabled) { NormalEquationsFlag() = enabled; }

std::vector<std::string> WlsBatchIsas() {
  std::vector<std::string> names;
  for (const Isa& isa : kIsas)
    if (isa.supported()) names.push_back(isa.name);
  return names;
}

bool SetWlsBatchIsa(std::string_view isa) {
  for (const Isa& candidate : kIsas)
    if (isa == candidate.name && candidate.supported()) {
      Selected() = &candidate;
      return true;
    }
  return false;
}

}  // namespace geomfit
