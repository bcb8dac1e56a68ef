#include "core/flow/flow.h"

#include <algorithm>
#include <cmath>

#include <Eigen/SparseCholesky>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/fitting/frames.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"

namespace geomfit {
namespace {

constexpr int kUU = TaylorIndex(2, 0), kUV = TaylorIndex(1, 1), kVV = TaylorIndex(0, 2);

// Prefixes a step's errors with the step and time, keeping the code.
absl::Status AtStep(const absl::Status& s, int step, double t) {
  if (s.ok()) return s;
  return absl::Status(s.code(), absl::StrFormat("step %d (t = %g): %s", step, t, s.message()));
}

// Calls fn(a, b, c) for every triangle (quads split along the diagonal a-c).
template <typename Fn>
void ForEachTriangle(const Mesh& m, Fn&& fn) {
  for (int f = 0; f < m.NumFaces(); ++f) {
    const Eigen::Vector3d a = m.positions.row(m.faces(f, 0)), b = m.positions.row(m.faces(f, 1)),
                          c = m.positions.row(m.faces(f, 2));
    fn(a, b, c);
    if (m.FaceSize(f) == 4) fn(a, c, Eigen::Vector3d(m.positions.row(m.faces(f, 3))));
  }
}

// y = A x; y is NaN once ctx trips (so that an iterative solve stops). A plain serial
// loop: parallel products (ParallelFor, or Eigen's OpenMP one for row-major A) make
// threads meet 4 times per BiCGSTAB iteration, which on a loaded machine cost 40-50x
// (SD at 10k vertices: 7.4-8.3 s against 0.17 s per solve).
void Multiply(const SparseMatrix& A, const Eigen::VectorXd& x, Eigen::VectorXd* y, const RunContext& ctx) {
  MultiplySerial(A, x, y);
  if (ctx.cancelled()) y->setConstant(std::nan(""));
}

}  // namespace

const char* FlowKindName(FlowKind kind) {
  return kind == FlowKind::kMeanCurvature ? "mcf" : "surface_diffusion";
}
const char* FlowSchemeName(FlowScheme s) {
  switch (s) {
    case FlowScheme::kExplicit: return "explicit";
    case FlowScheme::kSemiImplicit: return "semi_implicit";
    case FlowScheme::kBdf2: return "bdf2";
  }
  return "unknown";
}
absl::StatusOr<FlowKind> ParseFlowKind(const std::string& name) {
  for (FlowKind k : {FlowKind::kMeanCurvature, FlowKind::kSurfaceDiffusion})
    if (name == FlowKindName(k)) return k;
  return absl::InvalidArgumentError(absl::StrCat("kind: unknown flow '", name, "' (mcf, surface_diffusion)"));
}
absl::StatusOr<FlowScheme> ParseFlowScheme(const std::string& name) {
  for (FlowScheme s : {FlowScheme::kExplicit, FlowScheme::kSemiImplicit, FlowScheme::kBdf2})
    if (name == FlowSchemeName(s)) return s;
  return absl::InvalidArgumentError(
      absl::StrCat("scheme: unknown '", name, "' (explicit, semi_implicit, bdf2)"));
}

FitOptions DefaultFlowFitOptions() {
  FitOptions o;
  o.degree = 4;
  o.rings = 1.5;
  o.min_points_factor = 1.1;
  return o;
}

absl::Status ValidateFlowOptions(const FlowOptions& o) {
  if (!(std::isfinite(o.dt) && o.dt > 0)) return absl::InvalidArgumentError(absl::StrFormat("dt %g must be > 0", o.dt));
  if (o.steps < 0) return absl::InvalidArgumentError(absl::StrFormat("steps %d must be >= 0", o.steps));
  if (!(std::isfinite(o.end_time) && o.end_time >= 0))
    return absl::InvalidArgumentError(absl::StrFormat("end_time %g must be >= 0", o.end_time));
  if (!(o.max_face_turn_deg > 0 && o.max_face_turn_deg <= 180))
    return absl::InvalidArgumentError(
        absl::StrFormat("max_face_turn_deg %g is out of range (0, 180]", o.max_face_turn_deg));
  if (!(std::isfinite(o.time_tolerance) && o.time_tolerance >= 0))
    return absl::InvalidArgumentError(absl::StrFormat("time_tolerance %g must be >= 0", o.time_tolerance));
  if (o.fit.method != FitMethod::kLHF) return absl::InvalidArgumentError("fit.method: flows need LHF fits");
  if (absl::Status s = ValidateFitOptions(o.fit); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("fit: ", s.message()));
  return ValidateSolverOptions(o.solver);
}

double MeshArea(const Mesh& mesh) {
  double a = 0;
  ForEachTriangle(mesh, [&](const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& r) {
    a += 0.5 * (q - p).cross(r - p).norm();
  });
  return a;
}

double MeshVolume(const Mesh& mesh) {
  double v = 0;
  ForEachTriangle(mesh, [&](const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& r) {
    v += p.dot(q.cross(r)) / 6;
  });
  return v;
}

// The linearization of one step: fits at the geometry positions, fitted outward
// normals n_i, and M at the base positions, M_i = sum_k L_ik (b_{p_k} . m_i) (5.3.6).
// K_ (same pattern as the Laplace-Beltrami matrix) gets L_ik (n_{p_k} . m_i).
struct FlowStepper::Curvature {
  std::shared_ptr<const SurfaceFits> fits;
  Positions normals;
  Eigen::VectorXd mean;
};

absl::Status FlowStepper::Linearize(const Mesh& fit_mesh, const Positions& base, const RunContext& ctx,
                                    Curvature* c, double* fit_ms) {
  const Stopwatch fit_watch;
  GF_ASSIGN_OR_RETURN(c->fits, FitForOperators(fit_mesh, topo_, options_.fit, nb_, ctx));
  *fit_ms = fit_watch.Millis();
  const SurfaceFits& fits = *c->fits;
  const int nv = mesh_.NumVertices();
  c->normals.resize(nv, 3);
  c->mean.resize(nv);
  GF_RETURN_IF_ERROR(ParallelFor(nv, ctx, [&](int64_t i) {
    c->normals.row(i) = HeightGeometryAt(fits, static_cast<int>(i)).normal.transpose();
  }, 2048));
  if (K_.rows() != nv) K_ = assembler_->Pattern(OperatorKind::kLaplaceBeltrami);
  double* values = K_.valuePtr();
  const int* outer = K_.outerIndexPtr();
  const int rows = fits.stencil_rows();
  return ParallelFor(nv, ctx, [&](int64_t vi) {
    const int i = static_cast<int>(vi);
    const HeightGeometry g = HeightGeometryAt(fits, i);
    const Eigen::Vector3d m = fits.frame(i).normal;
    const int n = nb_->Size(i);
    const int32_t* pts = nb_->Points(i);
    const double* S = fits.stencil(i);
    const double scale = 1 / (2 * g.l * g.l * g.l);
    double mean = 0;
    for (int k = 0; k < n; ++k) {
      // L_ik: the bracket of (5.3.6) over 2 l^3 (Taylor basis: no factor 2).
      const double L = rows > kVV ? scale * (g.mean_weights(0) * S[kUU * n + k] + g.mean_weights(1) * S[kUV * n + k] +
                                             g.mean_weights(2) * S[kVV * n + k])
                                  : 0.0;
      mean += L * base.row(pts[k]).dot(m);
      values[outer[i] + assembler_->Slot(i, k)] = L * c->normals.row(pts[k]).dot(m);
    }
    c->mean(i) = mean;
  }, 1024);
}

// Surface diffusion's reduced system (I + a B K) s = -a B M (eliminating mu = M + K s
// from [[I, a B], [-K, I]]), solved matrix-free by BiCGSTAB warm-started from the last
// step. Default preconditioner P = (I - c B)^2, c = sqrt(a / 2), built from the GFD
// operators themselves: B ~ Laplace-Beltrami (eigenvalues -lambda) and K ~ its half plus
// the curvature term, so on a mode lambda, I + a B K ~ 1 + c^2 lambda^2 (up to the
// curvature term) while P ~ (1 + c lambda)^2: a ratio within [1, 2] at every frequency the
// stencils see, whatever n and a (the cotan square below lacks this: its 1-ring operator
// is not the wide stencils'). P^{-1} is two V-cycles of one AMG hierarchy of I - c B,
// kept from step to step (only the finest matrix is refreshed) until the iterations
// exceed 1.5x + 2 those after its build. Iterations: 7 at 386 vertices for a = 1e-4 and
// a = 1e4 alike (tests/flow SolversAgree); 12 / 25 at 10k / 40k (a = 1e-6), against
// Jacobi's 59 / 252 (bench/README.md, "Flows").
// With Preconditioner::kDiagonal: Jacobi (the diagonal of I + a B K), no set-up, fine
// while a |B K| is moderate (27 iterations at 10k vertices, dt = 1e-6, wide stencils).
// When AMG or Jacobi does not converge within max_iterations, the flow switches for good to the cotan
// square P = (I - c M^{-1} S)^2: with B ~ Laplace-Beltrami and K ~ Laplace-Beltrami / 2,
// a B K ~ (a/2) Laplace-Beltrami^2, and P^{-1} = ((M - c S)^{-1} M)^2 costs one sparse
// Cholesky factorization of the 1-ring matrix M - c S, kept while the iterations stay
// within twice those of its first solve. c = sqrt(a/2) / 2: the 1-ring cotan operator's
// top eigenvalues are ~3x the wide GFD stencils' (630 vs 190 at 386 vertices); halving c
// balances the spectrum of P^{-1} (I + a B K) to [0.15, 3] (a = 1e-2) .. [0.68, 1]
// (a = 1e-6), against [0.04, 1] .. [0.48, 1] with c = sqrt(a/2). It is not spectrally
// equivalent to the GFD system (wide stencils barely see the mesh's highest
// frequencies): iterations grow with n (bench/README.md, "Flows").
struct FlowStepper::Schur {
  // AMG: P = (I - c B)^2, c = sqrt(a / 2), P^{-1} ~ two V-cycles of one hierarchy.
  bool amg = false;               // from the start (kAmg), or once Jacobi needs > jacobi_limit (kAuto)
  Amg hierarchy;
  SparseMatrix shifted;           // I - c B
  double amg_c = -1;              // the hierarchy's c
  bool amg_stale = true;
  int amg_iterations_at_build = -1;
  int amg_builds = 0;
  bool cotan = false;             // switched from Jacobi
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
  Eigen::VectorXd mass;
  double c = -1;                  // the factorization's c (a changes: BDF2's start step)
  bool analyzed = false, refactor = true;
  int iterations_at_factor = -1;  // BiCGSTAB iterations of the first solve after it
  int factorizations = 0;

