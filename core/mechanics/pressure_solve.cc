#include "core/mechanics/pressure_solve.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

#include <unsupported/Eigen/AutoDiff>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/linalg/gmres.h"
#include "core/mechanics/membrane_kernel.h"
#include "core/operators/operators.h"
#include "core/surfaces/analytic.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"

namespace geomfit {

using mechanics_internal::Jet5;
using mechanics_internal::ReferenceGeometry;

const char* BoundaryConditionName(BoundaryCondition bc) {
  switch (bc) {
    case BoundaryCondition::kUnset: return "unset";
    case BoundaryCondition::kClamped: return "clamped";
    case BoundaryCondition::kFree: return "free";
  }
  return "unknown";
}

absl::Status ValidatePressureSolveOptions(const PressureSolveOptions& o) {
  GF_RETURN_IF_ERROR(ValidateMembraneOptions(o.material));
  if (o.fit.method != FitMethod::kLHF) return absl::InvalidArgumentError("fit.method: the solve needs LHF fits");
  if (o.fit.degree < 2) return absl::InvalidArgumentError("fit.degree: the solve needs second derivatives (>= 2)");
  if (absl::Status s = ValidateFitOptions(o.fit); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("fit: ", s.message()));
  if (!(o.tolerance > 0 && o.tolerance < 1))
    return absl::InvalidArgumentError(absl::StrFormat("tolerance %g must lie in (0, 1)", o.tolerance));
  if (o.max_iterations < 1) return absl::InvalidArgumentError("max_iterations must be >= 1");
  if (o.max_load_cuts < 0) return absl::InvalidArgumentError("max_load_cuts must be >= 0");
  if (!(o.chord_ratio >= 0 && o.chord_ratio < 1))
    return absl::InvalidArgumentError(absl::StrFormat("chord_ratio %g must lie in [0, 1)", o.chord_ratio));
  if (!(o.krylov_tolerance > 0 && o.krylov_tolerance < 1))
    return absl::InvalidArgumentError(absl::StrFormat("krylov_tolerance %g must lie in (0, 1)", o.krylov_tolerance));
  if (!(o.krylov_forcing_max > 0 && o.krylov_forcing_max < 1))
    return absl::InvalidArgumentError(
        absl::StrFormat("krylov_forcing_max %g must lie in (0, 1)", o.krylov_forcing_max));
  if (o.krylov_restart < 1) return absl::InvalidArgumentError("krylov_restart must be >= 1");
  if (o.krylov_max_iterations < 1) return absl::InvalidArgumentError("krylov_max_iterations must be >= 1");
  if (o.solver.kind == SolverKind::kBiCGSTAB && o.solver.preconditioner != Preconditioner::kIlut)
    return absl::InvalidArgumentError("solver: BiCGSTAB needs the ILUT preconditioner here (or a direct solver)");
  return ValidateSolverOptions(o.solver);
}

absl::Status SetPressureSolver(const std::string& name, PressureSolveOptions* o) {
  o->krylov = name == "gmres";
  if (o->krylov) {
    o->solver.kind = SolverAvailable(SolverKind::kUmfpack) ? SolverKind::kUmfpack : SolverKind::kSparseLU;
    return absl::OkStatus();
  }
  absl::StatusOr<SolverKind> kind = ParseSolverKind(name);
  if (!kind.ok())
    return absl::InvalidArgumentError(absl::StrCat("solver: unknown '", name,
                                                   "' (auto, sparselu, umfpack, klu, bicgstab, gmres)"));
  if (!SolverAvailable(*kind)) return absl::InvalidArgumentError(absl::StrCat("solver: ", name, " is not in this build"));
  o->solver.kind = *kind;
  if (*kind == SolverKind::kBiCGSTAB) o->solver.preconditioner = Preconditioner::kIlut;
  return absl::OkStatus();
}

namespace {

constexpr int kRows[5] = {TaylorIndex(1, 0), TaylorIndex(0, 1), TaylorIndex(2, 0), TaylorIndex(1, 1),
                          TaylorIndex(0, 2)};
using AD = Eigen::AutoDiffScalar<Eigen::Matrix<double, 15, 1>>;

// The residual at a vertex: div sigma + [p] n; at a free-edge vertex (`conormal`: the
// covariant components N_b = x_b . M of the reference outward conormal M) its normal
// component with the traction sigma m (= y_a S^ab N_b up to a positive factor, m the
// deformed conormal) times `edge_scale` in place of the tangential ones.
template <typename T>
mechanics_internal::V3<T> Residual(const ReferenceGeometry& ref, const Jet5<T>& y, double lambda, double mu,
                                   double p, const Eigen::Vector2d* conormal, double edge_scale) {
  using namespace mechanics_internal;
  const MembraneState<T> s = State<T>(ref, y, lambda, mu);
  V3<T> r = StressDivergence(ref, s, y, lambda, mu) + s.normal * T(p);
  if (!conormal) return r;
  const T rn = s.normal.dot(r);
  const Eigen::Vector2d& N = *conormal;
  const V3<T> traction = y.d[0] * (s.S(0, 0) * N(0) + s.S(0, 1) * N(1)) + y.d[1] * (s.S(1, 0) * N(0) + s.S(1, 1) * N(1));
  return s.normal * rn + traction * T(edge_scale);
}

// Residual at a vertex and, if `D`, its derivative with respect to the 15 derivatives
// (y_u, y_v, y_uu, y_uv, y_vv) of y.
void LocalResidual(const ReferenceGeometry& ref, const Jet5<double>& y, double lambda, double mu, double p,
                   const Eigen::Vector2d* conormal, double edge_scale, Eigen::Vector3d* R,
                   Eigen::Matrix<double, 3, 15>* D) {
  using namespace mechanics_internal;
  if (!D) {
    *R = Residual<double>(ref, y, lambda, mu, p, conormal, edge_scale);
    return;
  }
  Jet5<AD> ya;
  for (int q = 0; q < 5; ++q)
    for (int c = 0; c < 3; ++c) ya.d[q](c) = AD(y.d[q](c), 15, 3 * q + c);
  const V3<AD> r = Residual<AD>(ref, ya, lambda, mu, p, conormal, edge_scale);
  for (int c = 0; c < 3; ++c) {
    (*R)(c) = r(c).value();
    D->row(c) = r(c).derivatives().transpose();
  }
}

/// Fits of the compact preconditioner: degree 2 on the 1-ring alone (no growth).
FitOptions CompactFitOptions(const FitOptions& fit) {
  FitOptions f = fit;
  f.degree = 2;
  f.rings = 1;
  f.adaptive = false;
  return f;
}

class PressureProblem {
 public:
  PressureProblem(const Mesh& ref, const Topology& topo, std::shared_ptr<const SurfaceFits> fits,
                  const Eigen::VectorXd& pressure, const PressureSolveOptions& o)
      : x_(ref.positions), fits_(std::move(fits)), o_(o), nv_(ref.NumVertices()) {
    assembler_ = std::make_unique<OperatorAssembler>(
        std::shared_ptr<const Neighborhoods>(&fits_->neighborhoods(), [](const Neighborhoods*) {}));
    fixed_.assign(nv_, 0);
    free_.assign(nv_, 0);
    bool open = false;
    const bool free_edges = o.boundary == BoundaryCondition::kFree;
    for (int i = 0; i < nv_; ++i) {
      if (topo.is_boundary[i]) (free_edges ? free_ : fixed_)[i] = 1, open = true;
      if (fits_->diagnostics(i).degree_used < 2) fixed_[i] = 1, free_[i] = 0;  // no curvature: held in place
    }
    // Free edges hold nothing: the rigid motions are removed as on a closed surface.
    bordered_ = !open || free_edges;
    lambda_ = o.material.Lambda();
    mu_ = o.material.Mu();
    const double h = AverageEdgeLength(ref);
    clamp_scale_ = o.material.E / (h * h);
    edge_scale_ = 1 / h;
    border_scale_ = o.material.E;
    ref_.resize(nv_);
    p_.resize(nv_);
    for (int i = 0; i < nv_; ++i) {
      Jet5<double> x;
      mechanics_internal::StencilJet(*fits_, i, x_, x.d);
      ref_[i] = mechanics_internal::MakeReference(x);
      p_[i] = pressure.size() == 1 ? pressure(0) : pressure(i);
    }
    centroid_ = x_.colwise().mean().transpose();
    normals_.resize(nv_, 3);
    for (int i = 0; i < nv_; ++i) normals_.row(i) = HeightGeometryAt(*fits_, i).normal.transpose();
    ndiff_.resize(nv_);
    for (int i = 0; i < nv_; ++i) mechanics_internal::StencilJet(*fits_, i, normals_, ndiff_[i].d);
    conormal_.assign(nv_, Eigen::Vector2d::Zero());
    for (int i = 0; i < nv_; ++i) {
      if (!free_[i]) continue;
      const Eigen::Vector3d M = OutwardConormal(ref, topo, i, normals_.row(i).transpose());
      conormal_[i] = Eigen::Vector2d(ref_[i].x.d[0].dot(M), ref_[i].x.d[1].dot(M));
    }
    load_norm_ = 0;
    for (int i = 0; i < nv_; ++i)
      if (!fixed_[i]) load_norm_ += p_[i] * p_[i];
    load_norm_ = std::sqrt(load_norm_);
    BuildPattern();
  }

