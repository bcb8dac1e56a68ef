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
// EvaluateVertex's bits, but stage by stage across the lanes, so the divisions and
// square roots of different vertices overlap instead of forming one long chain per
// vertex (and the compiler may use vector instructions). Both principal-direction
// branches are computed and selected per lane.
constexpr int kLanes = 8;
using Lanes = double[kLanes];

__attribute__((target_clones("arch=x86-64-v4", "avx2", "default"))) void HeightLanes(const SurfaceFits& fits, uint32_t q, const int64_t* vs, int count, Differentials& d) {
  const int nc = fits.num_coefficients();
  auto coef = [&](const double* c, int j, int k) { return TaylorIndex(j, k) < nc ? c[TaylorIndex(j, k)] : 0.0; };
  Lanes a[3], b[3], xuu[3], xuv[3], xvv[3];
  for (int l = 0; l < kLanes; ++l) {  // Jet (dims 1); the padding lanes repeat lane 0
    const int v = static_cast<int>(vs[l < count ? l : 0]);
    const LocalFrame& fr = fits.frame(v);
    const double* c = fits.coefficients(v);
    const double c10 = coef(c, 1, 0), c01 = coef(c, 0, 1), c20 = coef(c, 2, 0), c11 = coef(c, 1, 1),
                 c02 = coef(c, 0, 2);
    for (int k = 0; k < 3; ++k) {
      a[k][l] = fr.t1[k] + c10 * fr.normal[k];
      b[k][l] = fr.t2[k] + c01 * fr.normal[k];
      xuu[k][l] = c20 * fr.normal[k];
      xuv[k][l] = c11 * fr.normal[k];
      xvv[k][l] = c02 * fr.normal[k];
    }
  }
  Lanes r11, r12, r22, q1[3], q2[3], n[3];
  for (int l = 0; l < kLanes; ++l) r11[l] = std::sqrt(a[0][l] * a[0][l] + a[1][l] * a[1][l] + a[2][l] * a[2][l]);
  for (int k = 0; k < 3; ++k)
    for (int l = 0; l < kLanes; ++l) q1[k][l] = a[k][l] / r11[l];
  for (int l = 0; l < kLanes; ++l) r12[l] = q1[0][l] * b[0][l] + q1[1][l] * b[1][l] + q1[2][l] * b[2][l];
  for (int k = 0; k < 3; ++k)
    for (int l = 0; l < kLanes; ++l) q2[k][l] = b[k][l] - r12[l] * q1[k][l];
  for (int l = 0; l < kLanes; ++l) r22[l] = std::sqrt(q2[0][l] * q2[0][l] + q2[1][l] * q2[1][l] + q2[2][l] * q2[2][l]);
  for (int k = 0; k < 3; ++k)
    for (int l = 0; l < kLanes; ++l) q2[k][l] = q2[k][l] / r22[l];
  for (int l = 0; l < kLanes; ++l) {
    n[0][l] = q1[1][l] * q2[2][l] - q1[2][l] * q2[1][l];
    n[1][l] = q1[2][l] * q2[0][l] - q1[0][l] * q2[2][l];
    n[2][l] = q1[0][l] * q2[1][l] - q1[1][l] * q2[0][l];
  }
  Lanes w11, w12, w22, mean, gauss, k1, k2, disc;
  for (int l = 0; l < kLanes; ++l) {
    const double b11 = n[0][l] * xuu[0][l] + n[1][l] * xuu[1][l] + n[2][l] * xuu[2][l];
    const double b12 = n[0][l] * xuv[0][l] + n[1][l] * xuv[1][l] + n[2][l] * xuv[2][l];
    const double b22 = n[0][l] * xvv[0][l] + n[1][l] * xvv[1][l] + n[2][l] * xvv[2][l];
    const double i11 = 1 / r11[l], i12 = -r12[l] / (r11[l] * r22[l]), i22 = 1 / r22[l];
    w11[l] = -(i11 * b11 * i11);
    w12[l] = -(i11 * (b11 * i12 + b12 * i22));
    w22[l] = -(i12 * (b11 * i12 + b12 * i22) + i22 * (b12 * i12 + b22 * i22));
  }
  for (int l = 0; l < kLanes; ++l) {
    mean[l] = 0.5 * (w11[l] + w22[l]);
    gauss[l] = w11[l] * w22[l] - w12[l] * w12[l];
    disc[l] = std::sqrt((w11[l] - w22[l]) * (w11[l] - w22[l]) + 4 * w12[l] * w12[l]);
    k1[l] = 0.5 * (w11[l] + w22[l] + disc[l]);
    k2[l] = 0.5 * (w11[l] + w22[l] - disc[l]);
  }
  Lanes e1[3], e2[3], z;
  bool round[kLanes];  // equal principal curvatures: the directions are q1, q2
  for (int l = 0; l < kLanes; ++l) {
    round[l] = disc[l] <= 1e-14 * (std::abs(w11[l]) + std::abs(w22[l]) + 1e-300);
    // (w11 - k2) q1 + w12 q2 if |w11 - k2| > |w11 - k1|, otherwise w12 q1 - (w11 - k1) q2
    const bool first = std::abs(w11[l] - k2[l]) > std::abs(w11[l] - k1[l]);
    const double s1 = first ? w11[l] - k2[l] : w12[l], s2 = first ? w12[l] : w11[l] - k1[l];
    for (int k = 0; k < 3; ++k) e1[k][l] = first ? s1 * q1[k][l] + s2 * q2[k][l] : s1 * q1[k][l] - s2 * q2[k][l];
  }
  for (int l = 0; l < kLanes; ++l) {
    z[l] = e1[0][l] * e1[0][l] + e1[1][l] * e1[1][l] + e1[2][l] * e1[2][l];
    z[l] = z[l] > 0 ? std::sqrt(z[l]) : 1.0;  // Eigen's normalized(): a zero vector stays
  }
  for (int k = 0; k < 3; ++k)
    for (int l = 0; l < kLanes; ++l) e1[k][l] = round[l] ? q1[k][l] : e1[k][l] / z[l];
  for (int l = 0; l < kLanes; ++l) {
    const double x = n[1][l] * e1[2][l] - n[2][l] * e1[1][l], y = n[2][l] * e1[0][l] - n[0][l] * e1[2][l],
                 z = n[0][l] * e1[1][l] - n[1][l] * e1[0][l];
    e2[0][l] = round[l] ? q2[0][l] : x;
    e2[1][l] = round[l] ? q2[1][l] : y;
    e2[2][l] = round[l] ? q2[2][l] : z;
  }
  for (int l = 0; l < count; ++l) {
    const int64_t v = vs[l];
    d.diagnostics[v] = fits.diagnostics(static_cast<int>(v));
    if (q & kNormals) d.normals(v, 0) = n[0][l], d.normals(v, 1) = n[1][l], d.normals(v, 2) = n[2][l];
    if (q & kMeanCurvature) d.mean(v) = mean[l];
    if (q & kGaussianCurvature) d.gaussian(v) = gauss[l];
    if (q & kPrincipalCurvatures) d.k1(v) = k1[l], d.k2(v) = k2[l];
    if (q & kPrincipalDirections)
      for (int k = 0; k < 3; ++k) d.dir1(v, k) = e1[k][l], d.dir2(v, k) = e2[k][l];
    if (q & kCurvatureTensor)  // column-major C = k1 e1 e1^T + k2 e2 e2^T as Eigen forms it
      for (int j = 0; j < 3; ++j)
        for (int i = 0; i < 3; ++i)
          d.tensor(v, 3 * j + i) = e1[j][l] * (k1[l] * e1[i][l]) + e2[j][l] * (k2[l] * e2[i][l]);
  }
}

