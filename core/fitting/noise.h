#pragma once
#include <memory>
#include <vector>

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
/// cubic pre-fit on the smoothed mesh (the normal refinement of FitOptions::normal_degree),
/// under heavy noise blended with a cubic pre-fit on larger stencils; on nearly clean
/// meshes the final fit interpolates the smoothed mesh with the slope refinement instead
/// (kSlopeRefinementResidualRatio).

/// The weights' eps of (2.2.1) in the noise mode's smoothing fits (and the final fit at
/// degree >= 4): nearly uniform weights (1 to 2^(-d/4) across the stencil) average the
/// noise of every point instead of trusting the nearest.
inline constexpr double kNoiseWeightEpsilon = 1.0;
/// How the noise mode balances bias against noise for the noise EstimateNoise finds
/// (bench/README.md, "Noisy meshes, second round").
struct NoiseSchedule {
  int smoothing_degree = 3;           ///< degree of the smoothing fits (flat weights)
  double final_weight_epsilon = 0.01;  ///< eps of (2.2.1) in the final fit
  bool final_clean_stencils = false;  ///< final fit on the clean stencils ((d+1)/2 rings)
  double final_points_factor = 0;     ///< and their growth factor (0: the clean one)
  int smoothing_passes = 2;           ///< passes when FitOptions::smoothing_passes is automatic
  bool cubic_near_boundary = false;   ///< smoothing fits within a ring of the boundary cubic
  /// Further passes after smoothing_passes, each moving every vertex by its
  /// LocalSmoothingSteps from the first pass's fits (automatic pass count only).
  int local_passes = 0;
  /// The final fit's rings on the clean stencils (0: (d+1)/2); when set, the final fit
  /// keeps the tangent plane of a fit of its degree on the (d+1)/2-ring clean stencils.
  double final_rings = 0;
  /// Degree-2 normals: a second cubic pre-fit on stencils grown to this factor x the
  /// coefficients (0: none), blended in by BlendLargeStencilNormals.
  double normal_points_factor = 0;
  /// The final fit's orders 0-2 from two stencil sets (TwoScaleFinalFit).
  bool two_scale_final = false;
  /// The local passes' steps from CurvatureSmoothingSteps instead of LocalSmoothingSteps.
  bool curvature_steps = false;
  /// Degree 2: the final fit interpolates the smoothed mesh with this many slope-refinement
  /// passes (slopes.h) instead of the cubic normal pre-fit (0: off).
  int slope_passes = 0;
  /// Passes after the local ones that move strongly curved vertices back (UnshrinkSteps).
  int unshrink_passes = 0;
  /// The smoothing and local passes' foot points also from fits of this degree, blended
  /// per vertex with smoothing_degree's (BlendFootPoints; 0: off).
  int smoothing_degree_high = 0;
  /// The final fit interpolates the smoothed mesh (with final_rings: also the tangent pre-fit).
  bool final_interpolates = false;
  /// eps of (2.2.1) in the clean tangent pre-fit of final_rings (0: final_weight_epsilon).
  double tangent_weight_epsilon = 0;
  /// Degree 3: the final fit is the default one on the smoothed mesh (interpolating, clean
  /// stencils, the Hermite curvatures of FitOptions::cubic_hermite).
  bool hermite_final = false;
  /// The smoothing passes' second fits, on stencils grown to this factor x the coefficients,
  /// blended in per vertex (0: none; NoiseSmoothingPointsFactor, set from the estimate).
  double smoothing_points_factor = 0;
};
/// Nearly clean meshes at degrees 3-4 (residual ratio below kLocalSmoothingResidualRatio:
/// O(h^3) noise, alpha 0.1-0.2: 0.010-0.024 at n = 64; a gmsh torus at 0.1 h^3, h = 0.0126:
/// 0.008). After quintic smoothing the torus keeps noise and the strongly curved bump the
/// smoothing's bias, in the same residual-ratio range: every smoothing pass (two global,
/// kNearlyCleanLocalPasses local) blends quintic and sextic foot points per vertex
/// (BlendFootPoints, spread kFootPointBlendSpread), and at degree 4 the final fit
/// interpolates the smoothed mesh on the clean stencils ((d+1)/2 rings, 1.5x the
/// coefficients) with eps 0.1, in the tangent plane of the same fit with eps 0.01: torus
/// alpha 0.1 at n = 64 d4 normal / H / K 0.72 / 0.63 / 0.61 (K Linf 1.10) -> 0.49 / 0.37 /
/// 0.38 (0.49)x the best CGAL, bump 0.80 / 0.78 / 0.77 -> 0.69 / 0.60 / 0.54, gmsh torus 0.1
/// h^3 d4 normal 0.75 -> 0.64x; torus d3 K Linf 0.81 / 0.94 -> 0.69 / 0.83 (alpha 0.2 / 0.1;
/// bench/README.md, "Nearly clean meshes"). At degree 3 the final fit is then the default
/// one on the smoothed mesh (hermite_final: interpolating, clean stencils, the Hermite
/// curvatures 4h/r^2 - g/r with the neighbours' degree-3 normals, slopes.h), which the
/// approximating 1.5-ring fit's clean-mesh accuracy at the torus's inner equator had
/// limited: torus alpha 0.1 d3 H / K 0.40 / 0.61 (K Linf 0.82) -> 0.05 / 0.12 (0.27)x the
/// best CGAL, bump 0.40 / 0.41 -> 0.13 / 0.12 (bench/README.md, `noise7`). Above
/// kLocalSmoothingResidualRatio the interpolated centre's noise shows (bump alpha 0.5 h^3:
/// H Linf 0.44 -> 0.60x), so the two-scale final fit stays there.
inline constexpr int kNearlyCleanLocalPasses = 2;
inline constexpr double kFootPointBlendSpread = 0.7;
inline constexpr double kNearlyCleanTangentEpsilon = 0.01;
/// Nearly clean meshes at degree 2 (residual ratio below kSlopeRefinementResidualRatio: O(h^3)
/// noise, alpha 0.5: 0.040-0.082 at n = 32-64; O(h^2) alpha 0.1 at n = 16-32: 0.113-0.145):
/// after two smoothing passes of degree 5 the smoothed mesh is as good as clean, and the
/// final fit interpolates it with the slope refinement (FitOptions::slope_refinement,
/// slopes.h), whose normals and Hermite curvatures cancel the cubic term the cubic normal
/// pre-fit and the approximating quadratic keep: torus O(h^3) alpha 0.5 at n = 64, K Linf
/// 0.94 -> 0.19x the best CGAL, bump H / K Linf 0.72 / 0.81 -> 0.25 / 0.19x (degree 4
/// smoothing: 0.46 / 0.39x). Above it (the bump at alpha 0.1 h^2, n = 32: K 0.70 -> 0.75x)
/// the interpolated centre keeps too much noise (bench/README.md, seventh round).
inline constexpr double kSlopeRefinementResidualRatio = 0.095;
inline constexpr int kNoiseSlopePasses = 2;
/// The heavy tier at degree 2 (cubic smoothing, cubic normal pre-fits on large stencils) relies
/// on the noise being above the cubic fits' truncation error (the quartic terms): the quartic
/// fit's residual against the cubic's (NoiseEstimate::cubic_ratio) near 1 (0.86-0.95 on the
/// meshes it wins on: O(h^2) noise, raw marching cubes). The residual ratio compares the noise
/// with the quadratic's truncation, the cubic terms, which a sphere lacks: there 0.1 h^3 of
/// noise, far below the quartic terms, reads "heavy" (gmsh sphere h = 0.03: residual ratio 0.53,
/// cubic ratio 0.54), and the cubic fits' bias sets the normals (Linf 1.48x the best CGAL).
/// Below kHeavyNoiseCubicRatio the degree-2 schedule is the slope tier's, with
/// kSymmetricSmoothingPasses quintic passes (bias O(h^6)) to average the noise the residual
/// ratio says is large against the quadratic's truncation: generated sphere 0.1 h^3 n = 32 / 64,
/// 0.3 h^3 n = 16 (cubic ratio 0.45-0.68) max error 2.3-3.3 -> 0.40-0.55x the best CGAL. Raw
/// marching-cubes tori (0.86-0.90, sextic ratio 0.7) lose with the interpolating final fit
/// (N = 56: 0.70 -> 1.6x); 0.75 keeps margins of 0.2 to the gmsh sphere and 0.1 to the lowest of
/// them (0.865). Between 0.75 and 0.8 the switch still wins (sphere 0.3 h^3 n = 32, 0.79: 1.71
/// -> 0.58x; torus 0.5 h^2 n = 32, 0.80: 0.91 -> 0.58x) but by the 0.8 tried first the torus
/// series of QuadraticNormalsUnderHeavyNoiseOnAFineMesh changed tier between levels
/// (bench/README.md, `noise9`).
inline constexpr double kHeavyNoiseCubicRatio = 0.75;
inline constexpr int kSymmetricSmoothingPasses = 8;
/// LocalSmoothingSteps: the top-degree part's scale against the noise level.
inline constexpr double kLocalSmoothingSignal = 0.3;
/// Light noise from this residual ratio on (O(h^3), alpha 0.5: 0.040-0.048 at n = 64)
/// gets the local passes; below it (alpha <= 0.2: <= 0.024) the smoothing fits' own bias
/// outweighs the noise they average.
inline constexpr double kLocalSmoothingResidualRatio = 0.032;
/// Residual ratio (NoiseEstimate) from which the noise dominates the truncation error.
inline constexpr double kHeavyNoiseResidualRatio = 0.2;
/// From this residual ratio on the degree-4 final fit keeps flat weights and (until the sixth
/// round, now TwoScaleFinalFit) the degree-3 final fit took the noise stencils: the
/// noise then dominates its curvatures (alpha 0.5 h^2 at n = 64: ratio 0.73-0.75, torus K
/// 0.70 -> 0.60x CGAL; a gmsh torus at h = 0.0127: H / K 0.83 / 0.80 -> 0.67 / 0.64x), while
/// at 0.44-0.49 (alpha 0.2) the bump's K needs the clean ones (1.00x on the noise stencils).
/// There, at degrees 2 and 4, the smoothing is 3 cubic passes and one local pass
/// (LocalSmoothingSteps) instead of 2 passes: marching-cubes torus (raw vertices, 192^3)
/// d3 K 0.71 -> 0.56x CGAL, d4 normal Linf 0.76 -> 0.68x; gmsh torus 0.5 h^2 d3 H 0.67 -> 0.47x
/// (4 global passes: 0.45x, but bump d3 K Linf 0.78 -> 0.94x: the local pass spares its centre).
inline constexpr double kVeryHeavyNoiseResidualRatio = 0.6;
/// Below it (and from kHeavyNoiseResidualRatio) the noise is moderate: at degree >= 3 the
/// truncation error of cubic smoothing still dominates the curvatures.
inline constexpr double kModerateNoiseResidualRatio = 0.35;
/// Heavy noise (O(h^2)): cubic smoothing fits, whose foot points carry no error from the
/// surface's cubic terms on asymmetric stencils (a quadratic's do, O(h^3) per pass, which
/// the final fit differentiates into O(h) curvature errors) and which average more noise
/// than quartics on the stencils they need. After smoothing, the final fit uses the text's
/// steep weights at degrees <= 3, where the truncation error of a large stencil dominates
/// (at degree 3 also the clean stencils, below kVeryHeavyNoiseResidualRatio), and flat weights on the noise stencils at degree
/// >= 4, where the noise still dominates (measured choices, bench/README.md).
/// Light noise (O(h^3), small O(h^2)): the truncation error dominates, so the smoothing
/// fits are of degree d + 2 (<= 5) and the final fit is the clean one (clean stencils,
/// steep weights), approximating, on the smoothed mesh; at degree >= 4 on 2x the
/// coefficients with eps = 0.1 (its truncation error is small, the noise still counts).
/// At degree 3 the final fit's Hessian comes from 1.5 rings (>= 1x the coefficients: less
/// truncation error) in the tangent plane of a degree-3 fit on the clean 2 rings; at
/// degree >= 3 with residual ratio >= kLocalSmoothingResidualRatio two local passes follow
/// the two smoothing passes (LocalSmoothingSteps), which the torus wants and the strongly
/// curved bump's centre does not (bench/README.md, fourth round).
/// Moderate noise (small O(h^2), residual ratio in [0.2, 0.35)) at degree >= 3: the heavy
/// schedule's final fit after 4 smoothing passes of degree d + 2 (<= 5), whose foot points
/// carry no quartic-term bias (which cubic smoothing leaves on a strongly curved surface)
/// and which average as much noise as two cubic passes; within a ring of the boundary,
/// where they extrapolate one-sided stencils, the smoothing fits stay cubic
/// (bench/README.md, third round).
/// Seventh round (Linf): degree 2 below kSlopeRefinementResidualRatio: quintic smoothing and
/// the slope refinement; degree 3 under light noise and degree 4 under moderate noise: the
/// two-scale final fit (TwoScaleFinalFit); degree >= 3 from kModerateNoiseResidualRatio:
/// the unshrink passes (UnshrinkSteps).
/// Ninth round: degree 2 from kModerateNoiseResidualRatio with cubic_ratio (NoiseEstimate)
/// below kHeavyNoiseCubicRatio: kSymmetricSmoothingPasses quintic passes and the slope
/// refinement (kSlopeRefinementResidualRatio's tier).
NoiseSchedule NoiseScheduleFor(int degree, double residual_ratio, double cubic_ratio = 1);
/// The options of a smoothing pass's fits: approximating, flat weights, the schedule's
/// degree on the noise mode's own stencils (`options`' rings and factor are the final fit's).
FitOptions NoiseSmoothingOptions(const FitOptions& options, const NoiseSchedule& schedule);

