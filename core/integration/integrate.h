#pragma once
#include <vector>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/reconstruction/surface.h"
#include "core/util/run_context.h"

namespace geomfit {

/// What to integrate over a reconstructed surface (4.3).
struct IntegrationInput {
  /// Quadrature degree; 0 = the fit degree + 2 (at least 4). Up to 30.
  int quadrature_degree = 0;
  bool area = true;
  bool volume = true;  ///< enclosed volume, (1/3) int x . n dA (4.3.16); closed surfaces
  /// Nodal scalar fields, #V x s: int phi dA (4.3.2) with phi blended from per-vertex
  /// fits of the nodal values (4.3.13) on WALF surfaces, linearly on the flat one.
  Eigen::MatrixXd scalars;
  /// A nodal vector field, #V x 3 (or empty): the flux int phi . n dA (4.3.4).
  Eigen::MatrixXd vectors;
};

struct Integrals {
  double area = 0, volume = 0;
  std::vector<double> scalars;  ///< one per column of IntegrationInput::scalars
  double flux = 0;
  int quadrature_points = 0;    ///< per face (triangles)
};

/// Integrates over every face with Jacobians of the reconstructed geometry (4.3.5)-(4.3.6).
/// Linear, WALF, and FeatureSurface over either (sharp features: integrated over the
/// split mesh's one-sided surface, fields indexed by the original vertices).
/// WALF surfaces blend vertex fits of the fields, which needs fits built with
/// FitRequest::stencils (FAILED_PRECONDITION otherwise); CMF surfaces are not
/// supported for fields (their Jacobian is approximate). Errors name the bad field.
/// `ctx` is polled between blocks of faces (progress phase "integrate").
absl::StatusOr<Integrals> Integrate(const ReconstructedSurface& surface, const IntegrationInput& input,
                                    const RunContext& ctx = {});

}  // namespace geomfit