  int size() const { return 3 * nv_ + (bordered_ ? 6 : 0); }

  /// The Jacobian's 1-ring part (GMRES's preconditioner): entries between a vertex and
  /// itself or an edge neighbour, and the border; values copied from the Jacobian.
  const SparseMatrix& OneRingPart(const Topology& topo) {
    if (keep_.empty()) {
      const int N = size();
      const int* outer = J_.outerIndexPtr();
      const int* inner = J_.innerIndexPtr();
      std::vector<int> pouter(N + 1, 0), pinner;
      for (int r = 0; r < N; ++r) {
        const int i = r / 3;
        for (int k = outer[r]; k < outer[r + 1]; ++k) {
          const int c = inner[k], j = c / 3;
          const bool near = r >= 3 * nv_ || c >= 3 * nv_ || j == i ||
                            std::binary_search(topo.Neighbors(i), topo.Neighbors(i) + topo.NumNeighbors(i), j);
          if (near) keep_.push_back(k), pinner.push_back(c);
        }
        pouter[r + 1] = static_cast<int>(keep_.size());
      }
      P_.resize(N, N);
      P_.resizeNonZeros(static_cast<Eigen::Index>(keep_.size()));
      std::copy(pouter.begin(), pouter.end(), P_.outerIndexPtr());
      std::copy(pinner.begin(), pinner.end(), P_.innerIndexPtr());
    }
    for (size_t m = 0; m < keep_.size(); ++m) P_.valuePtr()[m] = J_.valuePtr()[keep_[m]];
    return P_;
  }
  /// The compact preconditioner: the Jacobian `compact` (the same problem on 1-ring
  /// stencils, its values current) row by row in place of the 1-ring part, where its fit
  /// reached degree 2 and both patterns agree (the 1-ring part elsewhere).
  const SparseMatrix& CompactPart(const Topology& topo, const PressureProblem& compact) {
    OneRingPart(topo);
    const SparseMatrix& C = compact.J_;
    if (compact_rows_.empty()) {
      compact_rows_.assign(size(), 0);
      for (int r = 0; r < 3 * nv_; ++r) {
        const int i = r / 3;
        if (fixed_[i] || compact.fixed_[i] || free_[i]) continue;
        const int n = P_.outerIndexPtr()[r + 1] - P_.outerIndexPtr()[r];
        compact_rows_[r] = n == C.outerIndexPtr()[r + 1] - C.outerIndexPtr()[r] &&
                           std::equal(P_.innerIndexPtr() + P_.outerIndexPtr()[r],
                                      P_.innerIndexPtr() + P_.outerIndexPtr()[r + 1],
                                      C.innerIndexPtr() + C.outerIndexPtr()[r]);
      }
    }
    for (int r = 0; r < 3 * nv_; ++r)
      if (compact_rows_[r])
        std::copy(C.valuePtr() + C.outerIndexPtr()[r], C.valuePtr() + C.outerIndexPtr()[r + 1],
                  P_.valuePtr() + P_.outerIndexPtr()[r]);
    return P_;
  }
  /// Inverts the Jacobian's 3 x 3 diagonal blocks (for GaussSeidel).
  void InvertDiagonal() {
    dinv_.resize(nv_);
    const int* outer = J_.outerIndexPtr();
    const double* values = J_.valuePtr();
    for (int i = 0; i < nv_; ++i) {
      Eigen::Matrix3d D;
      const int slot = assembler_->Slot(i, 0);
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) D(r, c) = values[outer[3 * i + r] + 3 * slot + c];
      dinv_[i] = D.inverse();
    }
  }
  /// One block Gauss-Seidel sweep on J x = b over the vertex rows (forward or backward);
  /// the border unknowns stay.
  void GaussSeidel(const Eigen::VectorXd& b, Eigen::VectorXd* x, bool forward) const {
    const int* outer = J_.outerIndexPtr();
    const int* inner = J_.innerIndexPtr();
    const double* values = J_.valuePtr();
    for (int s = 0; s < nv_; ++s) {
      const int i = forward ? s : nv_ - 1 - s;
      Eigen::Vector3d r = b.segment<3>(3 * i);
      for (int q = 0; q < 3; ++q) {
        double acc = 0;
        for (int k = outer[3 * i + q]; k < outer[3 * i + q + 1]; ++k) acc += values[k] * (*x)(inner[k]);
        r(q) -= acc;
      }
      x->segment<3>(3 * i) += dinv_[i] * r;
    }
  }
  double load_norm() const { return load_norm_; }
  bool bordered() const { return bordered_; }
  SparseMatrix& jacobian() { return J_; }