/// Every vertex moved onto its own fit (the fit's point at its origin, x(0, 0) of
/// Table 3.1); vertices without a fit, or not marked in `only` (when given), keep `positions`.
/// With `step`, each moves that fraction of the way (negative: away, UnshrinkSteps).
Positions ProjectOntoFits(const SurfaceFits& fits, const Positions& positions, int num_threads = 0,
                          const double* step = nullptr);

/// The step of the local smoothing passes per vertex: 1 / (1 + q^2) of the way to its
/// fit's foot point, q = (the fit's top-degree part over one edge length h, |c_jk / (j! k!)|
/// h^p over j + k = p) / (kLocalSmoothingSignal x the noise level noise_over_h h). Where the
/// surface shows no high-order content above the noise (q << 1) a further pass averages
/// noise; where it does (the bump's centre: q up to 10) it would add the bias of the
/// surface's higher terms, so the vertex stays (a Wiener-like weight: continuous, no
/// seams between moved and kept vertices). LHF fits only (all 0 otherwise).
std::vector<double> LocalSmoothingSteps(const SurfaceFits& fits, const Mesh& mesh, double noise_over_h,
                                        int num_threads = 0);

/// Heavy noise at degree 2 (residual ratio >= kModerateNoiseResidualRatio): the cubic normal
/// pre-fit's slope carries an O(h) noise term on O(h^2) noise (noise / stencil radius), which
/// a stencil of 8x the coefficients (~80 points, radius ~1.6x) cuts ~2.5x at ~4x the O(h^3)
/// bias: gmsh torus at h = 0.0127, 0.5 h^2, normal 0.84 -> 0.57x CGAL (0.49x with the very
/// heavy passes); but inside the
/// strongly curved bump the bias dominates (alpha 0.2 at n = 64: 0.30 -> 0.48x), so the two
/// pre-fits are blended per vertex (BlendLargeStencilNormals; bench/README.md, fifth round).
/// Below the bound the large stencils' bias dominates everywhere (torus alpha 0.1 h^2 at
/// n = 64, ratio 0.245: 0.42 -> 0.59x with them).
inline constexpr double kHeavyNoiseNormalPointsFactor = 8;
/// The noise mode's normal pre-fits grow boundary vertices' (one-sided) stencils to this
/// factor x the coefficients (twice the interior's 3): bump d2 at 0.5 h^2, n = 64, normal
/// Linf 0.85 -> 0.50x CGAL (at boundary vertices), L2 0.39 -> 0.33; no cell got worse.
inline constexpr double kNoiseNormalBoundaryPointsFactor = 6;
/// `normals` (rows marked in `adopted`: the small-stencil pre-fit's, n_s) blended with the
/// large-stencil fits' normals n_L (a Lepski-like choice of the stencil): per vertex
/// n = (w n_L + (1 - w) n_s) / |.|, w = 1 / (1 + (d / tau)^2), d = |n_L - n_s|,
/// tau = kNormalBlendSpread x the median of d. Where the noise dominates, d is n_s's noise,
/// about its median, and n_L (less noise) wins; where d is far above it (the large
/// stencil's bias: the bump's centre), n_s stays.
inline constexpr double kNormalBlendSpread = 4;
void BlendLargeStencilNormals(const SurfaceFits& large, const std::vector<uint8_t>& adopted, Positions* normals,
                              int num_threads = 0);

