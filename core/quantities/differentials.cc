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
  for (int64_t v = begin; v < end; ++v) EvaluateVertex(fits, q, v, *d);
}

Differentials ComputeDifferentials(const SurfaceFits& fits, uint32_t q, int num_threads) {
  Differentials d = AllocateDifferentials(fits.num_vertices(), q);
  ParallelFor(fits.num_vertices(), num_threads, [&](int64_t v) { EvaluateVertex(fits, q, v, d); });
  return d;
}

absl::StatusOr<Differentials> ComputeDifferentials(const SurfaceFits& fits, uint32_t q, const RunContext& ctx) {
  Differentials d = AllocateDifferentials(fits.num_vertices(), q);
  GF_RETURN_IF_ERROR(ParallelFor(fits.num_vertices(), ctx, [&](int64_t v) { EvaluateVertex(fits, q, v, d); }, 1024,
                                 "evaluate"));
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