  // Rigid mode m (0..5) at vertex i: translations e_m, rotations e_{m-3} x (x_i - c).
  Eigen::Vector3d Mode(int i, int m) const {
    if (m < 3) return Eigen::Vector3d::Unit(m);
    return Eigen::Vector3d::Unit(m - 3).cross(x_.row(i).transpose() - centroid_);
  }

  // F(z) at load t (and the Jacobian's values if `jacobian`); z = (y, multipliers).
  absl::Status Evaluate(const Eigen::VectorXd& z, double t, Eigen::VectorXd* F, bool jacobian,
                        const RunContext& ctx) {
    F->resize(size());
    double* values = J_.valuePtr();
    const int* outer = J_.outerIndexPtr();
    const int b = bordered_ ? 6 : 0;
    Positions y(nv_, 3);
    for (int i = 0; i < nv_; ++i) y.row(i) = z.segment<3>(3 * i).transpose();
    GF_RETURN_IF_ERROR(ParallelFor(nv_, ctx, [&](int64_t vi) {
      const int i = static_cast<int>(vi);
      const int n = fits_->neighborhoods().Size(i);
      if (fixed_[i]) {
        F->segment<3>(3 * i) = clamp_scale_ * (y.row(i) - x_.row(i)).transpose();
        if (jacobian)
          for (int r = 0; r < 3; ++r) {
            std::fill(values + outer[3 * i + r], values + outer[3 * i + r + 1], 0.0);
            values[outer[3 * i + r] + 3 * assembler_->Slot(i, 0) + r] = clamp_scale_;
          }
        return;
      }
      const double* S = fits_->stencil(i);
      const int rows = fits_->stencil_rows();
      const int32_t* pts = fits_->neighborhoods().Points(i);
      Jet5<double> yj = ref_[i].x;
      for (int k = 0; k < n; ++k) {
        const Eigen::Vector3d phi = (y.row(pts[k]) - x_.row(pts[k])).transpose();
        for (int q = 0; q < 5; ++q) yj.d[q] += Block(i, k, q, S, n, rows) * phi;
      }
      Eigen::Vector3d R;
      Eigen::Matrix<double, 3, 15> D;
      LocalResidual(ref_[i], yj, lambda_, mu_, t * p_[i], free_[i] ? &conormal_[i] : nullptr, edge_scale_, &R,
                    jacobian ? &D : nullptr);
      for (int m = 0; m < b; ++m) R += border_scale_ * z(3 * nv_ + m) * Mode(i, m);
      F->segment<3>(3 * i) = R;
      if (!jacobian) return;
      for (int k = 0; k < n; ++k) {
        Eigen::Matrix3d block = Eigen::Matrix3d::Zero();
        for (int q = 0; q < 5; ++q) block += D.block<3, 3>(0, 3 * q) * Block(i, k, q, S, n, rows);
        const int slot = assembler_->Slot(i, k);
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) values[outer[3 * i + r] + 3 * slot + c] = block(r, c);
      }
      for (int r = 0; r < 3; ++r)
        for (int m = 0; m < b; ++m) values[outer[3 * i + r + 1] - b + m] = border_scale_ * Mode(i, m)(r);
    }, 512, "membrane_residual"));
    for (int m = 0; m < b; ++m) {  // C^T (y - x)
      double s = 0;
      for (int i = 0; i < nv_; ++i) s += Mode(i, m).dot(y.row(i).transpose() - x_.row(i).transpose());
      (*F)(3 * nv_ + m) = border_scale_ * s;
    }
    return absl::OkStatus();
  }

