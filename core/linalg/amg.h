#pragma once
// Algebraic multigrid (smoothed aggregation; Vanek, Mandel, Brezina, Computing 56 (1996))
// as a preconditioner for sparse systems that behave like I - c Laplacian: the flows'
// (I - dt K) and the factors of surface diffusion's preconditioner. Generic: built from
// any square row-major matrix with a nonzero diagonal, applied as one V-cycle.
//
// Set-up: strength graph |a_ij| >= theta sqrt(|a_ii a_jj|) (symmetrized; every coupling
// when that stalls the coarsening), greedy aggregation (seed + strong neighbours; leftovers
// join a neighbouring aggregate), tentative prolongator T (piecewise constants), smoothed
// P = (I - w D^{-1} A) T with w = 4 / (3 rho(D^{-1} A)), restriction R = P^T, Galerkin
// coarse operators R A P, a dense LU at the coarsest level. Cycle: Gauss-Seidel (forward
// before, backward after the coarse correction) or damped Jacobi. D is the diagonal,
// except in rows where it is small against the couplings (|a_ii| < sum_j |a_ij| / 2: the
// GFD stencils of valence-3 vertices and of the odd ill-conditioned stencil have a_ii ~ 0
// or < 0), which take the l1 diagonal |a_ii| + sum_j |a_ij| (plain D made the V-cycle
// diverge there). At the finest level such a row's local mode needs more than that: after
// the pre-smoothing and before the post-smoothing each is relaxed by an exact solve of A
// on its stencil's unknowns (a multiplicative Schwarz step; without it the V-cycle
// diverged on the 1M-vertex cubed sphere, bench/README.md). Every loop is serial: the
// preconditioner runs inside a Krylov iteration whose products are serial too (parallel
// loops meeting several times per iteration lose badly on a loaded machine;
// bench/README.md, "Flows").
#include <memory>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "absl/status/status.h"
#include "core/util/run_context.h"

namespace geomfit {

enum class AmgSmoother {
  kGaussSeidel,  ///< forward sweeps before the coarse correction, backward after
  kJacobi,       ///< damped (AmgOptions::jacobi_weight)
};

struct AmgOptions {
  double strength = 0.08;           ///< theta of the strength graph, [0, 1)
  bool smooth_prolongator = true;   ///< false: plain aggregation (P = T; cheaper cycles, not scalable)
  AmgSmoother smoother = AmgSmoother::kGaussSeidel;
  double jacobi_weight = 0.6;       ///< damping of the Jacobi smoother
  int sweeps = 1;                   ///< smoothing sweeps before and after the coarse correction
  int coarse_size = 400;            ///< the coarsest level: at most this many rows (dense LU)
  int max_levels = 20;
};
absl::Status ValidateAmgOptions(const AmgOptions& o);

/// y = A x with a serial loop over A's rows (Eigen's product of a row-major matrix is
/// OpenMP-parallel); `*y` is resized.
void MultiplySerial(const Eigen::SparseMatrix<double, Eigen::RowMajor, int>& A, const Eigen::VectorXd& x,
                    Eigen::VectorXd* y);

/// Whether a hierarchy kept across a sequence of matrices (time steps) should be rebuilt:
/// a solve took more than 1.5 x + 2 the iterations of the first solve after its build
/// (`iterations_at_build` < 0: no baseline yet).
inline bool AmgHierarchyStale(int iterations, int iterations_at_build) {
  return iterations_at_build >= 0 && iterations > 1.5 * iterations_at_build + 2;
}

/// An AMG hierarchy for one matrix. Not thread-safe: the cycle uses work vectors.
class Amg {
 public:
  using Matrix = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

  Amg();
  ~Amg();
  Amg(Amg&&) noexcept;
  Amg& operator=(Amg&&) noexcept;

  /// Builds the hierarchy of A (square, nonzero diagonal). INVALID_ARGUMENT for a bad
  /// matrix or options; FAILED_PRECONDITION when the coarsest operator is singular;
  /// polls ctx between the set-up's phases (CANCELLED / DEADLINE_EXCEEDED). On any
  /// error the hierarchy is left empty (built() false).
  absl::Status Build(const Matrix& A, const AmgOptions& options = AmgOptions(),
                     const RunContext& ctx = RunContext());
  /// Replaces the finest operator (same size; e.g. the next time step's) and keeps the
  /// coarse levels: the cycle smooths with the new matrix and corrects with the old
  /// coarse operators, a good preconditioner while the matrix changes little.
  absl::Status UpdateFinest(const Matrix& A);

  /// x = V-cycle(b) from a zero initial guess: an approximation of A^{-1} b, linear in b.
  void Apply(const Eigen::VectorXd& b, Eigen::VectorXd* x) const;

  bool built() const { return !levels_.empty(); }
  int num_levels() const { return static_cast<int>(levels_.size()); }
  int rows(int level) const;
  /// Sum of the levels' nonzeros over the finest one's.
  double operator_complexity() const;

 private:
  struct Level;
  absl::Status BuildLevels(const Matrix& A, const AmgOptions& options, const RunContext& ctx);
  void Cycle(int level, const Eigen::VectorXd& b, Eigen::VectorXd* x) const;
  /// One sweep; `from_zero`: x is zero (a forward Gauss-Seidel sweep then skips the upper part).
  void Smooth(const Level& l, const Eigen::VectorXd& b, Eigen::VectorXd* x, bool forward, bool from_zero) const;
  /// Solves each patch's local problem in turn (see BuildPatches in amg.cc); `r`, when
  /// given, is b - A x on entry and kept so.
  void SolvePatches(const Level& l, const Eigen::VectorXd& b, Eigen::VectorXd* x, Eigen::VectorXd* r) const;

  AmgOptions options_;
  std::vector<std::unique_ptr<Level>> levels_;
};

}  // namespace geomfit
