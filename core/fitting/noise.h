#pragma once
#include <memory>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "core/util/run_context.h"

namespace geomfit {

/// Noise-aware fitting (FitOptions::noise). Input positions with O(h^k) errors bound a
/// degree-d fit's j-th derivatives by O(h^(k-j)) noise terms besides the O(h^(d+1-j))
/// truncation (2.5), and interpolating fits with the steep weights of (2.2.1) amplify
/// the noise of the centre vertex. The noise mode therefore (1) fits approximating
/// polynomials, (2) with nearly uniform weights on d/2+1 rings grown to 3x the
/// coefficient count (2.1), and (3)
/// first runs smoothing-by-projection passes (§4.2.3): every vertex moves to its own
/// (cubic, flat-weighted) fit's foot point, which averages the noise of its stencil away,
/// and the mesh is refitted; (4) at degree 2 the final fit keeps the tangent plane of a
/// cubic pre-fit on the smoothed mesh (the normal refinement of FitOptions::normal_degree).

/// The weights' eps of (2.2.1) in the noise mode's smoothing fits (and the final fit at
/// degree >= 4): nearly uniform weights (1 to 2^(-d/4) across the stencil) average the
/// noise of every point instead of trusting the nearest.
inline constexpr double kNoiseWeightEpsilon = 1.0;
/// The smoothing passes fit cubics whatever the final degree: a cubic's foot point carries
/// no error from the surface's cubic terms on asymmetric stencils (a quadratic's does,
/// O(h^3) per pass, which the final fit differentiates into O(h) curvature errors), and
/// it averages more noise than a quartic on the stencil it needs (bench/README.md, "Noisy
/// meshes, second round").
inline constexpr int kNoiseSmoothingDegree = 3;
/// The final fit's eps after smoothing: at degrees <= 3 the truncation error of the large
/// stencil dominates what noise is left, so the text's steep weights (eps = 0.01 of
/// (2.2.1)) apply; at degree >= 4 the noise dominates and the weights stay flat.
constexpr double NoiseFinalWeightEpsilon(int degree) { return degree >= 4 ? kNoiseWeightEpsilon : 0.01; }

/// Every vertex moved onto its own fit (the fit's point at its origin, x(0, 0) of
/// Table 3.1); vertices without a fit keep `positions`.
Positions ProjectOntoFits(const SurfaceFits& fits, const Positions& positions, int num_threads = 0);

/// The noise test of NoiseMode::kAuto, on a sample of vertices: approximating degree-2
/// and degree-4 fits on the same (>= 40-point) stencil. On smooth data the quartic's
/// residual is O(h^2) times the quadratic's; on noisy data both residuals are the
/// noise's and their ratio approaches 1.
struct NoiseEstimate {
  double residual_ratio = 0;   ///< median over the sample of rms(res_4) / rms(res_2)
  double noise_over_h = 0;     ///< median rms(res_4) / h (the noise level, relative)
  int samples = 0;
  bool noisy = false;          ///< residual_ratio > kNoisyResidualRatio (clean meshes: < 0.14)
};
inline constexpr double kNoisyResidualRatio = 0.2;

/// `normals`: approximate vertex normals (frames). CANCELLED / DEADLINE_EXCEEDED from ctx.
absl::StatusOr<NoiseEstimate> EstimateNoise(const Mesh& mesh, const Topology& topo, const Positions& normals,
                                            const RunContext& ctx = {});

}  // namespace geomfit
