#pragma once
#include <array>
#include <cstdint>
#include <string>

#include "absl/status/status.h"

namespace geomfit {

/// How vertex neighbourhoods are parametrized (2.2, 3.2).
enum class FitMethod {
  kLHF,  ///< local height function over a tangent plane (Table 3.1, right column)
  kLOP,  ///< local orthogonal projection; parametric fit of x, y, z (Table 3.1, left)
  /// Comparison methods of chapters 2-3 (parametric fits of x, y, z; differentials only,
  /// not reconstruction): see core/fitting/parametric.h.
  kXu,    ///< Xu's 1-ring parametrization (2.2): angles scaled to 2 pi, edge lengths kept
  kLSCM,  ///< least-squares conformal map of each stencil's faces (2.2)
};

/// The least-squares solver (2.4).
enum class WlsSolver {
  kQR,   ///< column-scaled Householder QR, whole degrees dropped by condition (the default)
  kSVD,  ///< SVD of the same scaled matrix, singular values below sigma_1 / cut-off dropped
};

/// How approximate vertex normals (for frames and the weight safeguard) average faces.
enum class NormalWeighting { kArea, kAngle };

/// Noise-aware fitting for input whose positions carry O(h^2) or O(h^3) errors
/// (marching cubes, perturbed or measured data; §3.3 noisy tests). See core/fitting/noise.h.
enum class NoiseMode {
  kOff,   ///< the fits of chapters 2-3 as configured (the default)
  kOn,    ///< approximating fits after smoothing-by-projection passes (§4.2.3) on d/2+1
          ///< rings (2.1), >= 3x the coefficient count; stencils, weights and the smoothing
          ///< fits' degree follow the measured noise (NoiseSchedule, noise.h)
  kAuto,  ///< kOn where the mesh looks noisy (EstimateNoise), else kOff
};

/// The Hermite jets of degree-4/5 fits (FitOptions::jet_hermite).
enum class JetHermiteMode {
  kAuto,  ///< on at degree 5, off at degree 4 (the default)
  kOn,    ///< on at degrees 4 and 5
  kOff,   ///< off
};

/// Largest supported fitting degree (28 Taylor coefficients).
inline constexpr int kMaxDegree = 6;
/// Largest number of points in one stencil (fixed-capacity work arrays).
inline constexpr int kMaxStencil = 160;

/// Number of Taylor coefficients of a bivariate polynomial of degree d: (d+1)(d+2)/2.
constexpr int NumCoefficients(int d) { return (d + 1) * (d + 2) / 2; }

/// Options of the per-vertex weighted-least-squares fit. Defaults follow the
/// dissertation (chapters 2-3); every field is validated by ValidateFitOptions.
struct FitOptions {
  int degree = 2;              ///< 1..6
  double rings = 0;            ///< k-ring size in half steps (1, 1.5, 2, ...); 0 = (degree+1)/2
  bool adaptive = true;        ///< grow by half rings until enough points (2.1)
  /// Interior vertices grow to >= factor x #coefficients points; 0 = automatic: 1.5 as in
  /// (2.1), but 2.0 for degrees <= 2, whose 1.5-rings at valence-4 vertices (common in
  /// marching-cubes meshes) hold barely enough, often clustered, points.
  double min_points_factor = 0;
  double boundary_points_factor = 2.0;  ///< boundary vertices grow further
  double max_rings = 8;        ///< adaptive growth stops here (corners of open meshes need it)
  int max_points = 120;        ///< and never beyond this many points (<= kMaxStencil)
  FitMethod method = FitMethod::kLHF;
  double safeguard_angle_deg = 70;  ///< gamma_i = 0 beyond this normal angle (2.2.1)
  bool interpolate = true;     ///< fit passes through the centre vertex (c00 fixed)
  bool oscillation_safeguard = false;  ///< (4.1.3) lower the degree of oscillatory fits
  bool two_pass = false;       ///< refit in frames from the first pass's fitted normals
  NormalWeighting frame_normals = NormalWeighting::kArea;
  double weight_epsilon = 0.01;  ///< eps of (2.2.1), distances scaled by the stencil radius
  /// Condition-number cut-off of the column-scaled QR (2.4) per degree 1..6; a fit whose
  /// R exceeds it drops its highest degree, repeatedly. Index 0 unused.
  double cond_threshold[kMaxDegree + 1] = {0, 1e3, 1e3, 3.3e3, 1e4, 1e5, 1e6};
  /// Noise-aware fitting; kOn changes the automatic rings / min_points_factor and makes
  /// the fits approximating with the schedule's eps (interpolate and weight_epsilon are
  /// ignored; rings and min_points_factor, when set, apply to the final fit).
  NoiseMode noise = NoiseMode::kOff;
  /// Smoothing-by-projection passes before the final fit (§4.2.3: every vertex moves to
  /// its own approximating fit, then all are refitted); -1 = automatic: 0, or with noise the
  /// schedule's (NoiseScheduleFor: 2, or 4 under moderate noise at degree >= 3, plus two
  /// per-vertex local passes under light noise at degree >= 3; noise.h).
  int smoothing_passes = -1;
  WlsSolver solver = WlsSolver::kQR;
  /// Degree of a first LHF fit whose normals fix the final fit's tangent planes: the
  /// final fit is solved in the frame of that normal and keeps it (c10 = c01 = 0), so a
  /// degree-2 fit reports O(h^3) normals while its Hessian stays the degree-2 fit's
  /// (normal refinement, §3.2). 0 (default) or a value <= `degree`: off. Opt-in because
  /// it costs ~3.5x a plain degree-2 fit (a second neighbourhood build and a degree-3
  /// fit); normals 0.03-0.43x CGAL's at degree 2 with it (bench/README.md).
  int normal_degree = 0;
  /// Hermite curvatures (degree-2 interpolating LHF fits only; ignored otherwise): the
  /// Hessian is fitted to the directional second derivatives 4 h_j / r_j^2 - g_j / r_j
  /// of the stencil points (height h_j, radial slope g_j of the refined normal at r_j),
  /// in which the quartic Taylor term cancels and the cubic one halves (it enters only
  /// through the stencil's odd moments): H and K 0.04-0.45x CGAL's at degree 2. Implies
  /// the normal refinement (normal_degree 3 when unset), which supplies O(h^3) normals at
  /// every vertex; the stencil operators stay the plain fit's. Not for noisy input.
  bool hermite_hessian = false;
  /// Slope refinement (degree-2 interpolating LHF fits with the QR solver, when neither
  /// normal_degree nor hermite_hessian asks for the pre-fit; ignored otherwise and by the
  /// GFD operators): this many normal passes over the fit's own stencils with the
  /// neighbours' fitted normals, normals from h_j - p_j.G_j/3 in which the cubic term
  /// cancels, then the Hermite Hessian (hermite.h) with the cubic remainder as four more
  /// unknowns, in the refined frame (core/fitting/slopes.h). 0 = off (default), 1..3. The
  /// recipe for the best clean-mesh accuracy at degree 2 is 2: normals 0.01-0.49x, H
  /// 0.01-0.38x, K 0.03-0.38x CGAL Jet_fitting_3's on gmsh, marching-cubes, structured and
  /// quad meshes (marching cubes up to 342k vertices: <= 0.29x), for ~3x the CPU time of a
  /// plain degree-2 fit; at 1, ~2.5x, normals 0.03-0.42x, H 0.02-0.46x, K 0.04-0.48x, the
  /// max-norm ones growing towards 0.5x on fine marching-cubes meshes (bench/README.md). Not for
  /// noisy input.
  int slope_refinement = 0;
  /// Slope refinement and Hermite curvatures of degree-3 fits (interpolating LHF fits with
  /// the QR solver, noise off): after the fit, two normal passes over its stencils with the
  /// neighbours' normals (slopes.h: h_j - p_j.G_j / 4, in which the quartic term, the
  /// leading error of the fit's gradient, cancels; each pass shrinks the neighbours' errors
  /// by 4 and cancels their smooth part), then the vertex's Hessian refitted to the Hermite
  /// rows of the slope refinement's curvature pass (hermite.h: 4 h_j / r_j^2 - g_j / r_j,
  /// the quartic term cancels, the cubic form as four more unknowns) with the refined
  /// normals, in the fit's frame. The fit's c10, c01 (the normal) and c20, c11, c02 change;
  /// its cubic terms stay. Off, normals are 0.45-0.63x (0.89x Linf on a marching-cubes
  /// torus) and H, K 0.55-0.96x CGAL Jet_fitting_3's; on, normals 0.03-0.32x, H, K <= 0.54x
  /// (bench/README.md, `clean4`, `d3nrm`). Ignored by the GFD operators (FitRequest::stencils).
  bool cubic_hermite = true;
  /// Slope refinement of degree-2 fits by their own operator (interpolating LHF fits with the
  /// QR solver, noise off, slope_refinement 0; slopes.h): after the fit, its least-squares
  /// operator (same stencil, weights and columns) is applied twice more to
  /// h_j - p_j.G_j / 3 with the neighbours' fitted slopes G_j (the cubic term cancels): the
  /// normal from the second application, the Hessian 0.7 of the second's and 0.3 of the fit's
  /// own, in the fit's frame. On the clean meshes of bench/README.md (`d2fast`): normals
  /// 0.01-0.26x, H and K 0.12-0.42x CGAL Jet_fitting_3's (0.37-0.89x without), for ~2.5x the CPU
  /// time of a plain degree-2 fit: off by default (over issue 15's in-process budget).
  /// Results stream after the whole fit. Ignored by the GFD operators (FitRequest::stencils).
  bool quadratic_hermite = false;
  /// Hermite jets of degree-4 and -5 fits (interpolating LHF fits with the QR solver, noise
  /// off): after the fit, its Hessian and gradient are refitted to the rows
  /// (a h_j - p_j.G_j) / r_j^2 of the stencil points with the neighbours' fitted slopes G_j,
  /// a = degree + 1, in which the fit's leading bias term (of degree + 1) cancels (Euler's
  /// identity; slopes.h), the fit's terms of degrees 3..degree as unknowns ridged towards the
  /// fit's. In the fit's frame; frames and terms of degree >= 3 stay the fit's. On the clean
  /// meshes of bench/README.md (`d45k`): normals 0.03-0.39x, H 0.06-0.46x, K 0.07-0.55x CGAL
  /// Jet_fitting_3's at degrees 4-5 (0.14-0.70x without). Costs ~0.75x a plain degree-4 fit
  /// in process (one more pass over the stencils with a 14- or 20-unknown solve per vertex),
  /// ~1.35x the whole `geomfit curvature` run; kAuto (the default) runs it at degree 5 only: at
  /// degree 4 it is opt-in (kOn), since the whole degree-4 run with it is ~41x CGAL's, too near
  /// issue 15's 40x (bench/README.md, `jets4` and `merge15`). Results stream after the whole
  /// fit. Ignored by the GFD operators (FitRequest::stencils).
  JetHermiteMode jet_hermite = JetHermiteMode::kAuto;
  /// Hermite normals of degree-1 fits (interpolating LHF fits with the QR solver, noise off):
  /// the plane's gradient error on an irregular stencil, O(h), is a known linear map B of the
  /// Hessian (the quadratic term's projection onto the plane's columns); after the fit, the
  /// Hessian is fitted to the neighbours' plain slopes (their own B included) and B H is
  /// subtracted (core/fitting/plane_slopes.h): normals of order 2 instead of 1, 0.01-0.32x CGAL
  /// Jet_fitting_3's degree-1 normals on the clean audit meshes (bench/README.md, `d1slope`),
  /// for one more pass over the stencils. The fit's c10, c01 change; frames stay. Curvatures
  /// stay zero. Ignored by the GFD operators (FitRequest::stencils).
  bool plane_hermite = true;

