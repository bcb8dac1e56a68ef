#pragma once
#include <string>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"

namespace geomfit {

/// Error norms of computed quantities against an analytic surface (3.3): normals as
/// L2 = sqrt(mean |n~ - n|^2) and Linf = max |n~ - n|; curvatures relative,
/// L2 = |k~ - k|_2 / |k|_2 and Linf = max |k~ - k| / max |k|.
struct ErrorNorms {
  double l2 = 0, linf = 0;
};
struct DifferentialErrors {
  ErrorNorms normal, mean, gaussian, k1, k2;
  double h = 0;  ///< average edge length of the mesh
};

/// Errors over the vertices selected by `mask` (empty = all). Differentials must hold
/// normals, mean, gaussian and principal curvatures.
DifferentialErrors MeasureErrors(const Mesh& mesh, const AnalyticSurface& surface,
                                 const Differentials& d, const std::vector<uint8_t>& mask = {});

/// Least-squares slope of log(error) against log(h): the observed convergence order.
double ConvergenceOrder(const std::vector<double>& h, const std::vector<double>& err);

}  // namespace geomfit
