#include "core/mechanics/membrane.h"

#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"
#include "core/mechanics/membrane_kernel.h"
#include "core/operators/operators.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {

using mechanics_internal::Jet5;

absl::Status ValidateMembraneOptions(const MembraneOptions& o) {
  if (!(std::isfinite(o.E) && o.E > 0))
    return absl::InvalidArgumentError(absl::StrFormat("E: Young's modulus %g must be finite and > 0 (required)", o.E));
  if (!(o.nu > -1 && o.nu < 0.5))
    return absl::InvalidArgumentError(absl::StrFormat("nu: Poisson ratio %g must lie in (-1, 0.5) (required)", o.nu));
  return absl::OkStatus();
}

namespace mechanics_internal {

void StencilJet(const SurfaceFits& fits, int v, const Positions& positions, Eigen::Vector3d out[5]) {
  static constexpr int kRows[5] = {TaylorIndex(1, 0), TaylorIndex(0, 1), TaylorIndex(2, 0), TaylorIndex(1, 1),
                                   TaylorIndex(0, 2)};
  const Neighborhoods& nb = fits.neighborhoods();
  const int n = nb.Size(v);
  const int32_t* pts = nb.Points(v);
  const double* S = fits.stencil(v);
  for (int q = 0; q < 5; ++q) {
    out[q].setZero();
    if (kRows[q] >= fits.stencil_rows()) continue;
    const double* row = S + static_cast<size_t>(kRows[q]) * n;
    for (int k = 0; k < n; ++k) out[q] += row[k] * positions.row(pts[k]).transpose();
  }
}

absl::Status CheckPositions(const Positions& p, int num_vertices, const char* field) {
  if (p.rows() != num_vertices)
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: %d positions for a reference of %d vertices", field, p.rows(), num_vertices));
  for (int i = 0; i < p.rows(); ++i)
    if (!p.row(i).allFinite())
      return absl::InvalidArgumentError(absl::StrFormat("%s: vertex %d is not finite", field, i));
  return absl::OkStatus();
}

}  // namespace mechanics_internal

namespace {

absl::Status CheckReferenceFits(const SurfaceFits& fits) {
  if (fits.options().method != FitMethod::kLHF) return absl::FailedPreconditionError("membranes need LHF fits");
  if (!fits.has_stencils() || fits.stencil_rows() < NumCoefficients(std::min(2, fits.options().degree)))
    return absl::FailedPreconditionError("membranes need reference fits with stencil rows up to order 2");
  return absl::OkStatus();
}

// Eigenvalues (descending) of the 2 x 2 matrix m with real spectrum.
Eigen::Vector2d Eigen2(const Eigen::Matrix2d& m) {
  const double h = 0.5 * m.trace(), q = 0.5 * (m(0, 0) - m(1, 1));
  const double r = std::sqrt(std::max(0.0, q * q + m(0, 1) * m(1, 0)));
  return Eigen::Vector2d(h + r, h - r);
}

}  // namespace

absl::StatusOr<MembraneFields> ComputeMembrane(const SurfaceFits& reference, const Positions& reference_positions,
                                               const Positions& deformed, const MembraneOptions& options,
                                               const RunContext& ctx) {
  GF_RETURN_IF_ERROR(ValidateMembraneOptions(options));
  GF_RETURN_IF_ERROR(CheckReferenceFits(reference));
  const int nv = reference.num_vertices();
  GF_RETURN_IF_ERROR(mechanics_internal::CheckPositions(reference_positions, nv, "reference"));
  GF_RETURN_IF_ERROR(mechanics_internal::CheckPositions(deformed, nv, "deformed"));
  const double lambda = options.Lambda(), mu = options.Mu();
  MembraneFields out;
  out.stretches.resize(nv, 2);
  out.strain.resize(nv, 9);
  out.stress.resize(nv, 9);
  out.von_mises.resize(nv);
  out.pressure.resize(nv);
  out.traction.resize(nv);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  GF_RETURN_IF_ERROR(ParallelFor(nv, ctx, [&](int64_t vi) {
    const int v = static_cast<int>(vi);
    if (reference.diagnostics(v).degree_used < 1) {
      out.stretches.row(v).setConstant(nan);
      out.strain.row(v).setConstant(nan);
      out.stress.row(v).setConstant(nan);
      out.von_mises(v) = out.pressure(v) = out.traction(v) = nan;
      return;
    }
    Jet5<double> x, y;
    mechanics_internal::StencilJet(reference, v, reference_positions, x.d);
    mechanics_internal::StencilJet(reference, v, deformed, y.d);
    const mechanics_internal::ReferenceGeometry ref = mechanics_internal::MakeReference(x);
    const auto s = mechanics_internal::State<double>(ref, y, lambda, mu);
    const Eigen::Vector2d l2 = Eigen2(ref.Ginv * s.g);  // squared principal stretches
    out.stretches(v, 0) = std::sqrt(std::max(0.0, l2(0)));
    out.stretches(v, 1) = std::sqrt(std::max(0.0, l2(1)));
    Eigen::Matrix<double, 3, 2> Jr, Jd;
    Jr << x.d[0], x.d[1];
    Jd << y.d[0], y.d[1];
    const Eigen::Matrix<double, 3, 2> JrPinvT = Jr * ref.Ginv;  // J_ref^{+T}
    const Eigen::Matrix3d strain = JrPinvT * (0.5 * (s.g - ref.G)) * JrPinvT.transpose();
    const Eigen::Matrix3d stress = Jd * s.S * Jd.transpose();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) out.strain(v, 3 * r + c) = strain(r, c), out.stress(v, 3 * r + c) = stress(r, c);
    const Eigen::Vector2d sp = Eigen2(s.tau);
    out.von_mises(v) = std::sqrt(sp(0) * sp(0) - sp(0) * sp(1) + sp(1) * sp(1));
    out.pressure(v) = mechanics_internal::InterfacePressureAt(s, y);
    out.traction(v) = s.normal.dot(mechanics_internal::StressDivergence(ref, s, y, lambda, mu));
  }, 1024, "membrane"));
  return out;
}

absl::StatusOr<MembraneFields> ComputeMembrane(const Mesh& reference, const Topology& topo,
                                               const Positions& deformed, const MembraneOptions& options,
                                               const FitOptions& fit, const RunContext& ctx) {
  GF_RETURN_IF_ERROR(ValidateMembraneOptions(options));
  GF_RETURN_IF_ERROR(mechanics_internal::CheckPositions(deformed, reference.NumVertices(), "deformed"));
  GF_ASSIGN_OR_RETURN(auto fits, FitForOperators(reference, topo, fit, nullptr, ctx));
  return ComputeMembrane(*fits, reference.positions, deformed, options, ctx);
}

}  // namespace geomfit