  /// Whether the Hermite curvatures apply (see hermite_hessian).
  bool HermiteHessian() const {
    return hermite_hessian && degree == 2 && method == FitMethod::kLHF && solver == WlsSolver::kQR &&
           Interpolates();
  }
  /// The slope refinement's normal passes actually run (0: it does not apply).
  int SlopePasses() const {
    return degree == 2 && method == FitMethod::kLHF && solver == WlsSolver::kQR && Interpolates() &&
                   NormalDegree() == degree
               ? slope_refinement
               : 0;
  }
  /// Whether the degree-2 operator refinement runs (see quadratic_hermite).
  bool QuadraticHermite() const {
    return quadratic_hermite && degree == 2 && method == FitMethod::kLHF && solver == WlsSolver::kQR &&
           Interpolates() && noise == NoiseMode::kOff && NormalDegree() == degree && slope_refinement == 0;
  }
  /// Whether the degree-3 Hermite curvatures run (see cubic_hermite).
  bool CubicHermite() const {
    return cubic_hermite && degree == 3 && method == FitMethod::kLHF && solver == WlsSolver::kQR && Interpolates() &&
           noise == NoiseMode::kOff && NormalDegree() == degree;
  }
  /// Whether the degree-4/5 Hermite jets run (see jet_hermite).
  bool JetHermite() const {
    const bool on = jet_hermite == JetHermiteMode::kOn ? degree == 4 || degree == 5
                    : jet_hermite == JetHermiteMode::kAuto ? degree == 5
                                                           : false;
    return on && method == FitMethod::kLHF && solver == WlsSolver::kQR &&
           Interpolates() && noise == NoiseMode::kOff && NormalDegree() == degree;
  }
  /// Whether the degree-1 Hermite normals run (see plane_hermite).
  bool PlaneHermite() const {
    return plane_hermite && degree == 1 && method == FitMethod::kLHF && solver == WlsSolver::kQR && Interpolates() &&
           noise == NoiseMode::kOff && NormalDegree() == degree;
  }
  /// The normal pre-fit's degree actually used; equal to `degree` when there is none
  /// (the noise mode at degree 2 always refines its normals with a cubic, noise.h).
  int NormalDegree() const {
    if (method != FitMethod::kLHF || solver != WlsSolver::kQR) return degree;
    if (HermiteHessian() && normal_degree <= degree) return degree + 1;
    if (noise == NoiseMode::kOn && degree == 2 && normal_degree <= degree) return 3;  // noise.h
    return normal_degree > degree ? normal_degree : degree;
  }

