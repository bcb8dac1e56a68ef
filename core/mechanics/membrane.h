#pragma once
// Elastic membranes (§6.1-6.2): stress of a deformed membrane against its reference
// (unstressed) configuration, and the interface pressure its stress balances.
//
// Model (the text's, made precise in core/mechanics/membrane_kernel.h): both
// configurations are parametrized by the reference fit's frame (u, v) at each vertex;
// J_ref = [x_u | x_v] and J_def = [y_u | y_v] come from the same reference stencil applied
// to x and y. Green strain (6.1.5) eps* = J_ref^{+T} (g - G)/2 J_ref^+ (its tangential part
// on the reference surface, 6.3.1), membrane Hooke's law (6.1.13) with lambda* = nu E /
// (1 - nu^2) (6.1.14) and mu = E / (2 + 2 nu), the stress pushed to the deformed tangent
// plane as sigma = J_def tau^ J_def^+ (6.2.8) (symmetric; n^T sigma n = 0).
// Interface pressure p = tr(W tau^) (6.2.10) with W the deformed Weingarten map in the
// same (u, v) basis, positive when convex: p is the pressure inside minus outside that
// the stress balances (the balloon r0 -> r1: p = E/(1 - nu) (r1^2 - r0^2)/(r0^2 r1), 6.3.4).
// Degree-1 fits have no second derivatives: their W, hence p, is 0.
#include <cstdint>
#include <limits>
#include <memory>

#include <Eigen/Core>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/mesh/mesh.h"
#include "core/mesh/topology.h"
#include "core/util/run_context.h"

namespace geomfit {

/// Material of a membrane. Both fields are required (no defaults: NaN until set).
struct MembraneOptions {
  double E = std::numeric_limits<double>::quiet_NaN();   ///< Young's modulus, > 0
  double nu = std::numeric_limits<double>::quiet_NaN();  ///< Poisson ratio, -1 < nu < 0.5
  double Lambda() const { return nu * E / (1 - nu * nu); }  ///< lambda* (6.1.14)
  double Mu() const { return E / (2 + 2 * nu); }
};
/// OK, or INVALID_ARGUMENT naming the field (E, nu) and its valid range.
absl::Status ValidateMembraneOptions(const MembraneOptions& o);

/// Per-vertex results; NaN at vertices without a usable fit (isolated, too few points).
struct MembraneFields {
  using RowMajor9 = Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor>;
  Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> stretches;  ///< principal, l1 >= l2
  RowMajor9 strain;       ///< Green strain eps* (3 x 3 row-major, reference tangent plane)
  RowMajor9 stress;       ///< Cauchy stress sigma (3 x 3 row-major, deformed tangent plane)
  Eigen::VectorXd von_mises;  ///< sqrt(s1^2 - s1 s2 + s2^2) of the principal stresses
  Eigen::VectorXd pressure;   ///< p = tr(W tau^), inside minus outside
  /// n . div sigma (6.2.9) with div sigma in full (the tangential terms too): -p in the
  /// continuum (outward n), so p + traction measures the discrete balance's error.
  Eigen::VectorXd traction;
};

/// Stress and pressure of `deformed` (positions of the reference mesh's vertices) against
/// the reference fits (built by FitForOperators on the reference mesh, any degree 1..6).
/// Errors: INVALID_ARGUMENT for bad options, `deformed` of the wrong length or not finite,
/// FAILED_PRECONDITION for fits without stencils, CANCELLED / DEADLINE_EXCEEDED.
absl::StatusOr<MembraneFields> ComputeMembrane(const SurfaceFits& reference, const Positions& reference_positions,
                                               const Positions& deformed, const MembraneOptions& options,
                                               const RunContext& ctx = RunContext());

/// Fits the reference mesh (LHF, stencils up to order 2) and calls the above.
absl::StatusOr<MembraneFields> ComputeMembrane(const Mesh& reference, const Topology& topo,
                                               const Positions& deformed, const MembraneOptions& options,
                                               const FitOptions& fit, const RunContext& ctx = RunContext());

namespace mechanics_internal {
/// Derivatives (u, v, uu, uv, vv) of `positions` at vertex v from its reference stencil
/// (rows the fit does not keep read as zero).
void StencilJet(const SurfaceFits& fits, int v, const Positions& positions, Eigen::Vector3d out[5]);
/// Checks a position array against the reference (rows, finiteness); names `field`.
absl::Status CheckPositions(const Positions& p, int num_vertices, const char* field);
}  // namespace mechanics_internal

}  // namespace geomfit