  /// Adds c to the diagonal of the vertex rows (Levenberg-Marquardt damping of the step).
  void AddDiagonal(double c) {
    double* values = J_.valuePtr();
    const int* outer = J_.outerIndexPtr();
    for (int i = 0; i < nv_; ++i)
      if (!fixed_[i])
        for (int r = 0; r < 3; ++r) values[outer[3 * i + r] + 3 * assembler_->Slot(i, 0) + r] += c;
  }
  /// E / L^2, L^2 the mean squared distance to the centroid: the stiffness scale of the
  /// smooth (physical) modes, against which the damping is measured.
  double StiffnessScale() const {
    return o_.material.E / std::max(1e-300, (x_.rowwise() - centroid_.transpose()).rowwise().squaredNorm().mean());
  }

  /// 3 x 3 weight of stencil point k in derivative q (u, v, uu, uv, vv) of the displacement
  /// phi at vertex i. The normal part w = n . phi is differentiated by the product rule,
  /// d(w n) = (dw) n_i + w_i dn (dn: the stencil applied to the reference normals), so that
  /// w_i itself enters the strain at i; the plain stencil of w_k n_k sees w only at the
  /// neighbours (x_a . n_i = 0), which leaves odd-even (checkerboard) modes of the normal
  /// displacement nearly free: near-null Jacobian modes whose singular values fall like h^2.
  Eigen::Matrix3d Block(int i, int k, int q, const double* S, int n, int rows) const {
    auto s = [&](int qq) { return kRows[qq] < rows ? S[static_cast<size_t>(kRows[qq]) * n + k] : 0.0; };
    const int pk = fits_->neighborhoods().Points(i)[k];
    const Eigen::Vector3d nk = normals_.row(pk).transpose(), ni = normals_.row(i).transpose();
    const Eigen::Vector3d* nd = ndiff_[i].d;
    Eigen::Matrix3d B = s(q) * (Eigen::Matrix3d::Identity() - nk * nk.transpose()) + s(q) * ni * nk.transpose();
    if (q == 2) B += 2 * s(0) * nd[0] * nk.transpose();
    if (q == 3) B += (s(0) * nd[1] + s(1) * nd[0]) * nk.transpose();
    if (q == 4) B += 2 * s(1) * nd[1] * nk.transpose();
    if (k == 0) B += nd[q] * ni.transpose();
    return B;
  }