  /// The ring size actually used as the starting ring: (d+1)/2 for clean input, d/2+1
  /// with noise (2.1).
  double StartRings() const {
    return rings > 0 ? rings : noise == NoiseMode::kOn ? degree / 2.0 + 1 : (degree + 1) / 2.0;
  }
  /// The interior growth factor actually used (3 with noise: averaging needs points).
  double MinPointsFactor() const {
    return min_points_factor > 0 ? min_points_factor
           : noise == NoiseMode::kOn ? 3.0
                                     : (degree <= 2 ? 2.0 : 1.5);
  }
  /// Smoothing passes actually run.
  int SmoothingPasses() const { return smoothing_passes >= 0 ? smoothing_passes : noise == NoiseMode::kOn ? 2 : 0; }
  /// Whether fits pass through their centre vertex.
  bool Interpolates() const { return interpolate && noise != NoiseMode::kOn; }
};

/// OK, or INVALID_ARGUMENT naming the field and its valid range.
absl::Status ValidateFitOptions(const FitOptions& options);

/// A readable summary of every option that changes results (logs, summaries); never a
/// cache key (formatted doubles alias: see FitOptionsBits).
std::string FitOptionsKey(const FitOptions& options);

/// Every option that changes results, resolved (automatic values made explicit) and held
/// as exact bit patterns: two option sets give identical fits iff their bits are equal.
/// Cache keys are built from these, never from formatted text (`%g` aliases 1.5 and
/// 1.5000001).
using FitOptionsBits = std::array<uint64_t, 24 + kMaxDegree>;
FitOptionsBits FitOptionsIdentity(const FitOptions& options);

const char* FitMethodName(FitMethod m);
const char* NoiseModeName(NoiseMode m);  ///< "off", "on", "auto"
const char* WlsSolverName(WlsSolver s);  ///< "qr", "svd"

}  // namespace geomfit
