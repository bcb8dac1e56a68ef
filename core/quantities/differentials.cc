#include "core/quantities/differentials.h"

#include <cmath>
#include <limits>

#include "core/mesh/topology.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {

PointDifferentials DifferentialsFromJet(const SurfaceJet& jet) {
  PointDifferentials out;
  // J = QR by Gram-Schmidt (3.2.7).
  const Eigen::Vector3d a = jet.J.col(0), b = jet.J.col(1);
  const double r11 = a.norm();
  const Eigen::Vector3d q1 = a / r11;
  const double r12 = q1.dot(b);
  Eigen::Vector3d q2 = b - r12 * q1;
  const double r22 = q2.norm();
  q2 /= r22;
  const Eigen::Vector3d n = q1.cross(q2);  // = x_u x x_v / l (3.2.2)
  out.normal = n;
  // Second fundamental matrix (3.2.4) and the symmetric shape operator (3.2.7), negated
  // so that a sphere with outward normals has positive curvatures.
  const double b11 = n.dot(jet.xuu), b12 = n.dot(jet.xuv), b22 = n.dot(jet.xvv);
  const double i11 = 1 / r11, i12 = -r12 / (r11 * r22), i22 = 1 / r22;  // R^-1
  // W = -R^-T B R^-1 with R^-1 = [i11 i12; 0 i22].
  const double w11 = -(i11 * b11 * i11);
  const double w12 = -(i11 * (b11 * i12 + b12 * i22));
  const double w22 = -(i12 * (b11 * i12 + b12 * i22) + i22 * (b12 * i12 + b22 * i22));
  out.mean = 0.5 * (w11 + w22);
  out.gaussian = w11 * w22 - w12 * w12;
  // Principal curvatures (3.2.9) and directions (3.2.10).
  const double disc = std::sqrt((w11 - w22) * (w11 - w22) + 4 * w12 * w12);
  out.k1 = 0.5 * (w11 + w22 + disc);
  out.k2 = 0.5 * (w11 + w22 - disc);
  if (disc <= 1e-14 * (std::abs(w11) + std::abs(w22) + 1e-300)) {
    out.e1 = q1;
    out.e2 = q2;
  } else {
    auto direction = [&](double ki, double kother) -> Eigen::Vector3d {
      const Eigen::Vector3d d = std::abs(w11 - kother) > std::abs(w11 - ki)
                                    ? Eigen::Vector3d((w11 - kother) * q1 + w12 * q2)
                                    : Eigen::Vector3d(w12 * q1 - (w11 - ki) * q2);
      return d.normalized();
    };
    out.e1 = direction(out.k1, out.k2);
    out.e2 = n.cross(out.e1);  // orthonormal and right-handed by construction
  }
  out.tensor = out.k1 * out.e1 * out.e1.transpose() + out.k2 * out.e2 * out.e2.transpose();
  return out;
}

namespace {

void EvaluateVertex(const SurfaceFits& fits, uint32_t q, int64_t v, Differentials& d) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  PointDifferentials p;
  const VertexDiagnostics& diag = fits.diagnostics(static_cast<int>(v));
  if (diag.degree_used >= 1) {
    p = DifferentialsFromJet(fits.Jet(static_cast<int>(v)));
  } else {  // no usable fit: the frame normal (NaN if isolated), NaN curvatures
    p.normal = (diag.flags & kFlagIsolated) ? Eigen::Vector3d::Constant(nan) : fits.frame(static_cast<int>(v)).normal;
    p.mean = p.gaussian = p.k1 = p.k2 = nan;
    p.e1 = p.e2 = Eigen::Vector3d::Constant(nan);
    p.tensor = Eigen::Matrix3d::Constant(nan);
  }
  d.diagnostics[v] = diag;
  if (q & kNormals) d.normals.row(v) = p.normal;
  if (q & kMeanCurvature) d.mean(v) = p.mean;
  if (q & kGaussianCurvature) d.gaussian(v) = p.gaussian;
  if (q & kPrincipalCurvatures) d.k1(v) = p.k1, d.k2(v) = p.k2;
  if (q & kPrincipalDirections) d.dir1.row(v) = p.e1, d.dir2.row(v) = p.e2;
  if (q & kCurvatureTensor) d.tensor.row(v) = Eigen::Map<const Eigen::Matrix<double, 1, 9>>(p.tensor.data());
}