  Eigen::VectorXd Start() const {
    Eigen::VectorXd z = Eigen::VectorXd::Zero(size());
    for (int i = 0; i < nv_; ++i) z.segment<3>(3 * i) = x_.row(i).transpose();
    return z;
  }
  /// The initial guess at load t: every free vertex moved along its normal to the balloon
  /// radius of its mean curvature, r1 with E/(1 - nu) (r1^2 - r0^2)/(r0^2 r1) = t [p] and
  /// r0 = 1/H (6.3.4). An unstressed start has no geometric stiffness: Newton's first step
  /// from it excites near-inextensional modes; from a membrane in tension it does not.
  /// Exact for a sphere; elsewhere a start that Newton corrects.
  Eigen::VectorXd BalloonStart(double t) const {
    Eigen::VectorXd z = Start();
    const double k0 = (1 - o_.material.nu) / o_.material.E;
    for (int i = 0; i < nv_; ++i) {
      if (fixed_[i]) continue;
      const HeightGeometry g = HeightGeometryAt(*fits_, i);
      if (!(g.mean > 1e-12)) continue;  // flat or saddle-dominated: no balloon radius
      const double r0 = 1 / g.mean, k = t * p_[i] * k0 * r0;  // (r1/r0)^2 - 1 = k (r1/r0)
      const double ratio = (k + std::sqrt(k * k + 4)) / 2;
      z.segment<3>(3 * i) += (ratio - 1) * r0 * g.normal;
    }
    return z;
  }
  double ResidualNorm(const Eigen::VectorXd& F) const { return F.norm() / load_norm_; }

 private:
  /// The unit outward conormal of the reference at boundary vertex i: the sum of t x n
  /// over its boundary edges t (directed as their face runs, counter-clockwise seen
  /// from n, so the face lies to the left), projected onto the tangent plane. An edge
  /// (i, j) is on the boundary when one face around i has it.
  static Eigen::Vector3d OutwardConormal(const Mesh& m, const Topology& topo, int i, const Eigen::Vector3d& n) {
    std::vector<std::pair<int, int>> count;  // neighbour across an edge, faces having that edge
    auto bump = [&](int j) {
      for (auto& c : count)
        if (c.first == j) return void(++c.second);
      count.push_back({j, 1});
    };
    auto once = [&](int j) {
      for (const auto& c : count)
        if (c.first == j) return c.second == 1;
      return false;
    };
    auto corner = [&](int f) {
      int c = 0;
      while (m.faces(f, c) != i) ++c;
      return c;
    };
    for (int k = 0; k < topo.NumVertexFaces(i); ++k) {
      const int f = topo.VertexFaces(i)[k], c = corner(f);
      bump(m.Next(f, c));
      bump(m.Prev(f, c));
    }
    const Eigen::Vector3d xi = m.positions.row(i).transpose();
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    for (int k = 0; k < topo.NumVertexFaces(i); ++k) {
      const int f = topo.VertexFaces(i)[k], c = corner(f);
      const int next = m.Next(f, c), prev = m.Prev(f, c);
      if (once(next)) sum += (m.positions.row(next).transpose() - xi).cross(n);
      if (once(prev)) sum += (xi - m.positions.row(prev).transpose()).cross(n);
    }
    sum -= n * n.dot(sum);
    return sum.normalized();
  }

