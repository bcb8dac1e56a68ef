#pragma once
// The pressure-load problem of §6.4.2, eq. (6.4.1): find the deformed positions y of a
// membrane (reference x, material E, nu) on which the stress balances a pressure jump
// [p] (inside minus outside, a constant or per vertex, carried by the vertices):
//   div sigma(y) + [p] n(y) = 0   at every vertex
// (the text's div sigma = [p] n with the project's outward normal, so that n . div sigma
// = -tr(W tau^) = -[p]: the balloon r0 -> r1 of (6.3.4) solves it).
//
// Newton (the text's Picard iteration from phi = 0 leaves the linearization of grad phi^T
// grad phi open): the residual at vertex i depends on y only through first and second
// derivatives of y at i taken over i's reference stencil, so the Jacobian has the
// neighbourhood pattern in 3 x 3 blocks; the local 3 x 15 derivative of the residual is
// exact (forward-mode automatic differentiation of core/mechanics/membrane_kernel.h), the
// global one its product with the stencil blocks (an analytic Jacobian, no coloring).
// Derivatives of the displacement phi = y - x: tangential part T_k phi_k by the plain
// stencil; the normal part w n by the product rule, (dw) n_i + w_i dn with dn the stencil
// derivatives of the reference normals. The plain stencil of w_k n_k sees w only at the
// neighbours (x_a . n_i = 0): odd-even modes of w then cost almost no strain, and the
// Jacobian had near-null modes (smallest non-rigid singular value 0.55 / 0.15 at 218 / 866
// vertices against ~450 for the breathing mode, falling like h^2) on which Newton stalled;
// with the product rule it is 82 / 51. Start: every vertex moved along its normal to the
// balloon radius of its mean curvature (exact on a sphere; a membrane in tension elsewhere).
// Steps: backtracking on |F|; a step that does not descend is retried with diagonal
// (Levenberg-Marquardt) damping.
// Rigid modes: on a closed surface the six rigid motions are removed by a bordered system
//   [ J  C ] [dy]   [ -(R + C lambda) ]        C: translations and rotations about the
//   [ C^T 0 ] [dl] = [ -C^T (y - x)    ]        reference centroid (3n x 6)
// i.e. the mean displacement and the mean rotation (sum (x_i - c) x phi_i) are zero and
// six multipliers absorb the discrete net force and torque (O(h^{d-1})). On an open
// surface the boundary vertices are clamped (y_i = x_i), or free: a traction-free edge,
// the natural boundary condition sigma m = 0 (m the deformed outward conormal). With
// sigma = y_a S^ab y_b^T and m . y_b proportional to N_b = x_b . M (M the reference
// outward conormal: a pushed-forward edge keeps its normal covector) it reads
// y_a S^ab N_b = 0, two tangential equations that replace the tangential part of the
// vertex's equilibrium (its normal part n . (div sigma + [p] n) = 0 stays), scaled by
// 1/h against it. Nothing is held then, so the six rigid modes are removed by the
// border as on a closed surface. Check: an open cylinder with free ends under [p]
// expands uniaxially, hoop stretch l with p = E (l^2 - 1)/(2 l) and axial stretch
// sqrt(1 - nu (l^2 - 1)) (zero axial stress). Linear systems: a sparse direct
// solver (core/linalg: UMFPACK with METIS ordering when linked, else SparseLU), the
// factorization kept across Newton iterations by the chord rule, the symbolic analysis
// reused; or GMRES (PressureSolveOptions::krylov). Load stepping: when Newton does not converge
// at the full load, the load is approached in steps halved on failure and doubled after
// success.
#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "absl/status/statusor.h"
#include "core/fitting/options.h"
#include "core/linalg/sparse_solver.h"
#include "core/mechanics/membrane.h"
#include "core/mesh/mesh.h"
#include "core/mesh/topology.h"
#include "core/util/run_context.h"