// Differentials of height-function fits (LHF, dims 1) kLanes vertices at a time: Jet's
// and DifferentialsFromJet's operations in their order on every lane, so each lane has
// EvaluateVertex's bits, as vectors of kLanes doubles (the divisions and square roots
// of different vertices overlap instead of forming one long chain per vertex). Both
// principal-direction branches are computed and selected per lane by masks (GCC 12
// compiles some vector ?: to scalar code per lane).
constexpr int kLanes = 8;
typedef double V __attribute__((vector_size(kLanes * sizeof(double))));
typedef long long M __attribute__((vector_size(kLanes * sizeof(double))));  // comparison masks

#define GEOMFIT_LANES_INLINE inline __attribute__((always_inline))
GEOMFIT_LANES_INLINE V Pick(M mask, V a, V b) {
  return reinterpret_cast<V>((reinterpret_cast<M>(a) & mask) | (reinterpret_cast<M>(b) & ~mask));
}
GEOMFIT_LANES_INLINE V Magnitude(V x) {  // |x| bit for bit (sign cleared)
  return reinterpret_cast<V>(reinterpret_cast<M>(x) & (M{} + 0x7fffffffffffffffLL));
}
GEOMFIT_LANES_INLINE V SqrtLanes(V x) {
  V r;
  for (int l = 0; l < kLanes; ++l) r[l] = __builtin_sqrt(x[l]);
  return r;
}
GEOMFIT_LANES_INLINE void HeightLanes(const SurfaceFits& fits, uint32_t q, const int64_t* vs, int count, Differentials& d) {
  const int nc = fits.num_coefficients();
  auto coef = [&](const double* c, int j, int k) { return TaylorIndex(j, k) < nc ? c[TaylorIndex(j, k)] : 0.0; };
  // Jet (dims 1); the padding lanes repeat lane 0. Staged lane by lane in memory (built
  // in registers, each vector is a chain of 8 dependent inserts).
  alignas(64) double at[14][kLanes];  // t1, t2, normal (3 each), c10, c01, c20, c11, c02
  for (int l = 0; l < kLanes; ++l) {
    const int v = static_cast<int>(vs[l < count ? l : 0]);
    const LocalFrame& fr = fits.frame(v);
    const double* c = fits.coefficients(v);
    for (int k = 0; k < 3; ++k) at[k][l] = fr.t1[k], at[3 + k][l] = fr.t2[k], at[6 + k][l] = fr.normal[k];
    at[9][l] = coef(c, 1, 0), at[10][l] = coef(c, 0, 1), at[11][l] = coef(c, 2, 0), at[12][l] = coef(c, 1, 1),
    at[13][l] = coef(c, 0, 2);
  }
  const auto row = [&](int i) { return *reinterpret_cast<const V*>(at[i]); };
  const V c10 = row(9), c01 = row(10), c20 = row(11), c11 = row(12), c02 = row(13);
  V a[3], b[3], xuu[3], xuv[3], xvv[3];
  for (int k = 0; k < 3; ++k) {
    const V nk = row(6 + k);
    a[k] = row(k) + c10 * nk;
    b[k] = row(3 + k) + c01 * nk;
    xuu[k] = c20 * nk;
    xuv[k] = c11 * nk;
    xvv[k] = c02 * nk;
  }
  const V r11 = SqrtLanes(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  V q1[3], q2[3], n[3];
  for (int k = 0; k < 3; ++k) q1[k] = a[k] / r11;
  const V r12 = q1[0] * b[0] + q1[1] * b[1] + q1[2] * b[2];
  for (int k = 0; k < 3; ++k) q2[k] = b[k] - r12 * q1[k];
  const V r22 = SqrtLanes(q2[0] * q2[0] + q2[1] * q2[1] + q2[2] * q2[2]);
  for (int k = 0; k < 3; ++k) q2[k] = q2[k] / r22;
  n[0] = q1[1] * q2[2] - q1[2] * q2[1];
  n[1] = q1[2] * q2[0] - q1[0] * q2[2];
  n[2] = q1[0] * q2[1] - q1[1] * q2[0];
  const V b11 = n[0] * xuu[0] + n[1] * xuu[1] + n[2] * xuu[2];
  const V b12 = n[0] * xuv[0] + n[1] * xuv[1] + n[2] * xuv[2];
  const V b22 = n[0] * xvv[0] + n[1] * xvv[1] + n[2] * xvv[2];
  const V i11 = 1 / r11, i12 = -r12 / (r11 * r22), i22 = 1 / r22;
  const V w11 = -(i11 * b11 * i11);
  const V w12 = -(i11 * (b11 * i12 + b12 * i22));
  const V w22 = -(i12 * (b11 * i12 + b12 * i22) + i22 * (b12 * i12 + b22 * i22));
  const V mean = 0.5 * (w11 + w22);
  const V gauss = w11 * w22 - w12 * w12;
  const V disc = SqrtLanes((w11 - w22) * (w11 - w22) + 4 * w12 * w12);
  const V k1 = 0.5 * (w11 + w22 + disc);
  const V k2 = 0.5 * (w11 + w22 - disc);
  // Equal principal curvatures: the directions are q1, q2.
  const M round = disc <= 1e-14 * (Magnitude(w11) + Magnitude(w22) + 1e-300);
  // (w11 - k2) q1 + w12 q2 if |w11 - k2| > |w11 - k1|, otherwise w12 q1 - (w11 - k1) q2
  const M first = Magnitude(w11 - k2) > Magnitude(w11 - k1);
  const V s1 = Pick(first, w11 - k2, w12), s2 = Pick(first, w12, w11 - k1);
  V e1[3], e2[3];
  for (int k = 0; k < 3; ++k) e1[k] = Pick(first, s1 * q1[k] + s2 * q2[k], s1 * q1[k] - s2 * q2[k]);
  V z = e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2];
  z = Pick(z > 0, SqrtLanes(z), V{} + 1);  // Eigen's normalized(): a zero vector stays
  for (int k = 0; k < 3; ++k) e1[k] = Pick(round, q1[k], e1[k] / z);
  e2[0] = Pick(round, q2[0], n[1] * e1[2] - n[2] * e1[1]);
  e2[1] = Pick(round, q2[1], n[2] * e1[0] - n[0] * e1[2]);
  e2[2] = Pick(round, q2[2], n[0] * e1[1] - n[1] * e1[0]);
  for (int l = 0; l < count; ++l) {
    const int64_t v = vs[l];
    d.diagnostics[v] = fits.diagnostics(static_cast<int>(v));
    if (q & kNormals) d.normals(v, 0) = n[0][l], d.normals(v, 1) = n[1][l], d.normals(v, 2) = n[2][l];
    if (q & kMeanCurvature) d.mean(v) = mean[l];
    if (q & kGaussianCurvature) d.gaussian(v) = gauss[l];
    if (q & kPrincipalCurvatures) d.k1(v) = k1[l], d.k2(v) = k2[l];
    if (q & kPrincipalDirections)
      for (int k = 0; k < 3; ++k) d.dir1(v, k) = e1[k][l], d.dir2(v, k) = e2[k][l];
  }
  if (q & kCurvatureTensor)  // column-major C = k1 e1 e1^T + k2 e2 e2^T as Eigen forms it
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 3; ++i) {
        const V t = e1[j] * (k1 * e1[i]) + e2[j] * (k2 * e2[i]);
        for (int l = 0; l < count; ++l) d.tensor(vs[l], 3 * j + i) = t[l];
      }
}