/// Heavy noise at degree 3 (residual ratio >= kModerateNoiseResidualRatio; it replaces the
/// very heavy tier's noise stencils and 3 + 1 passes there): the clean final stencils' truncation error is small but
/// their noise term dominates H and K on fine or marching-cubes meshes (gmsh torus 0.1 h^2:
/// 0.73 / 0.80x CGAL; marching cubes N = 64: 0.90 / 0.93x), while on the noise stencils
/// (3x the coefficients) the bias dominates where the surface is strongly curved (bump
/// alpha 0.2: K 0.67 -> 1.00x, 99% of its K error at the 10% of vertices with |K| > 4).
/// The two fits' difference D = c_noise - c_clean (orders 0-2, as an ambient offset, vector
/// and tensor) is the large stencil's bias, smooth over the surface, plus the small
/// stencil's noise, which varies from vertex to vertex. TwoScaleFinalFit keeps the smooth
/// part and takes the rough part away: c = c_clean + w (D - S(D)), S the mean over the
/// noise stencil, i.e. the clean fit's low-pass plus the noise fit's high-pass. w = 1 / (1 +
/// (|Hess| / (kTwoScaleSpread x median |Hess|))^2) from the clean fit's Hessian spares
/// the strongly curved parts, where the bias varies at the scale of S.
/// The local passes (three after the two global ones) use CurvatureSmoothingSteps, the
/// same weight from the first smoothing fits: global smoothing where the surface is
/// mildly curved (marching cubes: its noise varies at scale h), none where it is strongly
/// curved (the cubic smoothing fits' bias). bench/README.md, "Noisy meshes, sixth round".
inline constexpr double kTwoScaleSpread = 2;
/// The local passes (CurvatureSmoothingSteps) under heavy noise, at degree 3 and, since the
/// eighth round, at degree >= 4 (after its 2, or very heavy 3, global passes; the very heavy
/// tier's one LocalSmoothingSteps pass before): the marching-cubes tori's noise varies at
/// scale h and their largest errors sit at isolated vertices where the raw positions are
/// worst (the same vertices as CGAL's), which more global smoothing averages away where the
/// surface is mildly curved while the bump's centre keeps its steps near 0. Marching cubes d4
/// N = 64: K Linf 0.74 -> 0.53x the best CGAL, N = 128 normal Linf 0.73 -> 0.66x; the bump
/// and torus at alpha 0.2 / 0.5 h^2 and the gmsh torus at 0.1 h^2 improve too
/// (bench/README.md, eighth round).
inline constexpr int kCurvatureLocalPasses = 3;
/// Degree 3 from kVeryHeavyNoiseResidualRatio (ninth round): more of those passes. Raw
/// marching-cubes tori keep their largest K errors at isolated vertices in mildly curved parts,
/// which the passes keep averaging while their steps spare the strongly curved ones: marching
/// cubes N = 112 (residual ratio 0.66) K L2 / Linf 0.73 / 0.72 -> 0.54 / 0.54x the best CGAL,
/// N = 56 (0.56: below, unchanged); torus / ellipsoid / sphere at 0.1-0.5 h^2, n = 32-64:
/// max of six norms 0.39-0.41 -> 0.27-0.29x; bump 0.5 / 1 h^2 n = 64: 0.66 / 0.71 -> 0.68 /
/// 0.68x (bench/README.md, `noise9`).
inline constexpr int kVeryHeavyCurvatureLocalPasses = 8;
/// The same fit on two stencil sets elsewhere (bench/README.md, seventh round): at degree 3
/// under light noise the 1.5-ring final fit (own) with the fit on the clean 2 rings whose
/// tangent plane it keeps (other; the mean over those): its noise at the torus's inner
/// equator set the K Linf (O(h^3) alpha 0.5, n = 64: K 0.65 (Linf 0.80) -> 0.55 (0.53)x the
/// best CGAL); at degree 4 under moderate noise (residual ratio in [0.2, 0.35)) the final fit
/// on the clean stencils grown to kModerateNoiseFinalPointsFactor x the coefficients (own)
/// with the 3x-coefficient noise stencils of the smoothing fits (other): the large
/// stencil's bias on the bump's flank set its K Linf (alpha 0.1 h^2: 0.61 (0.71) -> 0.41
/// (0.52)x; torus normal 0.63 -> 0.60x). Under heavy noise at degree 4 the torus's
/// normals want the noise stencils (alpha 0.2: 0.62 -> 0.72x two-scale).
inline constexpr double kModerateNoiseFinalPointsFactor = 2;
/// `coefficients` (`own`'s LHF fits on the clean stencils, written in place) from `own`
/// and `other` (the same frames and degree on the noise stencils `other_nb`); vertices
/// whose frames differ keep `own`'s.
void TwoScaleFinalFit(const SurfaceFits& own, const SurfaceFits& other, const Neighborhoods& other_nb,
                      double spread, double* coefficients, int num_threads = 0);