namespace geomfit {

/// Boundary vertices of an open membrane. No default: an open mesh needs one.
enum class BoundaryCondition {
  kUnset,    ///< closed surfaces only (an open mesh is INVALID_ARGUMENT)
  kClamped,  ///< boundary vertices stay at their reference positions
  kFree,     ///< traction-free edges (natural condition sigma m = 0); rigid modes removed
};
const char* BoundaryConditionName(BoundaryCondition bc);

/// GMRES's preconditioner (PressureSolveOptions::krylov).
enum class KrylovPreconditioner {
  kOneRing,  ///< the Jacobian's 1-ring part (its entries between edge neighbours)
  /// The Jacobian of the same problem discretized on 1-ring stencils (degree-2 fits over
  /// each vertex's edge neighbours): a consistent approximation of the same operator, so
  /// GMRES's iterations stay nearly flat as the mesh is refined (the 1-ring part's double
  /// per 4x vertices); rows whose 1-ring fit drops below degree 2 take the 1-ring part.
  kCompact,
};

struct PressureSolveOptions {
  MembraneOptions material;  ///< E, nu (required)
  FitOptions fit = [] {      ///< reference fits (LHF); degree 4 by default
    FitOptions f;
    f.degree = 4;
    return f;
  }();
  BoundaryCondition boundary = BoundaryCondition::kUnset;
  double tolerance = 1e-10;   ///< on |F| / |[p] n| (2-norms over all vertices, full load)
  int max_iterations = 12;    ///< Newton iterations per load step
  int max_load_cuts = 6;      ///< halvings of the load step before giving up
  /// Chord (frozen-Jacobian) steps reuse the last factorization while each cuts the
  /// residual by this factor or more; 0 refactorizes every iteration (plain Newton).
  double chord_ratio = 0.1;
  /// kAuto: UMFPACK if linked, else SparseLU; UMFPACK with METIS's nested dissection
  /// (84,968 vertices at degree 2 in 20 s of one core, 2.6 GB, on OpenBLAS: the fastest
  /// option at every size measured, bench/README.md "Membranes"). BiCGSTAB + ILUT also
  /// converges (2x slower than UMFPACK at 5k vertices).
  SolverOptions solver = [] {
    SolverOptions s;
    s.umfpack_metis = true;  // 1.2x faster and 0.75x the memory of AMD at 20k vertices
    return s;
  }();
  /// Newton's linear solves. false: `solver` factorizes the Jacobian (one factorization
  /// per load step here, kept by the chord rule). true: restarted GMRES on the Jacobian
  /// (core/linalg/gmres.h), right-preconditioned by `solver`'s factorization of a sparser
  /// matrix (`krylov_preconditioner`) followed by `krylov_smoothing` block Gauss-Seidel
  /// sweeps on the Jacobian (inexact Newton, Eisenstat-Walker forcing). The Jacobian is
  /// re-evaluated every iteration (assembly is cheap); the preconditioner's factorization
  /// is kept through the load step. Slower than the direct solve at every size
  /// measured (its iterations grow ~2.5-4x per 4x vertices), kept for comparison.
  bool krylov = false;
  KrylovPreconditioner krylov_preconditioner = KrylovPreconditioner::kCompact;
  /// Eisenstat-Walker forcing terms: each GMRES solve to eta_k = 0.9 (|F_k| / |F_k-1|)^2
  /// (krylov_forcing_max for the first), capped by krylov_forcing_max and never tighter
  /// than the Newton tolerance needs; false: every solve to krylov_tolerance.
  bool krylov_forcing = true;
  double krylov_forcing_max = 1e-2;
  double krylov_tolerance = 1e-6;
  int krylov_max_iterations = 300;
  int krylov_restart = 100;  ///< GMRES's Krylov dimension per cycle (85k: ~200 per solve)
  /// Symmetric block (3 x 3) Gauss-Seidel sweeps on the Jacobian after each preconditioner
  /// solve (multiplicative: they correct what the sparser matrix misses); 1 sweep cuts the
  /// iterations 2.5x at 5k-20k vertices.
  int krylov_smoothing = 1;
};
absl::Status ValidatePressureSolveOptions(const PressureSolveOptions& o);
/// Sets the linear solver by name: "auto", "sparselu", "umfpack", "klu", "bicgstab"
/// (with ILUT) factorize or iterate on the Jacobian; "gmres" sets `krylov` with UMFPACK
/// (else SparseLU) for the preconditioner. INVALID_ARGUMENT naming `solver` otherwise.
absl::Status SetPressureSolver(const std::string& name, PressureSolveOptions* o);

/// One Newton iteration (also the callback's argument).
struct NewtonIteration {
  int load_step = 0;       ///< 0-based load step
  double load = 1;         ///< fraction of the pressure of this step
  int iteration = 0;       ///< 1-based within the load step
  double residual = 0;     ///< |F| / |[p] n| after the iteration
  double step = 0;         ///< max_i |dy_i| of the iteration
  int krylov_iterations = 0;  ///< GMRES iterations of the iteration's solve (krylov)
};
using NewtonCallback = std::function<void(const NewtonIteration&)>;

struct PressureSolution {
  Positions deformed;      ///< y
  Positions displacement;  ///< y - x
  std::vector<NewtonIteration> history;
  double residual = 0;     ///< final relative residual
  int factorizations = 0;
  int load_steps = 0;
  int krylov_iterations = 0;  ///< GMRES iterations in all (krylov)
  /// The direct factorization ran out of memory and GMRES took over (see `krylov`).
  bool fell_back_to_krylov = false;
  double precondition_ms = 0;  ///< of solve_ms: the preconditioner's solves (krylov)
  double fit_ms = 0, assemble_ms = 0, factorize_ms = 0, solve_ms = 0;
};

/// Solves (6.4.1) for `reference` under `pressure` (1 value, or one per vertex).
/// Errors: INVALID_ARGUMENT for bad options, a pressure of the wrong length or not
/// finite, an open mesh without `boundary`;
/// FAILED_PRECONDITION when Newton does not converge (the message holds the residual
/// history); RESOURCE_EXHAUSTED when GMRES's preconditioner does not fit in memory
/// either (a direct factorization that does not hands over to GMRES); CANCELLED /
/// DEADLINE_EXCEEDED from `ctx` (polled every iteration).
absl::StatusOr<PressureSolution> SolvePressureLoad(const Mesh& reference, const Topology& topo,
                                                   const Eigen::VectorXd& pressure,
                                                   const PressureSolveOptions& options,
                                                   const RunContext& ctx = RunContext(),
                                                   const NewtonCallback& on_iteration = nullptr);

}  // namespace geomfit
