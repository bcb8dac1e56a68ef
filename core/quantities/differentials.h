#pragma once
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"

namespace geomfit {

/// First- and second-order differential quantities at a point (Table 3.1, 3.2.7-3.2.10).
/// Conventions: normal outward for counter-clockwise faces; H = (k1 + k2) / 2 with
/// H = +1/R on a sphere of radius R; K = k1 k2; k1 >= k2; (e1, e2, normal) right-handed.
struct PointDifferentials {
  Eigen::Vector3d normal;
  double mean = 0, gaussian = 0, k1 = 0, k2 = 0;
  Eigen::Vector3d e1, e2;
  Eigen::Matrix3d tensor;  ///< C = k1 e1 e1^T + k2 e2 e2^T (3.2.6, 3.2.8)
};

/// Differential quantities from a local parametrization's jet, through the symmetric
/// shape operator W~ = R^-T B R^-1 of J = QR (3.2.7).
PointDifferentials DifferentialsFromJet(const SurfaceJet& jet);

/// Which per-vertex quantities to fill.
enum Quantity : uint32_t {
  kNormals = 1,
  kMeanCurvature = 2,
  kGaussianCurvature = 4,
  kPrincipalCurvatures = 8,
  kPrincipalDirections = 16,
  kCurvatureTensor = 32,
  kAllQuantities = 63,
};

/// Per-vertex arrays (#V rows); arrays not requested are empty. Isolated vertices
/// hold NaN.
struct Differentials {
  Positions normals;
  Eigen::VectorXd mean, gaussian, k1, k2;
  Positions dir1, dir2;
  Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor> tensor;
  std::vector<VertexDiagnostics> diagnostics;
};

/// Differentials with the arrays of `quantities` sized for `num_vertices` rows.
Differentials AllocateDifferentials(int64_t num_vertices, uint32_t quantities);
/// Evaluates rows [begin, end) of `d` (from AllocateDifferentials(fits.num_vertices(),
/// quantities)) in the calling thread; the same values as ComputeDifferentials.
void EvaluateDifferentials(const SurfaceFits& fits, uint32_t quantities, int64_t begin, int64_t end,
                           Differentials* d);
/// Evaluates the quantities of every vertex from its fit (parallel, deterministic).
Differentials ComputeDifferentials(const SurfaceFits& fits, uint32_t quantities = kAllQuantities,
                                   int num_threads = 0);

/// The same, polling `ctx` (progress phase "evaluate").
absl::StatusOr<Differentials> ComputeDifferentials(const SurfaceFits& fits, uint32_t quantities,
                                                   const RunContext& ctx);

/// One-shot convenience: validate, fit and evaluate.
absl::StatusOr<Differentials> ComputeDifferentials(const Mesh& mesh, const FitOptions& options,
                                                   uint32_t quantities = kAllQuantities, const RunContext& ctx = {});

}  // namespace geomfit
