#pragma once
// Geometric flows of closed surfaces by GFD (§5.2-5.3), refitting every step on a fixed
// topology. Conventions: outward normals n, H = (k1 + k2)/2 (+1/R on a sphere), M = -H
// (the text's (5.2.5)).
//   mean-curvature flow   x_t = M n = -H n          (sphere: R(t)^2 = R0^2 - 2t)
//   surface diffusion     x_t = (Laplace-Beltrami H) n   (the sign (5.2.7) should have:
//                         volume conserved, area decreasing)
// Schemes: explicit Euler (5.2.6); semi-implicit (5.3.2)-(5.3.7) with motion along the
// step-n normals, solved in the normal offsets s (x^{n+1} = x^n + s n^n): MCF
// (I - dt K) s = dt M^n, SD [[I, dt B], [-K, I]] [s; mu] = [0; M^n] (by default reduced
// to (I + dt B K) s = -dt B M^n, matrix-free BiCGSTAB preconditioned by AMG V-cycles on
// (I - c B)^2, c = sqrt(dt / 2)); and linearly
// implicit BDF2 (frames, first derivatives and normals from 2x^n - x^{n-1}, one
// semi-implicit start step). K_ij = L_ij (n_j . m_i) with L the second-derivative stencil
// of eq. (5.3.6) / (2 l^3), B the Laplace-Beltrami matrix (5.1.18).
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/fitting/options.h"
#include "core/linalg/sparse_solver.h"
#include "core/mesh/mesh.h"
#include "core/mesh/topology.h"
#include "core/operators/operators.h"
#include "core/util/run_context.h"

namespace geomfit {

enum class FlowKind { kMeanCurvature, kSurfaceDiffusion };
enum class FlowScheme { kExplicit, kSemiImplicit, kBdf2 };
const char* FlowKindName(FlowKind kind);      ///< "mcf", "surface_diffusion"
const char* FlowSchemeName(FlowScheme s);     ///< "explicit", "semi_implicit", "bdf2"
absl::StatusOr<FlowKind> ParseFlowKind(const std::string& name);
absl::StatusOr<FlowScheme> ParseFlowScheme(const std::string& name);

/// The fit a flow uses unless told otherwise: LHF, degree 4 (Table 5.1) on compact
/// stencils: 1.5 rings grown to 1.1 x the coefficients (17 points at degree 4). The
/// text's Table 5.1 matches these (368 vertices: 1.40e-4, 1.68e-4 in the text); the
/// fitting default (2.5 rings, 1.5 x) gives 2.53e-4: the mean curvature's truncation
/// error is a bias of one sign that the 50 steps accumulate, and it grows with the
/// stencil's radius (bench/README.md, "Flows").
FitOptions DefaultFlowFitOptions();

struct FlowOptions {
  FlowKind kind = FlowKind::kMeanCurvature;
  FlowScheme scheme = FlowScheme::kSemiImplicit;
  double dt = 1e-3;          ///< time step, > 0
  int steps = 0;             ///< steps RunFlow takes; 0: until end_time
  double end_time = 0;       ///< when steps == 0, RunFlow takes ceil(end_time / dt) full steps
  FitOptions fit = DefaultFlowFitOptions();  ///< must be LHF
  SolverOptions solver;
  /// Iterative solves need not be more exact than the step itself: from the third step
  /// on they stop at the relative residual
  ///   clamp(time_tolerance * |d| / |s|, solver.tolerance, 1e-4),
  /// s the last step's normal offsets and d their first difference over the last two
  /// steps (~dt^2 x_tt, the first-order schemes' local error) or, for BDF2, their second
  /// difference (~dt^3, BDF2's). At 1e-3 the solve's error stays ~1000x below the step's
  /// truncation error; MCF at dt = 1e-3 then solves to ~1e-6 (BDF2 ~1e-9) instead of
  /// 1e-12 (bench/README.md, "Flows"). 0: solver.tolerance always.
  double time_tolerance = 1e-3;
  /// Blow-up check: a face whose normal turns by more than this in one step (degrees,
  /// (0, 180]) means the surface folded (inverted normals).
  double max_face_turn_deg = 90;
};
/// OK, or INVALID_ARGUMENT naming the field.
absl::Status ValidateFlowOptions(const FlowOptions& options);

/// Per-step report.
struct StepStats {
  int step = 0;            ///< 1 for the first step
  double t = 0;            ///< time after the step
  double area = 0;         ///< flat-face area after the step
  double volume = 0;       ///< enclosed volume (flat faces, divergence theorem)
  double max_speed = 0;    ///< max |x^{n+1} - x^n| / dt
  int solver_iterations = 0;
  double fit_ms = 0, assemble_ms = 0, solve_ms = 0;
};

/// Flat-face area and enclosed volume (quads split along a diagonal).
double MeshArea(const Mesh& mesh);
double MeshVolume(const Mesh& mesh);

/// A flow in progress: positions (current and previous level), the topology, the
/// operator pattern and the solver's symbolic analysis, all reused step after step.
class FlowStepper {
 public:
  /// Validates options and mesh (closed: flows take no boundary conditions).
  static absl::StatusOr<std::unique_ptr<FlowStepper>> Create(const Mesh& mesh, const FlowOptions& options,
                                                             const RunContext& ctx = RunContext());

