#pragma once
#include <cstdint>

#include "core/fitting/fit.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/mesh.h"
#include "core/mesh/topology.h"
#include "core/util/run_context.h"
#include "absl/status/status.h"

namespace geomfit {

/// The normal passes of FitOptions::cubic_hermite (degree 3) before its Hermite curvatures
/// (bench/README.md, `d3nrm`: one pass leaves the finest marching-cubes torus's normal Linf
/// at 0.39x and K Linf at 0.43x CGAL's, two at 0.26x / 0.28x, for ~15% more CPU time).
constexpr int kCubicSlopePasses = 2;

/// FitOptions::quadratic_hermite: the operator applications after a degree-2 fit, and the share
/// of the last one's Hessian in the one reported (the rest the fit's own; see RefineSlopes).
/// Scanned on gmsh, marching-cubes and generated meshes (bench/README.md, `d2fast`): 0.6-0.65
/// leave lower Linf orders of H and K on the gmsh ellipsoid, 0.75 the coarsest gmsh torus's
/// K Linf at 0.51x CGAL's; one application leaves the gmsh ellipsoid's H at 0.64x.
constexpr int kQuadraticSlopePasses = 2;
constexpr double kQuadraticShare = 0.7;

/// Slope refinement of interpolating degree-2 height fits (FitOptions::slope_refinement):
/// two passes over the fits' own stencils that use the neighbours' fitted normals.
///
/// 1. Normals. In the frame of a vertex's fitted normal, a stencil point p_j at height h_j
///    whose normal has slopes G_j satisfies, for the Taylor expansion f = a.p + p^T H p / 2
///    + C(p) / 6 + O(p^4), p.grad C(p) = 3 C(p) (Euler), hence
///    h_j - p_j.G_j / 3 = (2/3) a.p_j + (1/6) p_j^T H p_j + O(p^4): the cubic term, whose
///    projection onto the linear columns is the O(h^2) error of a degree-2 fit's gradient
///    (the u^3 column projects onto u), cancels exactly. The slopes G_j are the neighbours'
///    degree-2 normals, biased by e_j = O(h^2): they enter the new gradient as -e_j / 2 when
///    read as (3/2) of the fitted linear term. The refinement reports the fitted linear term
///    itself, (2/3) of that: the mean of the vertex's own gradient (error e_0, zero in its
///    own frame) with weight 1/3 and the new one with weight 2/3, in which the leading,
///    smooth part of the bias cancels (e_0 - mean e_j) / 3; what is left is the bias's
///    variation over the stencil and the quartic term's D r^4 / 72.
///    Each further pass (`passes` in all) repeats this with the previous pass's normals.
/// 2. Curvatures. The Hermite rows of FitOptions::hermite_hessian (hermite.h:
///    4 h_j / r_j^2 - g_j / r_j = e^T H e + C(p_j) / (6 r_j^2) + O(r^3), the quartic term
///    cancels), in the frame of the refined normal with the refined normals of the
///    neighbours, fitted with the cubic form C as four more unknowns (ridge: 1% of the
///    Hessian block's trace), so the cubic term no longer enters through the stencil's odd
///    moments; row weights s / (s + 0.3)^2.5. (The three-unknown fit of hermite_hessian left
///    the coarsest quad torus's and the finest marching-cubes torus's K Linf at 0.63x / 0.54x
///    CGAL's; this one at 0.41x, bench/README.md.)
///
/// Frames get the refined normals (the fits keep their tangent plane: c10 = c01 = 0);
/// vertices whose fit used degree < 2, or whose passes are ill-posed, keep their plain fit
/// (normal) or plain Hessian. `fits` must be interpolating LHF fits of degree 2, with
/// `coefficients` holding 6 Taylor coefficients per vertex; the neighbourhoods list the
/// centre first. Vertices are visited in `topo.locality_order` when it is set (the
/// neighbourhoods' ordered stencils), 8 at a time in vector lanes; every vertex's
/// result is independent of its batch and of the instruction set. Polls `ctx` between
/// chunks; the fits are written only at the end (a cancelled run leaves them unrefined).
///
/// Degree 2 by the fit's own operator (FitOptions::quadratic_hermite, `operator_passes` > 0,
/// `passes` ignored): no change of frame and no Hermite pass. The plain fit's least-squares
/// operator (its frame m, columns u, w, u^2/2, uw, w^2/2, weights (2.2.1) with eps =
/// `weight_epsilon`, the rows' gamma from the current normals) is applied to
/// r_j = h_j - p_j.G_j / 3 = (2/3) h_j + (d_j.n_j) / (3 m.n_j) = (2/3) a.p + T2(p) / 3 - T4(p) / 3
/// + O(p^5) - p.e_j / 3 (Euler; e_j the neighbour's slope error): the cubic term cancels. The
/// new gradient is the fitted linear term plus a third of the current one (error
/// (e_0 - mean e_j) / 3, as above); each application uses the previous one's normals. The
/// Hessian, 3x the fitted quadratic part, has -T4's projection where the fit's own has +T4's
/// and the cubic's (the cubic's only through odd moments, O(h) on irregular stencils): the
/// reported one is kQuadraticShare of the last application's and the rest the fit's, i.e. the
/// operator on (1 + 2 s) h_j - s p_j.G_j (s = the share), the T3 and T4 terms at 0.3 / -0.4 of
/// the fit's. The fits get the new gradient (c10, c01) and Hessian; frames and the tangent
/// plane stay the fit's.
///
/// Degree 3 (FitOptions::cubic_hermite: `num_coefficients` = 10, normals already O(h^3),
/// `passes` = kCubicSlopePasses) stays in each fit's own frame. The normal passes fit
/// h_j - p_j.G_j / 4 (the quartic term cancels, the rest is in the degree-3 columns) less a
/// quarter of the cubic, with the four cubic unknowns ridged towards it, and report the
/// fitted linear term plus a quarter of the vertex's current gradient (error
/// (e_0 - mean e_j) / 4); each pass also keeps the cubic it fitted. The curvature pass's
/// rows then subtract that gradient and cubic (4h - p.grad h = 3 a.p + p^T Hess p +
/// C(p) / 6 + O(p^5) in a tilted frame), the four cubic unknowns correct the cubic (ridge
/// 0.3%, weights s / (s + 0.5)^2.5). The fits get the refined normal as their gradient
/// (c10, c01) and the new Hessian (c20, c11, c02); frames and cubic terms stay the fit's.
///
/// Degrees 4 and 5 (FitOptions::jet_hermite: `num_coefficients` 15 / 21, passes = 0): the
/// Hermite jets. For the homogeneous Taylor terms T_k of the height over the fit's frame,
/// Euler's identity p.grad T_k = k T_k gives a h_j - p_j.G_j = sum_k (a - k) T_k(p_j) along the
/// ray to p_j (G_j: the neighbour's fitted slopes), so a = degree + 1 cancels T_{degree+1},
/// the leading bias of the fit's Hessian and gradient (hermite.h is a = 4). The rows
/// 2 (a h_j - p_j.G_j) / ((a - 2) r_j^2) less the fit's terms of degrees 1 and 3..degree are
/// fitted with all monomials of degrees 1..degree / r_j^2 (weights (2.2.1)'s gamma times
/// s / (s + eps)^2.5; degrees >= 3 ridged 0.3% towards the fit's): the Hessian replaces the
/// fit's (degree 5: 0.6 of it, 0.4 the fit's own), and (a - 1) / a of the gradient's
/// correction is added to c10, c01 (the neighbours' normal bias e enters it as -e / (a - 1),
/// the fit's own as e: the weights cancel the smooth part, as the degree-2 normal pass's 1/3,
/// 2/3). Frames and terms of degree >= 3 stay the fit's.
absl::Status RefineSlopes(const Mesh& mesh, const Topology& topo, const Neighborhoods& nb, double cos_cut, int passes,
                          const RunContext& ctx, const VertexDiagnostics* diagnostics, LocalFrame* frames,
                          double* coefficients, int num_coefficients = 6, int operator_passes = 0,
                          double weight_epsilon = 0.01);

}  // namespace geomfit
