#pragma once
#include "core/fitting/frames.h"
#include "core/fitting/options.h"
#include "core/fitting/wls.h"
#include "core/mesh/topology.h"

namespace geomfit {

/// The comparison methods of chapters 2-3 beside LHF/LOP: other parametrizations of a
/// stencil (2.2) and the SVD solver (2.4). All fit x, y, z parametrically (Table 3.1, left
/// column) like LOP; only the parameters (u_i, v_i) of the stencil points differ.

/// Overwrites P->u, P->v (rows are stencil points pts[first..n) in order) with the
/// parameters of `method`:
///  - kXu: Xu's 1-ring parametrization: the 1-ring (ordered by angle about the normal)
///    keeps its edge lengths to the centre, and its angles at the centre are scaled to sum
///    to 2 pi; the first neighbour lies on the u axis (the frame's t1 side).
///  - kLSCM: the least-squares conformal map of the stencil's faces (quads split),
///    with the centre at the origin and its nearest neighbour pinned at its projection
///    onto the tangent plane (fixing rotation and scale), solved densely per stencil.
/// Returns false (P unchanged: the caller keeps the orthogonal projection) where the
/// method does not apply: boundary vertices for kXu, stencils without faces for kLSCM.
bool ParametrizeStencil(FitMethod method, const Mesh& mesh, const Topology& topo, const int32_t* pts,
                        int n_pts, int first, const LocalFrame& frame, WlsProblem* P);

/// SolveWls with an SVD (Eigen::JacobiSVD) of the same weighted, radius- and column-scaled
/// Vandermonde matrix instead of QR: singular values below sigma_1 / cond_threshold[degree]
/// are dropped (the truncated SVD of 2.4). The oscillation safeguard is not applied.
/// Same outputs as SolveWls; `degree_used` stays the requested degree unless the rank
/// falls below the degree-1 columns.
WlsSolution SolveWlsSvd(const WlsProblem& problem, const WlsSettings& settings, double* coefficients,
                        double* op = nullptr);

}  // namespace geomfit