  /// Advances one step of options().dt. On error (cancelled, blow-up: non-finite
  /// positions or folded faces, solver failure) the state is left at the last good step
  /// and the message names the step.
  absl::StatusOr<StepStats> Step(const RunContext& ctx = RunContext());

  /// The linearized normal velocity of MCF at the current positions: the n x n matrix
  /// K of (I - dt K) s = dt M (explicit Euler is stable for dt < 2 / max |eig K|).
  absl::StatusOr<SparseMatrix> CurvatureJacobian(const RunContext& ctx = RunContext());

  const Mesh& mesh() const { return mesh_; }
  const Topology& topology() const { return topo_; }
  const FlowOptions& options() const { return options_; }
  double time() const { return steps_ * options_.dt; }
  int steps_taken() const { return steps_; }
  const SparseSolver& solver() const { return solver_; }
  /// Surface diffusion with the default solver: cotan preconditioner factorizations so
  /// far (0 while AMG or Jacobi suffices; 1 for a run whose geometry changes slowly).
  int preconditioner_factorizations() const;
  /// AMG hierarchies built so far (MCF's system or SD's reduced one; 1 for a run whose
  /// geometry changes slowly).
  int preconditioner_builds() const;

  ~FlowStepper();

 private:
  FlowStepper();
  struct Curvature;  // per-step linearization, see flow.cc
  struct Schur;      // surface diffusion's reduced system, see flow.cc
  absl::Status Linearize(const Mesh& fit_mesh, const Positions& base, const RunContext& ctx, Curvature* c,
                         double* fit_ms);
  /// Surface diffusion's semi-implicit system reduced to s: (I + a B K) s = -a B M.
  absl::StatusOr<int> SolveSchur(const Mesh& geometry, const Eigen::VectorXd& mean, double adt,
                                 double tolerance, const RunContext& ctx, Eigen::VectorXd* s);
  /// The relative residual this step's solve stops at (FlowOptions::time_tolerance).
  double SolveTolerance() const;

  FlowOptions options_;
  Mesh mesh_;            // current positions
  Positions previous_;   // positions one step back (BDF2)
  Topology topo_;
  std::shared_ptr<const Neighborhoods> nb_;
  std::unique_ptr<OperatorAssembler> assembler_;
  SparseMatrix K_, B_, system_;
  SparseSolver solver_;
  Eigen::VectorXd solution_;  // the last solve's, a warm start for the next
  std::vector<Eigen::VectorXd> offsets_;  // the last steps' normal offsets s, newest last (at most 3)
  std::unique_ptr<Schur> schur_;  // set for surface diffusion with SolverKind::kAuto
  int steps_ = 0;
};

struct FlowResult {
  Mesh mesh;                     ///< the last good positions
  std::vector<StepStats> steps;  ///< one per step taken
};

/// Runs options.steps steps (or up to options.end_time). `on_step` (optional) sees each
/// step's stats and mesh; a non-OK status from it stops the run with that status.
/// Reports progress ("flow", steps done, steps total) and polls `ctx` every step. On
/// error `result` still holds the last good mesh and the steps taken.
absl::Status RunFlow(const Mesh& mesh, const FlowOptions& options, const RunContext& ctx, FlowResult* result,
                     const std::function<absl::Status(const StepStats&, const Mesh&)>& on_step = nullptr);

}  // namespace geomfit
