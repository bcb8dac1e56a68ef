#pragma once

#include "core/fitting/fit.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/mesh.h"
#include "core/util/run_context.h"
#include "absl/status/status.h"

namespace geomfit {

/// Hermite normals of interpolating degree-1 (plane) fits (FitOptions::plane_hermite).
///
/// A plane fitted to the heights h_k = a.p_k + p_k^T H p_k / 2 + O(p^3) of a stencil over a
/// vertex's frame (weights (2.2.1) at degree 1, c_k the least-squares weights of its
/// gradient, sum_k c_k p_k^T = I) has the gradient g = a + B H + O(h^2), B H =
/// sum_k c_k p_k^T H p_k / 2: the quadratic term's projection onto the plane's columns, O(h)
/// on an irregular stencil and varying from vertex to vertex like its odd moments, but a
/// known linear map of the Hessian (2 x 3, from the stencil alone). Every vertex's B is
/// formed with its plane (pass 1). Pass 2 writes each neighbour j's plain normal as a slope
/// G_j in the vertex's frame: G_j = a + H p_j + R_j B_j (R_j^T H R_j) + O(h^2) (R_j: j's
/// tangent basis in the vertex's, which carries j's Hessian and slope error between the
/// frames), and the vertex's own g = a + B H; their differences G_j - g, linear in H alone,
/// are fitted for the Hessian (3 unknowns, two rows a neighbour, unit weights), whose O(h)
/// error (the O(h^2) residuals over |p_j|) leaves the corrected gradient a = g - B H with
/// O(h^2): normals of order 2 instead of 1 (Euler's identity p.grad Q = 2 Q behind the
/// Hermite rows of the other degrees, slopes.h, applied to the plane's own bias).
///
/// The fits keep their frames and get the corrected normal as their gradient (c10, c01);
/// vertices whose fit has degree_used < 1, or whose Hessian fit has fewer than two
/// neighbours (the safeguard gamma of (2.2.1) on the frames' normals, both passes) or is
/// singular, keep theirs. Parallel, the same bits for any thread count; polls `ctx`
/// between chunks and writes the fits only at the end (a cancelled run leaves them plain).
absl::Status RefinePlaneNormals(const Mesh& mesh, const Neighborhoods& nb, double cos_cut, double weight_epsilon,
                                const RunContext& ctx, const VertexDiagnostics* diagnostics, LocalFrame* frames,
                                double* coefficients, int num_coefficients);

}  // namespace geomfit
