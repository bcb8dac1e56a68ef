#pragma once
// Sparse linear solvers for time stepping: the pattern of the system stays the same from
// step to step (topology is fixed), so the symbolic analysis (ordering, elimination tree)
// is done once and only the numeric factorization is repeated.
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/SparseCore>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/linalg/amg.h"

namespace geomfit {

enum class SolverKind {
  kAuto,      ///< the caller's choice for its systems (SparseSolver itself: SparseLU)
  kSparseLU,  ///< Eigen's supernodal SparseLU (COLAMD ordering); always available
  kUmfpack,   ///< SuiteSparse UMFPACK through Eigen's UmfPackLU (libsuitesparse-dev)
  kKlu,       ///< SuiteSparse KLU through Eigen's KLU (libsuitesparse-dev)
  kBiCGSTAB,  ///< BiCGSTAB, warm-started from the previous solution (see Preconditioner)
};
/// BiCGSTAB's preconditioner. kDiagonal and kAmg run SolveBicgstab below (serial
/// products); kIlut Eigen's BiCGSTAB.
enum class Preconditioner {
  kDiagonal,  ///< Jacobi: cheapest; enough for (I - dt K) at moderate dt |K|
  kIlut,      ///< incomplete LU with thresholding (ilut_drop, ilut_fill)
  /// One V-cycle of smoothed-aggregation AMG (amg.h, SolverOptions::amg): iterations
  /// nearly independent of n where Jacobi's grow like 1/h. The hierarchy is built once
  /// and kept across Factorize calls (only the finest operator is replaced) until a
  /// solve takes more than 1.5 x + 2 the iterations of the first solve after the build.
  kAmg,
  /// Jacobi while a solve converges within SolverOptions::jacobi_limit iterations; from
  /// the first solve that needs more, AMG for good (that solve goes on from Jacobi's
  /// iterate). Jacobi's iterations are cheap (~1/5 of an AMG one) but grow like 1/h:
  /// this keeps Jacobi where it is as fast (MCF at 10k vertices: 12 iterations) and AMG
  /// where it wins (MCF at 100k / 1M: Jacobi 42 / 143, AMG 6 / 7; SD at 100k: 626 / 23)
  /// (bench/README.md, "Flows").
  kAuto,
};
const char* SolverKindName(SolverKind kind);
/// Parses "auto", "sparselu", "umfpack", "klu", "bicgstab".
absl::StatusOr<SolverKind> ParseSolverKind(const std::string& name);
/// Whether the build links the solver (UMFPACK and KLU need SuiteSparse).
bool SolverAvailable(SolverKind kind);

struct SolverOptions {
  /// kAuto lets the caller choose. Flows take BiCGSTAB, warm-started, with `preconditioner`
  /// (AMG by default; Jacobi with kDiagonal): for MCF on (I - dt K); for surface
  /// diffusion on the system reduced to the normal offsets, (I + dt B K) s = -dt B M,
  /// matrix-free, preconditioned by (I - c B)^2, c = sqrt(dt / 2) (AMG V-cycles), or
  /// with kDiagonal by Jacobi; when those do not converge within max_iterations, by the
  /// cotan square (I - c Lc)^2, c = sqrt(dt / 2) / 2, whose factorization is reused while
  /// it works (FlowStepper::Schur in flow.cc). Any other kind solves SD's 2n block system
  /// (ILUT for BiCGSTAB: Jacobi stalls there).
  /// GFD stencils of 25-40 points per row fill direct factorizations badly: MCF at 5768
  /// vertices solves in ~10 ms against ~1 s for SparseLU, UMFPACK or KLU; SD's block
  /// system at 10k vertices in ~0.7 s (ILUT) against 5 s for UMFPACK, the best direct
  /// one (bench/README.md, "Flows").
  SolverKind kind = SolverKind::kAuto;
  double tolerance = 1e-12;   ///< BiCGSTAB relative residual
  int max_iterations = 1000;  ///< BiCGSTAB
  Preconditioner preconditioner = Preconditioner::kAuto;
  /// Preconditioner::kAuto: a Jacobi iteration costs ~1/5 of an AMG one, and AMG needs
  /// ~4-7 on the flows' warm-started systems: Jacobi pays while it needs up to ~30.
  int jacobi_limit = 30;
  double ilut_drop = 1e-3;    ///< ILUT drop tolerance
  int ilut_fill = 5;          ///< ILUT fill factor (5, 1e-3: 1.5x faster SD steps than 20, 1e-4)
  /// UMFPACK's iterative refinement steps per solve (its default 2); 0 for a
  /// preconditioner, where each solve need not be exact.
  int umfpack_refinement = 2;
  /// UMFPACK's fill-reducing ordering: METIS nested dissection instead of its default
  /// (AMD / COLAMD); less fill on large surface meshes (bench/README.md, "Membranes").
  bool umfpack_metis = false;
  AmgOptions amg;  ///< Preconditioner::kAmg
};
absl::Status ValidateSolverOptions(const SolverOptions& o);

/// Solves A x = b for a sequence of matrices with one sparsity pattern. Row-major input
/// (the operators' CSR) is converted to the column-major form the factorizations take.
class SparseSolver {
 public:
  using Matrix = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

  explicit SparseSolver(const SolverOptions& options = SolverOptions());
  ~SparseSolver();
  SparseSolver(SparseSolver&&) noexcept;
  SparseSolver& operator=(SparseSolver&&) noexcept;

  /// Factorizes A (square). The symbolic analysis is redone only when A's pattern
  /// differs from the previous call's. FAILED_PRECONDITION if A is numerically singular;
  /// RESOURCE_EXHAUSTED when UMFPACK runs out of memory (too much fill).
  absl::Status Factorize(const Matrix& A);
  /// Solves with the last factorization; iterative solvers start from `*x` if it has the
  /// right size (warm start), else from zero.
  absl::Status Solve(const Eigen::VectorXd& b, Eigen::VectorXd* x);

  const SolverOptions& options() const { return options_; }
  /// Iterative solvers' relative residual from the next Solve on (> 0).
  void set_tolerance(double tolerance) { options_.tolerance = tolerance; }
  /// Symbolic analyses done so far (1 for a run with a fixed pattern).
  int analyses() const { return analyses_; }
  /// Iterations of the last solve (1 for direct solvers).
  int iterations() const { return iterations_; }
  /// AMG hierarchies built so far (Preconditioner::kAmg).
  int preconditioner_builds() const { return builds_; }

 private:
  struct Impl;
  /// Builds the AMG hierarchy of the current matrix, or refreshes its finest level.
  absl::Status RefreshAmg(bool rebuild);
  SolverOptions options_;
  std::unique_ptr<Impl> impl_;
  int analyses_ = 0;
  int iterations_ = 0;
  int builds_ = 0;
};

/// y = A x for an operator given only by its action (matrix-free); `*y` is resized.
using LinearMap = std::function<void(const Eigen::VectorXd& x, Eigen::VectorXd* y)>;

/// Right-preconditioned BiCGSTAB (van der Vorst; Eigen's variant, restarting when the
/// shadow residual turns orthogonal) for A x = b given as maps: `preconditioner` applies
/// an approximation of A^{-1}. Starts from `*x` when it has b's size (warm start), else
/// from zero; stops at ||b - A x|| <= tolerance ||b||. Returns the iterations;
/// FAILED_PRECONDITION when max_iterations pass first or the result is not finite.
absl::StatusOr<int> SolveBicgstab(const LinearMap& A, const LinearMap& preconditioner, const Eigen::VectorXd& b,
                                  Eigen::VectorXd* x, double tolerance, int max_iterations);

}  // namespace geomfit