  // 3 x 3 blocks over each vertex's sorted stencil points, then the border columns; the
  // border rows are dense (values fixed: C^T).
  void BuildPattern() {
    const int b = bordered_ ? 6 : 0, N = size();
    std::vector<int> outer(N + 1, 0);
    int64_t nnz = 0;
    for (int i = 0; i < nv_; ++i)
      for (int r = 0; r < 3; ++r) outer[3 * i + r] = static_cast<int>(nnz), nnz += 3 * fits_->neighborhoods().Size(i) + b;
    for (int m = 0; m < b; ++m) outer[3 * nv_ + m] = static_cast<int>(nnz), nnz += 3 * nv_;
    outer[N] = static_cast<int>(nnz);
    J_.resize(N, N);
    J_.resizeNonZeros(nnz);
    std::copy(outer.begin(), outer.end(), J_.outerIndexPtr());
    int* inner = J_.innerIndexPtr();
    double* values = J_.valuePtr();
    std::fill(values, values + nnz, 0.0);
    for (int i = 0; i < nv_; ++i) {
      const int n = fits_->neighborhoods().Size(i);
      for (int r = 0; r < 3; ++r) {
        int pos = outer[3 * i + r];
        for (int p = 0; p < n; ++p)
          for (int c = 0; c < 3; ++c) inner[pos++] = 3 * assembler_->Columns(i)[p] + c;
        for (int m = 0; m < b; ++m) inner[pos++] = 3 * nv_ + m;
      }
    }
    for (int m = 0; m < b; ++m) {
      int pos = outer[3 * nv_ + m];
      for (int i = 0; i < nv_; ++i) {
        const Eigen::Vector3d e = Mode(i, m);
        for (int c = 0; c < 3; ++c) inner[pos] = 3 * i + c, values[pos++] = border_scale_ * e(c);
      }
    }
  }

  Positions x_;
  std::shared_ptr<const SurfaceFits> fits_;
  PressureSolveOptions o_;
  int nv_;
  std::unique_ptr<OperatorAssembler> assembler_;
  std::vector<uint8_t> fixed_;
  std::vector<uint8_t> free_;              // free-edge vertices
  std::vector<Eigen::Vector2d> conormal_;  // their reference outward conormals, N_b = x_b . M
  bool bordered_ = false;
  double lambda_ = 0, mu_ = 0, clamp_scale_ = 1, border_scale_ = 1, load_norm_ = 0, edge_scale_ = 1;
  std::vector<ReferenceGeometry> ref_;
  Positions normals_;               // reference fitted normals
  std::vector<Jet5<double>> ndiff_;  // their stencil derivatives per vertex
  std::vector<double> p_;
  Eigen::Vector3d centroid_;
  SparseMatrix J_;
  SparseMatrix P_;          // OneRingPart
  std::vector<int> keep_;   // its entries' positions in J_
  std::vector<uint8_t> compact_rows_;  // CompactPart: rows from the compact Jacobian
  std::vector<Eigen::Matrix3d> dinv_;  // InvertDiagonal
};

std::string History(const std::vector<NewtonIteration>& h) {
  std::string s;
  int step = -1;
  for (const NewtonIteration& it : h) {
    if (it.load_step != step) {
      step = it.load_step;
      absl::StrAppend(&s, s.empty() ? "" : "; ", absl::StrFormat("load %.4g:", it.load));
    }
    absl::StrAppend(&s, absl::StrFormat(" %.3e", it.residual));
  }
  return s;
}

}  // namespace