/// Per-vertex steps 1 / (1 + (|Hess_v| / (spread x median |Hess|))^2) from `fits`' Hessians
/// (LHF fits; 0 where unfitted).
std::vector<double> CurvatureSmoothingSteps(const SurfaceFits& fits, double spread, int num_threads = 0);

/// Heavy noise at degree >= 3 (residual ratio >= kModerateNoiseResidualRatio): every
/// smoothing pass flattens the strongly curved bump's peak (its foot points lie below a
/// surface whose quartic terms the cubic fit averages over the stencil), and the final fit
/// then underestimates K there (alpha 0.2 at n = 64: 98 against 102 at the centre, where
/// the bump's K Linf sat; CGAL's largest errors are elsewhere, from noise). After the
/// schedule's passes, kUnshrinkPasses more move each vertex *away* from its smoothing fit's
/// foot point, x -= kUnshrinkStep (1 - w) (foot - x), w = CurvatureSmoothingSteps(fits,
/// kUnshrinkSpread): the bias estimate S(x) - x of the smoothed, nearly noise-free mesh
/// taken back (a Taubin-like step), only where the surface is strongly curved (w -> 0: the
/// bump's centre, |Hess| ~ 10x the median), so the noise the passes removed elsewhere stays
/// removed. Bump K Linf at alpha 0.5 / 0.2: d3 0.85 / 0.86 -> 0.66 / 0.52x the best CGAL, d4
/// (alpha 0.2) 0.99 -> 0.52x. A wider weight (step 2, spread 3) moved the torus and the
/// marching-cubes meshes too (torus alpha 0.2 d4 normal 0.62 -> 0.66x, marching cubes N = 64
/// d4 K Linf 0.72 -> 0.77x; bench/README.md, seventh round).
inline constexpr int kUnshrinkPasses = 2;
inline constexpr double kUnshrinkStep = 4;
inline constexpr double kUnshrinkSpread = 8;
/// Every vertex moved onto a per-vertex blend of its two smoothing fits' foot points x_l
/// (`low`) and x_h (`high`, of a higher degree; x(0, 0) of Table 3.1):
/// x_l + w (x_h - x_l), w = t^2 / (1 + t^2), t = |x_h - x_l| / (spread x noise), noise =
/// noise_over_h x the mean edge length. Where the two differ by less than the noise, the
/// lower degree, which averages more of it, wins (the gmsh torus: t ~ 0.1-0.4); where they
/// differ by more (the lower degree's bias from the surface's higher terms: the generated
/// torus at n = 64, t ~ 0.5, and the bump's flanks, t up to ~10) the higher degree does.
/// With `step` (the local passes), each vertex moves that fraction of the way there.
/// Vertices fitted by one only take its foot point; by none, keep `positions`.
Positions BlendFootPoints(const SurfaceFits& low, const SurfaceFits& high, const Positions& positions,
                          const Mesh& mesh, double noise_over_h, double spread, const double* step = nullptr,
                          int num_threads = 0);