// Vertices [begin, end): height-function fits kLanes at a time, the others one by one.
void EvaluateRange(const SurfaceFits& fits, uint32_t q, int64_t begin, int64_t end, Differentials& d) {
  if (fits.dims() != 1) {
    for (int64_t v = begin; v < end; ++v) EvaluateVertex(fits, q, v, d);
    return;
  }
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

Differentials ComputeDifferentials(const SurfaceFits& fits, uint32_t q, int num_threads) {
  Differentials d = AllocateDifferentials(fits.num_vertices(), q);
  constexpr int64_t kGrain = 256;
  const int64_t nv = fits.num_vertices();
  ParallelFor((nv + kGrain - 1) / kGrain, num_threads,
              [&](int64_t c) { EvaluateRange(fits, q, c * kGrain, std::min(nv, (c + 1) * kGrain), d); }, 1);
  return d;
}

absl::StatusOr<Differentials> ComputeDifferentials(const SurfaceFits& fits, uint32_t q, const RunContext& ctx) {
  Differentials d = AllocateDifferentials(fits.num_vertices(), q);
  constexpr int64_t kGrain = 1024;
  const int64_t nv = fits.num_vertices();
  // Progress in vertices as before: the range of each chunk is evaluated at its first item.
  GF_RETURN_IF_ERROR(ParallelFor(
      nv, ctx,
      [&](int64_t v) {
        if (v % kGrain == 0) EvaluateRange(fits, q, v, std::min(nv, v + kGrain), d);
      },
      kGrain, "evaluate"));
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
