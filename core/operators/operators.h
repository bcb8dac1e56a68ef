#pragma once
// GFD surface operators (§5.1, §5.3) as sparse matrices assembled from the per-vertex
// stencils of LHF fits: the rows of C = A^+ in the Taylor basis (no monomial factor 2).
// Row i of a scalar operator holds vertex i's stencil points (the neighbourhood graph),
// so the sparsity pattern depends only on topology: an OperatorAssembler built once per
// topology refills the values of the same matrices for every new fit (time steps).
#include <cstdint>
#include <memory>
#include <vector>

#include <Eigen/SparseCore>

#include "absl/status/statusor.h"
#include "core/fitting/fit.h"
#include "core/mesh/topology.h"
#include "core/util/run_context.h"

namespace geomfit {

/// Compressed sparse rows (the pattern of every operator below).
using SparseMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

enum class OperatorKind {
  kGradient,               ///< 3n x n; rows 3i + c: component c of grad phi at i (5.1.3)
  kDivergence,             ///< n x 3n; columns 3j + c; standard tr((I - n n^T) grad psi)
  kTangentialDivergence,   ///< n x 3n; the text's (5.1.9): div(T psi) = div psi - 2H n.psi
  kLaplaceBeltrami,        ///< n x n; (5.1.18) in its height form (5.2.9)
  kHessian,                ///< 9n x n; rows 9i + 3r + c: entry (r, c) of the surface Hessian
  kWeingarten,             ///< 3n x 3n block diagonal: the shape operator dn on tangent vectors
};
const char* OperatorKindName(OperatorKind kind);

/// Per-vertex geometry of an LHF fit at its origin, in the frame (t1, t2, m): the height
/// derivatives f_u .. f_vv, J = [x_u | x_v] (global), G^{-1}, l = sqrt(1 + f_u^2 + f_v^2),
/// the outward unit normal and H = (k1 + k2)/2 (+1/R on a sphere).
struct HeightGeometry {
  double fu = 0, fv = 0, fuu = 0, fuv = 0, fvv = 0;
  double l = 1;
  Eigen::Matrix<double, 3, 2> J;
  Eigen::Matrix2d Ginv;
  Eigen::Vector3d normal;
  double mean = 0;
  /// Coefficients (a_uu, a_uv, a_vv) with (1 + f_v^2) f_uu - 2 f_u f_v f_uv + (1 + f_u^2) f_vv
  /// = a . (f_uu, f_uv, f_vv): the bracket of eq. (5.3.6).
  Eigen::Vector3d mean_weights;
};
HeightGeometry HeightGeometryAt(const SurfaceFits& fits, int v);

/// Fits `mesh` with the stencil rows the operators need (Taylor order <= 2). The one
/// place that maps a RunContext onto the fitting API. `options.method` must be LHF.
absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitForOperators(
    const Mesh& mesh, const Topology& topo, const FitOptions& options,
    std::shared_ptr<const Neighborhoods> neighborhoods, const RunContext& ctx);

/// The operators' sparsity pattern, built once per topology (stencils of
/// `neighborhoods`), and their numeric assembly from fits over those neighbourhoods.
class OperatorAssembler {
 public:
  explicit OperatorAssembler(std::shared_ptr<const Neighborhoods> neighborhoods);

  int num_vertices() const { return static_cast<int>(row_offsets_.size()) - 1; }
  const Neighborhoods& neighborhoods() const { return *nb_; }
  /// Position within row i (columns sorted) of vertex i's k-th stencil point.
  int Slot(int i, int k) const { return slot_[nb_->offsets[i] + k]; }
  /// Sorted stencil points of vertex i (the columns of scalar row i).
  const int32_t* Columns(int i) const { return columns_.data() + row_offsets_[i]; }

  /// An all-zero matrix with the operator's pattern.
  SparseMatrix Pattern(OperatorKind kind) const;
  /// Fills `m` with the operator of `fits`. If `m` already has this operator's pattern
  /// (from Pattern or an earlier Assemble), only its values are rewritten: the structure,
  /// and any solver's symbolic analysis of it, stay valid. Errors: FAILED_PRECONDITION
  /// for fits without stencil rows up to order 2 or not LHF, INVALID_ARGUMENT for fits
  /// over other neighbourhoods, CANCELLED / DEADLINE_EXCEEDED from `ctx`.
  absl::Status Assemble(OperatorKind kind, const SurfaceFits& fits, SparseMatrix* m,
                        const RunContext& ctx = RunContext()) const;
  absl::StatusOr<SparseMatrix> Assemble(OperatorKind kind, const SurfaceFits& fits,
                                        const RunContext& ctx = RunContext()) const;

  /// Checks that `fits` can feed the operators (see Assemble).
  absl::Status CheckFits(const SurfaceFits& fits) const;

 private:
  std::shared_ptr<const Neighborhoods> nb_;
  std::vector<int64_t> row_offsets_;  // scalar rows: n + 1
  std::vector<int32_t> columns_;      // sorted stencil points per vertex
  std::vector<int32_t> slot_;         // stencil point k of vertex i -> position in its row
};

/// One-shot operators in the pmp-library style (an assembler per call; reuse an
/// OperatorAssembler across revisions instead).
absl::StatusOr<SparseMatrix> GradientMatrix(const SurfaceFits& fits, const RunContext& ctx = RunContext());
absl::StatusOr<SparseMatrix> DivergenceMatrix(const SurfaceFits& fits, bool tangential = false,
                                              const RunContext& ctx = RunContext());
absl::StatusOr<SparseMatrix> LaplaceBeltramiMatrix(const SurfaceFits& fits, const RunContext& ctx = RunContext());
absl::StatusOr<SparseMatrix> HessianMatrix(const SurfaceFits& fits, const RunContext& ctx = RunContext());
absl::StatusOr<SparseMatrix> WeingartenMatrix(const SurfaceFits& fits, const RunContext& ctx = RunContext());

/// The classic low-order (1-ring) Laplace-Beltrami of a triangle mesh (quads split along
/// the diagonal 0-2): Laplace-Beltrami u ~ M^{-1} S u with the symmetric, negative
/// semidefinite cotan stiffness (S u)_i = 1/2 sum_j (cot a_ij + cot b_ij)(u_j - u_i) and
/// the lumped (barycentric) mass M. Compact and symmetric, so cheap to factorize: the
/// flows use it to precondition the GFD systems (and bench/ as the peer scheme).
struct CotanLaplacian {
  Eigen::SparseMatrix<double> stiffness;  ///< S, n x n, column-major (Eigen's Cholesky)
  Eigen::VectorXd mass;                   ///< M's diagonal: a third of the adjacent areas
};
CotanLaplacian BuildCotanLaplacian(const Mesh& mesh);

}  // namespace geomfit