/// NoiseMode::kAuto at degree >= 3 (fit.cc): whether the first smoothing pass (`before` ->
/// `after`) moved the vertices by more than the noise it was to remove. Where the noise
/// dominates, the moves |after - before| are the noise (uniform alpha h^k along the normal,
/// marching cubes: 90th percentile 1.1-2.0x the noise level noise_over_h x the mean edge
/// length, 1.9-2.7x their median); where the smoothing fits' bias does (the strongly curved
/// open bump at n <= 32 under light noise, which the sextic ratio calls noisy), a tail of
/// vertices moves much further: 90th percentile 2.5-8x the noise level and 3.3-12x the
/// median. Both above kSmoothingBiasQuantile90 and kSmoothingBiasSpread: the noise mode
/// would lose to the default fit (bump 0.2 h^3 n = 32, d3 normal 0.98 vs 0.47x the best
/// CGAL; bench/README.md, `noise7`).
inline constexpr double kSmoothingBiasQuantile90 = 2.2;
inline constexpr double kSmoothingBiasSpread = 3;
bool SmoothingBiasDominates(const Positions& before, const Positions& after, const Mesh& mesh, double noise_over_h);

/// The unshrink passes' per-vertex steps (negative; 0 where unfitted) from `fits`.
std::vector<double> UnshrinkSteps(const SurfaceFits& fits, int num_threads = 0);