  absl::Status Factorize(const Mesh& geometry, double c_new) {
    const CotanLaplacian cot = BuildCotanLaplacian(geometry);
    Eigen::SparseMatrix<double> P = -c_new * cot.stiffness;
    for (int i = 0; i < P.rows(); ++i) P.coeffRef(i, i) += cot.mass(i);
    if (!analyzed) ldlt.analyzePattern(P);
    analyzed = true;
    ldlt.factorize(P);
    if (ldlt.info() != Eigen::Success)
      return absl::FailedPreconditionError("cotan preconditioner: factorization failed (degenerate faces?)");
    mass = cot.mass;
    c = c_new;
    refactor = false;
    iterations_at_factor = -1;
    ++factorizations;
    return absl::OkStatus();
  }
};

FlowStepper::FlowStepper() = default;
FlowStepper::~FlowStepper() = default;

int FlowStepper::preconditioner_factorizations() const { return schur_ ? schur_->factorizations : 0; }
int FlowStepper::preconditioner_builds() const {
  return schur_ ? schur_->amg_builds : solver_.preconditioner_builds();
}

double FlowStepper::SolveTolerance() const {
  const double base = options_.solver.tolerance;
  const int k = static_cast<int>(offsets_.size());
  const bool bdf2 = options_.scheme == FlowScheme::kBdf2;
  if (!(options_.time_tolerance > 0) || k < (bdf2 ? 3 : 2)) return base;
  const Eigen::VectorXd& s = offsets_[k - 1];
  const double change = bdf2 ? (s - 2 * offsets_[k - 2] + offsets_[k - 3]).norm() : (s - offsets_[k - 2]).norm();
  const double norm = s.norm();
  if (!(norm > 0)) return base;
  return std::max(base, std::min(1e-4, options_.time_tolerance * change / norm));
}

absl::StatusOr<int> FlowStepper::SolveSchur(const Mesh& geometry, const Eigen::VectorXd& mean, double adt,
                                            double tolerance, const RunContext& ctx, Eigen::VectorXd* s) {
  Schur& z = *schur_;
  Eigen::VectorXd tmp;
  const LinearMap apply = [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    Multiply(K_, x, &tmp, ctx);
    Multiply(B_, tmp, y, ctx);
    *y = x + adt * *y;
  };
  Eigen::VectorXd rhs;
  Multiply(B_, mean, &rhs, ctx);
  rhs *= -adt;
  const int max_iterations = options_.solver.max_iterations;
  const bool adaptive = options_.solver.preconditioner == Preconditioner::kAuto;
  *s = solution_;  // warm start
  int jacobi_iterations = 0;
  if (!z.amg && !z.cotan) {
    const SparseMatrix Kt = K_.transpose();
    Eigen::VectorXd inverse_diagonal(K_.rows());
    GF_RETURN_IF_ERROR(ParallelFor(K_.rows(), ctx, [&](int64_t i) {
      inverse_diagonal(i) = 1 / (1 + adt * B_.row(i).dot(Kt.row(i)));
    }, 4096));
    const LinearMap jacobi = [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
      *y = inverse_diagonal.cwiseProduct(x);
    };
    const int limit = adaptive ? std::min(options_.solver.jacobi_limit, max_iterations) : max_iterations;
    const absl::StatusOr<int> iterations = SolveBicgstab(apply, jacobi, rhs, s, tolerance, limit);
    GF_RETURN_IF_ERROR(ctx.Check());
    if (iterations.ok()) {
      solution_ = *s;
      return iterations;
    }
    jacobi_iterations = limit;
    if (!s->allFinite()) *s = solution_;
    if (adaptive) {
      z.amg = true;  // Jacobi is too slow for this system: AMG from now on, from Jacobi's iterate
    } else {
      z.cotan = true;
    }
  }
  if (z.amg) {
    const double c = std::sqrt(adt / 2);  // see Schur
    if (z.shifted.rows() != B_.rows()) z.shifted = B_;
    const int nv = static_cast<int>(B_.rows());
    for (Eigen::Index p = 0; p < B_.nonZeros(); ++p) z.shifted.valuePtr()[p] = -c * B_.valuePtr()[p];
    for (int i = 0; i < nv; ++i) z.shifted.valuePtr()[z.shifted.outerIndexPtr()[i] + assembler_->Slot(i, 0)] += 1;
    if (z.amg_stale || c != z.amg_c || !z.hierarchy.built()) {
      GF_RETURN_IF_ERROR(z.hierarchy.Build(z.shifted, options_.solver.amg, ctx));
      z.amg_c = c;
      z.amg_stale = false;
      z.amg_iterations_at_build = -1;
      ++z.amg_builds;
    } else {
      GF_RETURN_IF_ERROR(z.hierarchy.UpdateFinest(z.shifted));
    }
    Eigen::VectorXd half;
    const LinearMap vcycles = [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
      z.hierarchy.Apply(x, &half);
      z.hierarchy.Apply(half, y);
    };
    const absl::StatusOr<int> iterations = SolveBicgstab(apply, vcycles, rhs, s, tolerance, max_iterations);
    GF_RETURN_IF_ERROR(ctx.Check());
    if (iterations.ok()) {
      // A solve that went on from Jacobi's iterate is no baseline for the hierarchy.
      if (jacobi_iterations == 0 && z.amg_iterations_at_build < 0) {
        z.amg_iterations_at_build = *iterations;
      } else if (AmgHierarchyStale(*iterations, z.amg_iterations_at_build)) {
        z.amg_stale = true;  // rebuild at the next step
      }
      solution_ = *s;
      return jacobi_iterations + *iterations;
    }
    z.amg = false;
    z.cotan = true;
    *s = solution_;
  }
  const double c = 0.5 * std::sqrt(adt / 2);  // see Schur
  if (z.refactor || c != z.c) GF_RETURN_IF_ERROR(z.Factorize(geometry, c));
  Eigen::VectorXd half;
  const LinearMap cotan = [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
    half = z.ldlt.solve(z.mass.cwiseProduct(x));  // no aliasing: the solve permutes into y
    *y = z.ldlt.solve(z.mass.cwiseProduct(half));
  };
  *s = solution_;
  const absl::StatusOr<int> iterations = SolveBicgstab(apply, cotan, rhs, s, tolerance, max_iterations);
  GF_RETURN_IF_ERROR(ctx.Check());
  if (!iterations.ok()) return iterations.status();
  if (z.iterations_at_factor < 0) {
    z.iterations_at_factor = *iterations;
  } else if (*iterations > 2 * z.iterations_at_factor + 2) {
    z.refactor = true;  // the geometry moved away from the preconditioner's
  }
  solution_ = *s;
  return iterations;
}

absl::StatusOr<std::unique_ptr<FlowStepper>> FlowStepper::Create(const Mesh& mesh, const FlowOptions& options,
                                                                  const RunContext& ctx) {
  GF_RETURN_IF_ERROR(ValidateFlowOptions(options));
  GF_ASSIGN_OR_RETURN(Topology topo, ValidateMesh(mesh));
  if (topo.num_boundary_edges > 0)
    return absl::InvalidArgumentError(absl::StrFormat(
        "mesh: open surface (%d boundary edges); flows need a closed surface", topo.num_boundary_edges));
  if (topo.num_isolated > 0)
    return absl::InvalidArgumentError(absl::StrFormat("mesh: %d isolated vertices (in no face)", topo.num_isolated));
  std::unique_ptr<FlowStepper> s(new FlowStepper());
  s->options_ = options;
  s->mesh_ = mesh;
  s->topo_ = std::move(topo);
  s->nb_ = std::make_shared<Neighborhoods>(
      BuildNeighborhoods(s->topo_, mesh, RingSpecFor(options.fit), ctx.threads()));
  GF_RETURN_IF_ERROR(ctx.Check());
  s->assembler_ = std::make_unique<OperatorAssembler>(s->nb_);
  SolverOptions so = options.solver;
  if (so.kind == SolverKind::kAuto) {  // see SolverOptions::kind
    so.kind = SolverKind::kBiCGSTAB;
    if (options.kind == FlowKind::kSurfaceDiffusion) so.preconditioner = Preconditioner::kIlut;
    if (options.kind == FlowKind::kSurfaceDiffusion && options.scheme != FlowScheme::kExplicit) {
      s->schur_ = std::make_unique<Schur>();
      s->schur_->amg = options.solver.preconditioner == Preconditioner::kAmg ||
                       options.solver.preconditioner == Preconditioner::kIlut;
    }
  }
  s->solver_ = SparseSolver(so);
  return s;
}

absl::StatusOr<SparseMatrix> FlowStepper::CurvatureJacobian(const RunContext& ctx) {
  Curvature c;
  double fit_ms = 0;
  GF_RETURN_IF_ERROR(Linearize(mesh_, mesh_.positions, ctx, &c, &fit_ms));
  return K_;
}

absl::StatusOr<StepStats> FlowStepper::Step(const RunContext& ctx) {
  const int step = steps_ + 1;
  const double dt = options_.dt, t = step * dt;
  GF_RETURN_IF_ERROR(AtStep(ctx.Check(), step, t));
  const int nv = mesh_.NumVertices();
  const bool bdf2 = options_.scheme == FlowScheme::kBdf2 && steps_ > 0;
  const double alpha = bdf2 ? 2.0 / 3.0 : 1.0;  // BDF2: (3 x^{n+1} - 4 x^n + x^{n-1}) / 2 = dt V
  StepStats st;
  st.step = step;
  st.t = t;

  // Geometry (frames, first derivatives, normals) from x^n, or from 2 x^n - x^{n-1}
  // for BDF2; the new positions are base + s n.
  Mesh geometry;
  Positions base;
  if (bdf2) {
    geometry.positions = 2 * mesh_.positions - previous_;
    base = (4 * mesh_.positions - previous_) / 3;
  }
  const Mesh& fit_mesh = bdf2 ? geometry : mesh_;
  if (bdf2) geometry.faces = mesh_.faces;
  const Positions& b = bdf2 ? base : mesh_.positions;

  Curvature c;
  const Stopwatch watch;
  GF_RETURN_IF_ERROR(AtStep(Linearize(fit_mesh, b, ctx, &c, &st.fit_ms), step, t));
  const bool diffusion = options_.kind == FlowKind::kSurfaceDiffusion;
  if (diffusion) GF_RETURN_IF_ERROR(AtStep(assembler_->Assemble(OperatorKind::kLaplaceBeltrami, *c.fits, &B_, ctx), step, t));

  Eigen::VectorXd s(nv);
  double solve_ms = 0;
  if (options_.scheme == FlowScheme::kExplicit) {
    s = diffusion ? Eigen::VectorXd(-dt * (B_ * c.mean)) : Eigen::VectorXd(dt * c.mean);  // (5.2.6), (5.2.8)
  } else if (schur_) {
    st.assemble_ms = watch.Millis() - st.fit_ms;
    const Stopwatch solve_watch;
    const absl::StatusOr<int> iterations = SolveSchur(fit_mesh, c.mean, alpha * dt, SolveTolerance(), ctx, &s);
    GF_RETURN_IF_ERROR(AtStep(iterations.status(), step, t));
    st.solver_iterations = *iterations;
    solve_ms = solve_watch.Millis();
  } else {
    const double adt = alpha * dt;
    Eigen::VectorXd rhs;
    if (!diffusion) {  // (I - a dt K) s = a dt M
      if (system_.rows() != nv) system_ = assembler_->Pattern(OperatorKind::kLaplaceBeltrami);
      const Eigen::Index nnz = K_.nonZeros();
      for (Eigen::Index j = 0; j < nnz; ++j) system_.valuePtr()[j] = -adt * K_.valuePtr()[j];
      for (int i = 0; i < nv; ++i) system_.valuePtr()[system_.outerIndexPtr()[i] + assembler_->Slot(i, 0)] += 1;
      rhs = adt * c.mean;
    } else {  // [[I, a dt B], [-K, I]] [s; mu] = [0; M]
      const int* outer = K_.outerIndexPtr();
      const int64_t nnzL = K_.nonZeros();
      if (system_.rows() != 2 * nv) {
        system_.resize(2 * nv, 2 * nv);
        system_.resizeNonZeros(2 * (nnzL + nv));
        int* so = system_.outerIndexPtr();
        int* si = system_.innerIndexPtr();
        for (int i = 0; i < nv; ++i) {
          const int n = outer[i + 1] - outer[i];
          const int top = i + outer[i], bottom = static_cast<int>(nv + nnzL) + i + outer[i];
          so[i] = top;
          so[nv + i] = bottom;
          si[top] = i;
          for (int p = 0; p < n; ++p) {
            si[top + 1 + p] = nv + K_.innerIndexPtr()[outer[i] + p];
            si[bottom + p] = K_.innerIndexPtr()[outer[i] + p];
          }
          si[bottom + n] = nv + i;
        }
        so[2 * nv] = static_cast<int>(2 * (nnzL + nv));
      }
      double* sv = system_.valuePtr();
      for (int i = 0; i < nv; ++i) {
        const int n = outer[i + 1] - outer[i];
        const int top = i + outer[i], bottom = static_cast<int>(nv + nnzL) + i + outer[i];
        sv[top] = 1;
        for (int p = 0; p < n; ++p) {
          sv[top + 1 + p] = adt * B_.valuePtr()[outer[i] + p];
          sv[bottom + p] = -K_.valuePtr()[outer[i] + p];
        }
        sv[bottom + n] = 1;
      }
      rhs.setZero(2 * nv);
      rhs.tail(nv) = c.mean;
    }
    st.assemble_ms = watch.Millis() - st.fit_ms;
    const Stopwatch solve_watch;
    Eigen::VectorXd sol = solution_;  // warm start for iterative solvers
    solver_.set_tolerance(SolveTolerance());
    GF_RETURN_IF_ERROR(AtStep(solver_.Factorize(system_), step, t));
    GF_RETURN_IF_ERROR(AtStep(solver_.Solve(rhs, &sol), step, t));
    solution_ = sol;
    solve_ms = solve_watch.Millis();
    st.solver_iterations = solver_.iterations();
    s = sol.head(nv);
  }
  if (options_.scheme == FlowScheme::kExplicit) st.assemble_ms = watch.Millis() - st.fit_ms;
  st.solve_ms = solve_ms;

  Positions next = b;
  for (int i = 0; i < nv; ++i) next.row(i) += s(i) * c.normals.row(i);

  // Blow-up checks: finite positions, no folded face.
  if (!next.allFinite())
    return absl::FailedPreconditionError(absl::StrFormat(
        "step %d (t = %g): positions are not finite (NaN or Inf): the %s scheme blew up at dt = %g", step, t,
        FlowSchemeName(options_.scheme), dt));
  Mesh moved;
  moved.positions = std::move(next);
  moved.faces = mesh_.faces;
  const double cos_turn = std::cos(options_.max_face_turn_deg * M_PI / 180);
  for (int f = 0; f < moved.NumFaces(); ++f) {
    const double turn = FaceNormal(mesh_, f).dot(FaceNormal(moved, f));
    if (!(turn >= cos_turn))
      return absl::FailedPreconditionError(absl::StrFormat(
          "step %d (t = %g): face %d turned by %.0f degrees (inverted normals): the %s scheme is unstable at dt = %g",
          step, t, f, std::acos(std::max(-1.0, std::min(1.0, turn))) * 180 / M_PI, FlowSchemeName(options_.scheme), dt));
  }
  st.max_speed = (moved.positions - mesh_.positions).rowwise().norm().maxCoeff() / dt;
  previous_ = std::move(mesh_.positions);
  mesh_.positions = std::move(moved.positions);
  steps_ = step;
  // BDF2's differences are taken over BDF2 steps only (its start step has other offsets).
  if (options_.scheme != FlowScheme::kBdf2 || bdf2) {
    if (offsets_.size() == 3) offsets_.erase(offsets_.begin());
    offsets_.push_back(std::move(s));
  }
  st.area = MeshArea(mesh_);
  st.volume = MeshVolume(mesh_);
  return st;
}

absl::Status RunFlow(const Mesh& mesh, const FlowOptions& options, const RunContext& ctx, FlowResult* result,
                     const std::function<absl::Status(const StepStats&, const Mesh&)>& on_step) {
  result->mesh = mesh;
  result->steps.clear();
  GF_RETURN_IF_ERROR(ValidateFlowOptions(options));
  if (options.steps == 0 && options.end_time <= 0)
    return absl::InvalidArgumentError("steps: 0 steps and no end_time: nothing to run");
  const int total = options.steps > 0 ? options.steps
                                      : static_cast<int>(std::ceil(options.end_time / options.dt - 1e-9));
  GF_ASSIGN_OR_RETURN(std::unique_ptr<FlowStepper> stepper, FlowStepper::Create(mesh, options, ctx));
  for (int i = 0; i < total; ++i) {
    GF_ASSIGN_OR_RETURN(const StepStats st, stepper->Step(ctx));
    result->steps.push_back(st);
    result->mesh.positions = stepper->mesh().positions;
    if (on_step) GF_RETURN_IF_ERROR(on_step(st, stepper->mesh()));
    ctx.Report("flow", i + 1, total);
  }
  return absl::OkStatus();
}

}  // namespace geomfit