// Height-function fits (dims 1) of vertices [begin, end), kLanes at a time (one call per
// range: the clone's dispatch and entry once, not per 8 vertices).
__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void HeightRange(const SurfaceFits& fits, uint32_t q,
                                                                                   int64_t begin, int64_t end,
                                                                                   Differentials& d) {
  int64_t lanes[kLanes];
  int count = 0;
  for (int64_t v = begin; v < end; ++v) {
    if (fits.diagnostics(static_cast<int>(v)).degree_used < 1) {
      EvaluateVertex(fits, q, v, d);
      continue;
    }
    lanes[count++] = v;
    if (count == kLanes) HeightLanes(fits, q, lanes, count, d), count = 0;
  }
  if (count > 0) HeightLanes(fits, q, lanes, count, d);
}

// Vertices [begin, end): height-function fits kLanes at a time, the others one by one.
void EvaluateRange(const SurfaceFits& fits, uint32_t q, int64_t begin, int64_t end, Differentials& d) {
  if (fits.dims() == 1) return HeightRange(fits, q, begin, end, d);
  for (int64_t v = begin; v < end; ++v) EvaluateVertex(fits, q, v, d);
}

}  // namespace

Differentials AllocateDifferentials(int64_t nv, uint32_t q) {
  Differentials d;
  if (q & kNormals) d.normals.resize(nv, 3);
  if (q & kMeanCurvature) d.mean.resize(nv);
  if (q & kGaussianCurvature) d.gaussian.resize(nv);
  if (q & kPrincipalCurvatures) d.k1.resize(nv), d.k2.resize(nv);
  if (q & kPrincipalDirections) d.dir1.resize(nv, 3), d.dir2.resize(nv, 3);
  if (q & kCurvatureTensor) d.tensor.resize(nv, 9);
  d.diagnostics.resize(static_cast<size_t>(nv));
  return d;
}