/// The noise test of NoiseMode::kAuto, on a sample of vertices: approximating degree-2,
/// 4 and 6 fits on the same (>= 40-point) stencil. On smooth data the quartic's residual
/// is O(h^2) times the quadratic's; on noisy data both residuals are the noise's and their
/// ratio approaches 1. That ratio alone misses light noise (O(h^3), alpha 0.1-0.5: 0.01-0.08)
/// that clean coarse meshes reach by truncation (up to 0.18): the noise is then below the
/// quadratic's truncation error but above the quartic's, which sets the default fits'
/// curvatures (torus 0.2 h^3, n = 64: K L2 4.2x CGAL's). The sextic's residual against the
/// quartic's, each per remaining degree of freedom (rms x sqrt(rows / (rows - coefficients))),
/// tells them apart: truncation keeps dropping, O(h^2) again (clean meshes, gmsh and
/// marching-cubes included, coarse to fine: <= 0.24), while noise floors at 1 (0.6-1.0
/// where the noise is above the quartic's truncation; bench/README.md, issue 16).
struct NoiseEstimate {
  double residual_ratio = 0;   ///< median over the sample of rms(res_4) / rms(res_2)
  double noise_over_h = 0;     ///< median rms(res_4) / h (the noise level, relative)
  double sextic_ratio = 0;     ///< median rms(res_6) / rms(res_4) x sqrt((rows - 15) / (rows - 28))
  double cubic_ratio = 0;      ///< median rms(res_4) / rms(res_3) (kHeavyNoiseCubicRatio)
  double curvature_h = 0;      ///< median |Hessian| of the quadratic fits x h (NoiseSmoothingPointsFactor)
  int samples = 0;
  /// residual_ratio > kNoisyResidualRatio (clean meshes: < 0.18) or sextic_ratio >
  /// kNoisySexticRatio (clean meshes: <= 0.24).
  bool noisy = false;
};
inline constexpr double kNoisyResidualRatio = 0.2;
inline constexpr double kNoisySexticRatio = 0.5;
/// NoiseMode::kAuto at degree >= 3 (fit.cc) calls noisy from this sextic ratio on: there the
/// smoothing-bias check (SmoothingBiasDominates) sends the meshes whose smoothing fits' bias
/// would cost back to the default fit (the coarse bump 0.1 h^3 n = 32, sextic ratio 0.454,
/// for which auto3 kept 0.5), and the 0.45-0.5 band holds lightly perturbed meshes where the
/// noise mode wins at degrees 3-6 (gmsh torus 0.1 h^3, h = 0.0275: 0.494, d4 max error 3.85
/// -> 0.66x the best CGAL, d3 0.77 -> 0.37x). Not 0.4: a coarse gmsh ellipsoid at 0.1 h^3
/// (0.409) loses with the noise mode at d3 / d5 (0.88 -> 1.87x); clean meshes stay below
/// 0.24 (bench/README.md, `noise8`).
inline constexpr double kNoisySexticRatioHighDegree = 0.45;
/// NoiseMode::kAuto at degree 2 calls noisy from this sextic ratio on where the noise mode's
/// schedule is the nearly clean slope tier (residual ratio below kSlopeRefinementResidualRatio:
/// quintic smoothing, then the interpolating fit with the slope refinement). Band audit
/// (bench/README.md, `noise9`): clean meshes (generated n = 8-128, gmsh, marching cubes) read
/// <= 0.22 (noise8's set: <= 0.234); perturbed O(h^2) / O(h^3) meshes at 0.30-0.50 in the slope
/// tier: the noise mode wins at 11 of 14 (torus 0.1 h^3 n = 56, 0.478: 0.77 -> 0.24x the best
/// CGAL; bump 0.05 h^3 n = 48, 0.492: 0.81 -> 0.40x; the held-out gmsh torus 0.1 h^3 at
/// h = 0.0275, 0.494: 0.80 -> 0.15x) and loses at the very coarse bump n = 16 (289 vertices,
/// 0.2 / 0.3 h^3: 1.24 -> 1.72x) and sphere n = 8 (386: 0.81 -> 1.18x). The bias check of degree
/// >= 3 would send the bump n = 24-48 back to the default fit (0.40 -> 0.81x), so degree 2 runs
/// without it (as noise7 found). Above the slope tier (residual ratio >= 0.095: coarse meshes,
/// n <= 24) the light tier's approximating final fit loses to the default fit (torus 0.3 h^3
/// n = 24: 0.87 -> 1.10x), so auto keeps the default fit there.
inline constexpr double kNoisySexticRatioDegree2 = 0.3;
/// Whether NoiseMode::kAuto fits a mesh with this estimate at `degree` in the noise mode.
inline bool NoisyAt(const NoiseEstimate& est, int degree) {
  return est.noisy || (degree >= 3 && est.sextic_ratio > kNoisySexticRatioHighDegree) ||
         (degree == 2 && est.sextic_ratio > kNoisySexticRatioDegree2 &&
          est.residual_ratio < kSlopeRefinementResidualRatio);
}