absl::StatusOr<PressureSolution> SolvePressureLoad(const Mesh& reference, const Topology& topo,
                                                   const Eigen::VectorXd& pressure,
                                                   const PressureSolveOptions& options, const RunContext& ctx,
                                                   const NewtonCallback& on_iteration) {
  GF_RETURN_IF_ERROR(ValidatePressureSolveOptions(options));
  const int nv = reference.NumVertices();
  if (pressure.size() != 1 && pressure.size() != nv)
    return absl::InvalidArgumentError(
        absl::StrFormat("pressure: %d values for %d vertices (give 1 or one per vertex)", pressure.size(), nv));
  for (Eigen::Index i = 0; i < pressure.size(); ++i)
    if (!std::isfinite(pressure(i)))
      return absl::InvalidArgumentError(absl::StrFormat("pressure: value %d is not finite", i));
  if (topo.num_boundary_edges > 0 && options.boundary == BoundaryCondition::kUnset)
    return absl::InvalidArgumentError("boundary: the mesh is open; give a boundary condition (clamped or free)");
  PressureSolution out;
  const Stopwatch fit_watch;
  GF_ASSIGN_OR_RETURN(auto fits, FitForOperators(reference, topo, options.fit, nullptr, ctx));
  out.fit_ms = fit_watch.Millis();
  PressureProblem problem(reference, topo, fits, pressure, options);
  Eigen::VectorXd z = problem.Start();
  auto finish = [&](const Eigen::VectorXd& zz) {
    out.deformed.resize(nv, 3);
    for (int i = 0; i < nv; ++i) out.deformed.row(i) = zz.segment<3>(3 * i).transpose();
    out.displacement = out.deformed - reference.positions;
  };
  if (problem.load_norm() == 0) {  // no load: the reference is the equilibrium
    finish(z);
    return out;
  }
  SolverOptions so = options.solver;
  if (so.kind == SolverKind::kAuto)
    so.kind = SolverAvailable(SolverKind::kUmfpack) ? SolverKind::kUmfpack : SolverKind::kSparseLU;
  SparseSolver solver(so);
  // GMRES's set-up: the compact preconditioner's problem (the same membrane on 1-ring
  // degree-2 stencils) and a factorization without iterative refinement.
  bool krylov = false;
  std::unique_ptr<PressureProblem> compact;
  auto use_krylov = [&]() -> absl::Status {
    krylov = true;
    if (options.krylov_preconditioner == KrylovPreconditioner::kCompact) {
      const Stopwatch w;
      GF_ASSIGN_OR_RETURN(auto compact_fits,
                          FitForOperators(reference, topo, CompactFitOptions(options.fit), nullptr, ctx));
      compact = std::make_unique<PressureProblem>(reference, topo, compact_fits, pressure, options);
      out.fit_ms += w.Millis();
    }
    so.umfpack_refinement = 0;  // a preconditioner
    solver = SparseSolver(so);
    return absl::OkStatus();
  };
  if (options.krylov) GF_RETURN_IF_ERROR(use_krylov());

  double t = 0, dt = 1;
  int cuts = 0;
  Eigen::VectorXd F, Fc, dz;
  while (t < 1) {
    const double target = std::min(1.0, t + dt);
    const double tol = target < 1 ? std::max(options.tolerance, 1e-6) : options.tolerance;
    // From the reference, start at the balloon guess of the target load; later steps
    // start from the last equilibrium.
    Eigen::VectorXd zt = t == 0 ? problem.BalloonStart(target) : z;
    bool converged = false;
    {
      const Stopwatch w;
      GF_RETURN_IF_ERROR(problem.Evaluate(zt, target, &F, false, ctx));
      out.assemble_ms += w.Millis();
    }
    double res = problem.ResidualNorm(F);
    double damping = 0;  // raised only when a step does not descend
    // Chord steps: the factorization is kept while it still cuts the residual 10x per
    // iteration (factorizations dominate the cost); refactorized otherwise.
    bool factorized = false;
    double ratio = 1;
    double eta = 0, previous_res = 0;  // Eisenstat-Walker forcing term and the residual it follows
    for (int it = 1; it <= options.max_iterations && !converged; ++it) {
      GF_RETURN_IF_ERROR(ctx.Check());
      Stopwatch w;
      // GMRES keeps its preconditioner through the load step (refactorized only with
      // more damping after a step that does not descend): a stale one costs iterations
      // only, and the Jacobian barely moves. The direct solve keeps its factorization
      // by the chord rule.
      const bool stale = !krylov && ratio > options.chord_ratio;
      if (!factorized || stale) {
        GF_RETURN_IF_ERROR(problem.Evaluate(zt, target, &F, true, ctx));
        problem.AddDiagonal(damping);
        if (compact) {
          GF_RETURN_IF_ERROR(compact->Evaluate(zt, target, &Fc, true, ctx));
          compact->AddDiagonal(damping);
        }
        out.assemble_ms += w.Millis();
        w = Stopwatch();
        absl::Status fs = solver.Factorize(!krylov ? problem.jacobian()
                                           : compact     ? problem.CompactPart(topo, *compact)
                                                         : problem.OneRingPart(topo));
        out.factorize_ms += w.Millis();
        ++out.factorizations;
        if (fs.code() == absl::StatusCode::kResourceExhausted && !krylov) {
          // The Jacobian's factorization does not fit: GMRES on a sparser one from here.
          GF_RETURN_IF_ERROR(use_krylov());
          out.fell_back_to_krylov = true;
          --it;
          continue;
        }
        if (fs.code() == absl::StatusCode::kResourceExhausted) return fs;  // a smaller load does not help
        if (!fs.ok()) break;  // singular Jacobian: cut the load
        factorized = true;
      } else if (krylov) {  // GMRES takes the fresh Jacobian; the preconditioner stays
        GF_RETURN_IF_ERROR(problem.Evaluate(zt, target, &F, true, ctx));
        problem.AddDiagonal(damping);
        out.assemble_ms += w.Millis();
      }
      w = Stopwatch();
      dz.resize(0);
      int step_krylov = 0;
      if (krylov) {
        const SparseMatrix& J = problem.jacobian();
        if (options.krylov_smoothing > 0) problem.InvertDiagonal();
        // Eisenstat-Walker (choice 2, gamma 0.9): loose first solves, then
        // eta_k = 0.9 (|F_k| / |F_k-1|)^2, never below what the tolerance needs.
        if (!options.krylov_forcing) {
          eta = options.krylov_tolerance;
        } else {
          eta = previous_res > 0 ? std::max(0.9 * std::pow(res / previous_res, 2), 0.9 * eta * eta)
                                 : options.krylov_forcing_max;
          eta = std::min(options.krylov_forcing_max, std::max(eta, 0.5 * tol / res));
        }
        GmresOptions go;
        go.tolerance = eta;
        go.max_iterations = options.krylov_max_iterations;
        go.restart = options.krylov_restart;
        GmresResult gr;
        const absl::Status gs = Gmres(
            [&](const Eigen::VectorXd& v, Eigen::VectorXd* y) {
              *y = J * v;
              return absl::OkStatus();
            },
            [&](const Eigen::VectorXd& v, Eigen::VectorXd* y) {
              const Stopwatch pw;
              y->resize(0);
              const absl::Status s = solver.Solve(v, y);
              for (int sweep = 0; s.ok() && sweep < options.krylov_smoothing; ++sweep) {
                problem.GaussSeidel(v, y, true);
                problem.GaussSeidel(v, y, false);
              }
              out.precondition_ms += pw.Millis();
              return s;
            },
            -F, go, &dz, &gr, ctx);
        out.krylov_iterations += gr.iterations;
        step_krylov = gr.iterations;
        // Not reaching the tolerance leaves the best iterate: the line search judges it.
        if (!gs.ok() && gs.code() != absl::StatusCode::kFailedPrecondition) return gs;
      } else {
        GF_RETURN_IF_ERROR(solver.Solve(-F, &dz));
      }
      out.solve_ms += w.Millis();
      // Backtracking: halve the step while the residual grows (at most 4 times).
      double alpha = 1, new_res = 0;
      Eigen::VectorXd trial;
      for (int ls = 0; ls < 5; ++ls, alpha *= 0.5) {
        trial = zt + alpha * dz;
        w = Stopwatch();
        GF_RETURN_IF_ERROR(problem.Evaluate(trial, target, &F, false, ctx));
        out.assemble_ms += w.Millis();
        new_res = problem.ResidualNorm(F);
        if (std::isfinite(new_res) && new_res < res) break;
      }
      if (alpha == 1 && new_res < res) {
        damping = damping < 1e-8 * problem.StiffnessScale() ? 0 : damping / 4;
      } else {
        damping = std::max(8 * damping, 1e-3 * problem.StiffnessScale());
      }
      ratio = new_res / res;
      if (!(new_res < res)) {  // no descent: refactorize with more damping
        factorized = false;
        NewtonIteration ni;
        ni.load_step = out.load_steps, ni.load = target, ni.iteration = it, ni.residual = res, ni.step = 0;
        ni.krylov_iterations = step_krylov;
        out.history.push_back(ni);
        if (on_iteration) on_iteration(ni);
        continue;
      }
      double step = 0;
      for (int i = 0; i < nv; ++i) step = std::max(step, alpha * dz.segment<3>(3 * i).norm());
      NewtonIteration ni;
      ni.load_step = out.load_steps;
      ni.load = target;
      ni.iteration = it;
      ni.residual = new_res;
      ni.step = step;
      ni.krylov_iterations = step_krylov;
      out.history.push_back(ni);
      if (on_iteration) on_iteration(ni);
      if (!std::isfinite(new_res) || new_res > 1e6) break;
      zt = trial;
      previous_res = res;
      res = new_res;
      converged = res <= tol;
    }
    ++out.load_steps;
    if (converged) {
      z = zt;
      t = target;
      dt = std::min(1.0, 2 * dt);
      continue;
    }
    if (++cuts > options.max_load_cuts)
      return absl::FailedPreconditionError(absl::StrFormat(
          "Newton did not converge (load %.4g of the pressure, %d load cuts); residual history: %s", target,
          cuts - 1, History(out.history)));
    dt *= 0.5;
  }
  out.residual = problem.ResidualNorm(F);
  finish(z);
  return out;
}

}  // namespace geomfit