void EvaluateDifferentials(const SurfaceFits& fits, uint32_t q, int64_t begin, int64_t end, Differentials* d) {
  EvaluateRange(fits, q, begin, end, *d);
}

constexpr int64_t kEvaluateGrain = 512;

Differentials ComputeDifferentials(const SurfaceFits& fits, uint32_t q, int num_threads) {
  Differentials d = AllocateDifferentials(fits.num_vertices(), q);
  // Ranges in contiguous shares per thread (ChunkShares): a thread reads the fits it
  // wrote (FitAll hands out its blocks the same way) and its streams run on.
  ParallelForShares(fits.num_vertices(), kEvaluateGrain, RunContext(nullptr, num_threads),
                    [&](int64_t begin, int64_t end) { EvaluateRange(fits, q, begin, end, d); })
      .IgnoreError();  // never cancelled
  return d;
}

absl::StatusOr<Differentials> ComputeDifferentials(const SurfaceFits& fits, uint32_t q, const RunContext& ctx) {
  Differentials d = AllocateDifferentials(fits.num_vertices(), q);
  GF_RETURN_IF_ERROR(ParallelForShares(
      fits.num_vertices(), kEvaluateGrain, ctx, [&](int64_t begin, int64_t end) { EvaluateRange(fits, q, begin, end, d); },
      "evaluate"));  // progress in vertices
  return d;
}

absl::StatusOr<Differentials> ComputeDifferentials(const Mesh& mesh, const FitOptions& options,
                                                   uint32_t quantities, const RunContext& ctx) {
  GF_RETURN_IF_ERROR(ValidateFitOptions(options));
  GF_ASSIGN_OR_RETURN(Topology topo, ValidateMesh(mesh));
  GF_ASSIGN_OR_RETURN(auto fits, FitSurface(mesh, topo, options, nullptr, {}, ctx));
  return ComputeDifferentials(*fits, quantities, ctx);
}

}  // namespace geomfit
