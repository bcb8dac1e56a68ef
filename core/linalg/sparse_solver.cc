#include "core/linalg/sparse_solver.h"

#include <cstring>

#include <Eigen/IterativeLinearSolvers>
#include <Eigen/SparseLU>
#ifdef GEOMFIT_HAVE_SUITESPARSE
#include <Eigen/KLUSupport>
#include <Eigen/UmfPackSupport>
#endif

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/util/status_macros.h"

namespace geomfit {

using ColMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

const char* SolverKindName(SolverKind kind) {
  switch (kind) {
    case SolverKind::kAuto: return "auto";
    case SolverKind::kSparseLU: return "sparselu";
    case SolverKind::kUmfpack: return "umfpack";
    case SolverKind::kKlu: return "klu";
    case SolverKind::kBiCGSTAB: return "bicgstab";
  }
  return "unknown";
}

absl::StatusOr<SolverKind> ParseSolverKind(const std::string& name) {
  for (SolverKind k : {SolverKind::kAuto, SolverKind::kSparseLU, SolverKind::kUmfpack, SolverKind::kKlu,
                       SolverKind::kBiCGSTAB})
    if (name == SolverKindName(k)) return k;
  return absl::InvalidArgumentError(
      absl::StrCat("solver: unknown '", name, "' (auto, sparselu, umfpack, klu, bicgstab)"));
}

bool SolverAvailable(SolverKind kind) {
#ifdef GEOMFIT_HAVE_SUITESPARSE
  (void)kind;
  return true;
#else
  return kind == SolverKind::kAuto || kind == SolverKind::kSparseLU || kind == SolverKind::kBiCGSTAB;
#endif
}

absl::Status ValidateSolverOptions(const SolverOptions& o) {
  if (!SolverAvailable(o.kind))
    return absl::InvalidArgumentError(
        absl::StrCat("solver: ", SolverKindName(o.kind), " is not available in this build (needs SuiteSparse)"));
  if (!(o.tolerance > 0 && o.tolerance < 1))
    return absl::InvalidArgumentError(absl::StrFormat("solver.tolerance %g is out of range (0, 1)", o.tolerance));
  if (o.max_iterations < 1)
    return absl::InvalidArgumentError(absl::StrFormat("solver.max_iterations %d must be >= 1", o.max_iterations));
  if (!(o.ilut_drop >= 0) || o.ilut_fill < 1)
    return absl::InvalidArgumentError("solver.ilut_drop must be >= 0 and solver.ilut_fill >= 1");
  if (o.umfpack_refinement < 0) return absl::InvalidArgumentError("solver.umfpack_refinement must be >= 0");
  if (o.jacobi_limit < 1) return absl::InvalidArgumentError("solver.jacobi_limit must be >= 1");
  if (o.preconditioner == Preconditioner::kAmg || o.preconditioner == Preconditioner::kAuto) {
    if (absl::Status s = ValidateAmgOptions(o.amg); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat("solver.", s.message()));
  }
  return absl::OkStatus();
}

struct SparseSolver::Impl {
  ColMatrix A;
  // Jacobi and AMG: our BiCGSTAB on the row-major matrix with a serial product.
  SparseSolver::Matrix rows;
  Eigen::VectorXd inverse_diagonal;
  Amg amg;
  bool use_amg = false;  // kAmg, or kAuto once Jacobi needed more than jacobi_limit
  bool amg_stale = true;
  int iterations_at_build = -1;
  std::vector<int> outer, inner;  // pattern of the last analysis
  Eigen::SparseLU<ColMatrix, Eigen::COLAMDOrdering<int>> lu;
  Eigen::BiCGSTAB<ColMatrix, Eigen::IncompleteLUT<double, int>> bicgstab_ilut;
  Eigen::BiCGSTAB<ColMatrix, Eigen::DiagonalPreconditioner<double>> bicgstab_diag;
  // Factorizes (preconditioner set-up) or solves with the chosen BiCGSTAB.
  template <typename Fn>
  auto WithBicgstab(const SolverOptions& o, Fn&& fn) {
    return o.preconditioner == Preconditioner::kIlut ? fn(bicgstab_ilut) : fn(bicgstab_diag);
  }
  bool OwnBicgstab(const SolverOptions& o) const {
    return o.kind == SolverKind::kBiCGSTAB && o.preconditioner != Preconditioner::kIlut;
  }
#ifdef GEOMFIT_HAVE_SUITESPARSE
  Eigen::UmfPackLU<ColMatrix> umfpack;
  Eigen::KLU<ColMatrix> klu;
#endif
  bool SamePattern() const {
    const size_t no = A.outerSize() + 1, ni = A.nonZeros();
    return outer.size() == no && inner.size() == ni &&
           std::memcmp(outer.data(), A.outerIndexPtr(), no * sizeof(int)) == 0 &&
           std::memcmp(inner.data(), A.innerIndexPtr(), ni * sizeof(int)) == 0;
  }
};

SparseSolver::SparseSolver(const SolverOptions& options) : options_(options), impl_(std::make_unique<Impl>()) {
  if (options_.kind == SolverKind::kAuto) options_.kind = SolverKind::kSparseLU;
}
SparseSolver::~SparseSolver() = default;
SparseSolver::SparseSolver(SparseSolver&&) noexcept = default;
SparseSolver& SparseSolver::operator=(SparseSolver&&) noexcept = default;

absl::Status SparseSolver::Factorize(const Matrix& A) {
  if (A.rows() != A.cols()) return absl::InvalidArgumentError("the system matrix is not square");
  Impl& m = *impl_;
  if (m.OwnBicgstab(options_)) {
    const bool analyze = m.rows.rows() != A.rows() || m.rows.nonZeros() != A.nonZeros() ||
                         std::memcmp(m.rows.outerIndexPtr(), A.outerIndexPtr(), (A.rows() + 1) * sizeof(int)) != 0 ||
                         std::memcmp(m.rows.innerIndexPtr(), A.innerIndexPtr(), A.nonZeros() * sizeof(int)) != 0;
    m.rows = A;
    m.rows.makeCompressed();
    if (analyze) ++analyses_;
    m.inverse_diagonal = m.rows.diagonal();
    for (Eigen::Index i = 0; i < m.inverse_diagonal.size(); ++i)
      m.inverse_diagonal(i) = m.inverse_diagonal(i) != 0 ? 1 / m.inverse_diagonal(i) : 1;  // Eigen's rule
    if (options_.preconditioner == Preconditioner::kAmg) m.use_amg = true;
    if (m.use_amg) return RefreshAmg(analyze);
    return absl::OkStatus();
  }
  m.A = A;
  m.A.makeCompressed();
  const bool analyze = !m.SamePattern();
  if (analyze) {
    m.outer.assign(m.A.outerIndexPtr(), m.A.outerIndexPtr() + m.A.outerSize() + 1);
    m.inner.assign(m.A.innerIndexPtr(), m.A.innerIndexPtr() + m.A.nonZeros());
    ++analyses_;
  }
  Eigen::ComputationInfo info = Eigen::Success;
  switch (options_.kind) {
    case SolverKind::kSparseLU:
      if (analyze) m.lu.analyzePattern(m.A);
      m.lu.factorize(m.A);
      info = m.lu.info();
      break;
    case SolverKind::kBiCGSTAB:
      m.bicgstab_ilut.preconditioner().setDroptol(options_.ilut_drop);
      m.bicgstab_ilut.preconditioner().setFillfactor(options_.ilut_fill);
      info = m.WithBicgstab(options_, [&](auto& solver) {
        solver.setTolerance(options_.tolerance);
        solver.setMaxIterations(options_.max_iterations);
        solver.compute(m.A);
        return solver.info();
      });
      break;
#ifdef GEOMFIT_HAVE_SUITESPARSE
    case SolverKind::kUmfpack:
      m.umfpack.umfpackControl()(UMFPACK_IRSTEP) = options_.umfpack_refinement;
      if (options_.umfpack_metis) m.umfpack.umfpackControl()(UMFPACK_ORDERING) = UMFPACK_ORDERING_METIS;
      if (analyze) m.umfpack.analyzePattern(m.A);
      if (m.umfpack.info() == Eigen::Success) m.umfpack.factorize(m.A);
      info = m.umfpack.info();
      // Out of memory (UMFPACK's int workspace: its estimate of the fill past 2^31 words)
      // is not a singular system: the caller may choose a sparser method.
      if (info != Eigen::Success && m.umfpack.umfpackFactorizeReturncode() == UMFPACK_ERROR_out_of_memory) {
        m.outer.clear();  // analyze again next time
        return absl::ResourceExhaustedError("umfpack: out of memory (the factorization's fill is too large)");
      }
      break;
    case SolverKind::kKlu:
      if (analyze) m.klu.analyzePattern(m.A);
      m.klu.factorize(m.A);
      info = m.klu.info();
      break;
#endif
    default:
      return ValidateSolverOptions(options_);
  }
  if (info != Eigen::Success)
    return absl::FailedPreconditionError(
        absl::StrCat(SolverKindName(options_.kind), ": factorization failed (singular or not finite system)"));
  return absl::OkStatus();
}

absl::Status SparseSolver::RefreshAmg(bool rebuild) {
  Impl& m = *impl_;
  if (rebuild || m.amg_stale || !m.amg.built()) {
    GF_RETURN_IF_ERROR(m.amg.Build(m.rows, options_.amg));
    m.amg_stale = false;
    m.iterations_at_build = -1;
    ++builds_;
    return absl::OkStatus();
  }
  return m.amg.UpdateFinest(m.rows);
}

absl::Status SparseSolver::Solve(const Eigen::VectorXd& b, Eigen::VectorXd* x) {
  Impl& m = *impl_;
  if (m.OwnBicgstab(options_)) {
    if (b.size() != m.rows.rows()) return absl::InvalidArgumentError("right-hand side size does not match the system");
    const LinearMap product = [&](const Eigen::VectorXd& u, Eigen::VectorXd* v) { MultiplySerial(m.rows, u, v); };
    const LinearMap jacobi = [&](const Eigen::VectorXd& u, Eigen::VectorXd* v) {
      *v = m.inverse_diagonal.cwiseProduct(u);
    };
    iterations_ = 0;
    if (!m.use_amg) {
      const bool adaptive = options_.preconditioner == Preconditioner::kAuto;
      const Eigen::VectorXd start = *x;
      const absl::StatusOr<int> it =
          SolveBicgstab(product, jacobi, b, x, options_.tolerance,
                        adaptive ? std::min(options_.jacobi_limit, options_.max_iterations) : options_.max_iterations);
      if (it.ok() || !adaptive) {
        if (it.ok()) iterations_ = *it;
        return it.status();
      }
      iterations_ = std::min(options_.jacobi_limit, options_.max_iterations);
      if (!x->allFinite()) *x = start;
      m.use_amg = true;  // Jacobi is too slow for these systems: AMG from now on
      GF_RETURN_IF_ERROR(RefreshAmg(true));
    }
    const absl::StatusOr<int> it =
        SolveBicgstab(product, [&](const Eigen::VectorXd& u, Eigen::VectorXd* v) { m.amg.Apply(u, v); }, b, x,
                      options_.tolerance, options_.max_iterations);
    if (!it.ok()) {
      m.amg_stale = true;
      return it.status();
    }
    // A solve that went on from Jacobi's iterate is no baseline for the hierarchy.
    const bool baseline = iterations_ == 0;
    iterations_ += *it;
    if (baseline && m.iterations_at_build < 0) {
      m.iterations_at_build = *it;
    } else if (AmgHierarchyStale(*it, m.iterations_at_build)) {
      m.amg_stale = true;
    }
    return absl::OkStatus();
  }
  if (b.size() != m.A.rows()) return absl::InvalidArgumentError("right-hand side size does not match the system");
  iterations_ = 1;
  Eigen::ComputationInfo info = Eigen::Success;
  switch (options_.kind) {
    case SolverKind::kSparseLU:
      *x = m.lu.solve(b);
      info = m.lu.info();
      break;
    case SolverKind::kBiCGSTAB:
      if (x->size() != b.size()) x->setZero(b.size());
      info = m.WithBicgstab(options_, [&](auto& solver) {
        *x = solver.solveWithGuess(b, *x);
        iterations_ = static_cast<int>(solver.iterations());
        return solver.info();
      });
      break;
#ifdef GEOMFIT_HAVE_SUITESPARSE
    case SolverKind::kUmfpack:
      *x = m.umfpack.solve(b);
      info = m.umfpack.info();
      break;
    case SolverKind::kKlu:
      *x = m.klu.solve(b);
      info = m.klu.info();
      break;
#endif
    default:
      return ValidateSolverOptions(options_);
  }
  if (info != Eigen::Success || !x->allFinite())
    return absl::FailedPreconditionError(absl::StrCat(SolverKindName(options_.kind), ": solve failed",
                                                      options_.kind == SolverKind::kBiCGSTAB
                                                          ? absl::StrFormat(" (no convergence in %d iterations)", iterations_)
                                                          : std::string()));
  return absl::OkStatus();
}

absl::StatusOr<int> SolveBicgstab(const LinearMap& A, const LinearMap& preconditioner, const Eigen::VectorXd& b,
                                  Eigen::VectorXd* x, double tolerance, int max_iterations) {
  const Eigen::Index n = b.size();
  if (x->size() != n) x->setZero(n);
  const double target = tolerance * b.norm();
  if (target == 0) {
    x->setZero();
    return 0;
  }
  Eigen::VectorXd r(n), ax(n), y(n), z(n), v = Eigen::VectorXd::Zero(n), p = Eigen::VectorXd::Zero(n), s(n), t(n);
  A(*x, &ax);
  r = b - ax;
  Eigen::VectorXd r0 = r;
  double rho = 1, alpha = 1, w = 1;
  const double eps2 = Eigen::NumTraits<double>::epsilon() * Eigen::NumTraits<double>::epsilon();
  int it = 0;
  for (; r.norm() > target; ++it) {
    if (it == max_iterations || !r.allFinite())
      return absl::FailedPreconditionError(
          absl::StrFormat("bicgstab: no convergence in %d iterations (relative residual %.2e)", it, r.norm() / b.norm()));
    const double rho_old = rho;
    rho = r0.dot(r);
    if (w == 0 || std::abs(rho) < eps2 * r0.squaredNorm()) {  // breakdown (w = 0, r0 . r = 0): restart
      r0 = r;
      rho = r.squaredNorm();
      p.setZero();
      v.setZero();
      alpha = w = 1;
    }
    const double beta = (rho / rho_old) * (alpha / w);
    p = r + beta * (p - w * v);
    preconditioner(p, &y);
    A(y, &v);
    alpha = rho / r0.dot(v);
    s = r - alpha * v;
    preconditioner(s, &z);
    A(z, &t);
    const double tt = t.squaredNorm();
    w = tt > 0 ? t.dot(s) / tt : 0;
    *x += alpha * y + w * z;
    r = s - w * t;
  }
  if (!x->allFinite()) return absl::FailedPreconditionError("bicgstab: the solution is not finite");
  return it;
}

}  // namespace geomfit