/// Degree 2 under heavy noise (cubic smoothing fits): the smoothing fits' stencil size by the
/// noise level (issue 16 item 1, the orders on O(h^2) noise). With position noise sigma and a
/// stencil of radius R (n ~ (R / h)^2 points) the smoothed mesh keeps noise ~ sigma / sqrt(n),
/// whose curvature error ~ sigma / (R^2 sqrt(n)) = sigma h / R^3 does not shrink with h on the
/// fixed rings (R ~ h) when sigma ~ h^2 (§3.3: "lower than linear"; main's sphere at 0.3 h^2: H
/// order 0.16), against a bias growing with R. Balancing the two, (R / h)^4 ~ (sigma / h) /
/// (kappa h)^2, from the noise test's noise level (noise_over_h) and curvature scale (the median
/// |Hessian| of its quadratic fits, curvature_h): the stencils grow to
/// kGrownSmoothingPointsScale x sqrt(q) x the coefficients, q = noise_over_h / curvature_h^2,
/// clamped to kMaxStencil points (16x for cubics); below the noise mode's own 3x: 0 (unchanged).
/// O(h^2) noise: q ~ 1 / h, so R ~ h^(3/4) and the curvature error ~ h^(3/4) or better. Every
/// global and local smoothing pass also fits the grown stencils and moves each vertex to the
/// BlendFootPoints blend of the two foot points (grown as `low`, spread kFootPointBlendSpread):
/// where they differ by more than the noise (the grown stencil's bias: the bump's peak) the
/// noise mode's own fit wins. Generated sphere / ellipsoid / torus at 0.3 h^2, n = 16-128, H L2
/// orders 0.16 / 0.29 / 1.29 -> 0.98 / 1.06 / 1.50 (bench/README.md, `noiseord`). Not at
/// degrees 3-4: their unshrink and curvature-weighted local passes undo the standard stencils'
/// bias only, and the bump's K Linf grew fourfold (alpha 0.5 h^2 d3: 0.66 -> 2.6x CGAL's).
inline constexpr double kGrownSmoothingPointsScale = 7.5;
/// The factor above (0: the noise mode's own stencils) for a fit of `degree` whose schedule
/// smooths at `smoothing_degree`.
double NoiseSmoothingPointsFactor(const NoiseEstimate& est, int degree, int smoothing_degree);

/// The noise test's stencils: 2.5 rings, grown to 40 points, at most 80.
RingSpec NoiseStencilSpec();
/// `normals`: approximate vertex normals (frames). CANCELLED / DEADLINE_EXCEEDED from ctx.
/// The sample is every (n / 2000)-th vertex, by source index when topo.vertex_source is
/// set (a relabelled mesh: the same vertices and stencil point sets, hence the same
/// estimate to round-off). The stencils are built for the sampled vertices alone (BuildNeighborhoodsOf); with
/// `all_stencils` (every vertex's, of NoiseStencilSpec(): the tests' reference path) those
/// are read instead, with the same result bit for bit.
absl::StatusOr<NoiseEstimate> EstimateNoise(const Mesh& mesh, const Topology& topo, const Positions& normals,
                                            const RunContext& ctx = {},
                                            const Neighborhoods* all_stencils = nullptr);

}  // namespace geomfit
