#include "core/operators/operators.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "absl/strings/str_format.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

constexpr int kU = TaylorIndex(1, 0), kV = TaylorIndex(0, 1);
constexpr int kUU = TaylorIndex(2, 0), kUV = TaylorIndex(1, 1), kVV = TaylorIndex(0, 2);

// Rows per vertex and columns per stencil point of the operators with the generic
// layout (every kind but the Weingarten map).
int RowsPerVertex(OperatorKind k) {
  switch (k) {
    case OperatorKind::kGradient: return 3;
    case OperatorKind::kHessian: return 9;
    default: return 1;
  }
}
int ColsPerPoint(OperatorKind k) {
  return k == OperatorKind::kDivergence || k == OperatorKind::kTangentialDivergence ? 3 : 1;
}

// The stencil rows of one vertex: value row r of stencil point k is S[r * n + k]; rows
// beyond the fit's kept rows read as zero (degree-1 fits have no second derivatives).
struct StencilRows {
  const double* S;
  int n, rows;
  double operator()(int r, int k) const { return r < rows ? S[r * n + k] : 0.0; }
};

}  // namespace

const char* OperatorKindName(OperatorKind kind) {
  switch (kind) {
    case OperatorKind::kGradient: return "gradient";
    case OperatorKind::kDivergence: return "divergence";
    case OperatorKind::kTangentialDivergence: return "tangential_divergence";
    case OperatorKind::kLaplaceBeltrami: return "laplace_beltrami";
    case OperatorKind::kHessian: return "hessian";
    case OperatorKind::kWeingarten: return "weingarten";
  }
  return "unknown";
}

HeightGeometry HeightGeometryAt(const SurfaceFits& fits, int v) {
  const LocalFrame& fr = fits.frame(v);
  const double* c = fits.coefficients(v);
  const int nc = fits.num_coefficients();
  auto at = [&](int i) { return i < nc ? c[i] : 0.0; };
  HeightGeometry g;
  g.fu = at(kU), g.fv = at(kV), g.fuu = at(kUU), g.fuv = at(kUV), g.fvv = at(kVV);
  const double l2 = 1 + g.fu * g.fu + g.fv * g.fv;
  g.l = std::sqrt(l2);
  g.J.col(0) = fr.t1 + g.fu * fr.normal;
  g.J.col(1) = fr.t2 + g.fv * fr.normal;
  g.Ginv << 1 + g.fv * g.fv, -g.fu * g.fv, -g.fu * g.fv, 1 + g.fu * g.fu;  // (5.2.11)
  g.Ginv /= l2;
  g.normal = (fr.normal - g.fu * fr.t1 - g.fv * fr.t2) / g.l;  // (5.2.4)
  g.mean_weights = Eigen::Vector3d(1 + g.fv * g.fv, -2 * g.fu * g.fv, 1 + g.fu * g.fu);
  // M of (5.2.5) is -H with outward frames.
  g.mean = -g.mean_weights.dot(Eigen::Vector3d(g.fuu, g.fuv, g.fvv)) / (2 * l2 * g.l);
  return g;
}

absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitForOperators(
    const Mesh& mesh, const Topology& topo, const FitOptions& options,
    std::shared_ptr<const Neighborhoods> neighborhoods, const RunContext& ctx) {
  if (options.method != FitMethod::kLHF)
    return absl::InvalidArgumentError("method: the GFD operators need LHF fits (height functions)");
  FitRequest req;
  req.stencils = true;
  req.stencil_order = 2;
  FitOptions o = options;  // the operators' function stencils share the fits' own tangent planes
  o.normal_degree = 0;  // no normal refinement: it would break the operators' orders
  o.hermite_hessian = false;  // nor Hermite curvatures (they need it, and leave the stencils)
  o.slope_refinement = 0;  // nor the slope refinement (frames change after the stencils)
  return FitSurface(mesh, topo, o, std::move(neighborhoods), req, ctx);
}

OperatorAssembler::OperatorAssembler(std::shared_ptr<const Neighborhoods> nb) : nb_(std::move(nb)) {
  const int nv = static_cast<int>(nb_->offsets.size()) - 1;
  row_offsets_.assign(nb_->offsets.begin(), nb_->offsets.end());
  columns_.assign(nb_->indices.begin(), nb_->indices.end());
  slot_.resize(columns_.size());
  std::vector<int> order;
  for (int i = 0; i < nv; ++i) {
    const int n = nb_->Size(i);
    const int32_t* pts = nb_->Points(i);
    order.resize(n);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int a, int b) { return pts[a] < pts[b]; });
    for (int p = 0; p < n; ++p) {
      columns_[row_offsets_[i] + p] = pts[order[p]];
      slot_[nb_->offsets[i] + order[p]] = p;
    }
  }
}

SparseMatrix OperatorAssembler::Pattern(OperatorKind kind) const {
  const int nv = num_vertices();
  SparseMatrix m;
  if (kind == OperatorKind::kWeingarten) {
    m.resize(3 * nv, 3 * nv);
    const Eigen::Index nnz = 9 * static_cast<Eigen::Index>(nv);
    m.resizeNonZeros(nnz);
    for (int64_t r = 0; r <= 3 * static_cast<int64_t>(nv); ++r) m.outerIndexPtr()[r] = static_cast<int>(3 * r);
    for (int64_t r = 0; r < 3 * static_cast<int64_t>(nv); ++r)
      for (int c = 0; c < 3; ++c) m.innerIndexPtr()[3 * r + c] = static_cast<int>(3 * (r / 3) + c);
    std::fill(m.valuePtr(), m.valuePtr() + nnz, 0.0);
    return m;
  }
  const int R = RowsPerVertex(kind), E = ColsPerPoint(kind);
  m.resize(static_cast<Eigen::Index>(R) * nv, static_cast<Eigen::Index>(E) * nv);
  const Eigen::Index nnz = static_cast<Eigen::Index>(R) * E * row_offsets_[nv];
  m.resizeNonZeros(nnz);  // nonZeros() reads the outer index: use nnz until it is filled
  int* outer = m.outerIndexPtr();
  int* inner = m.innerIndexPtr();
  for (int i = 0; i < nv; ++i) {
    const int n = static_cast<int>(row_offsets_[i + 1] - row_offsets_[i]);
    for (int r = 0; r < R; ++r) {
      const int64_t start = E * (R * row_offsets_[i] + static_cast<int64_t>(r) * n);
      outer[R * i + r] = static_cast<int>(start);
      for (int p = 0; p < n; ++p)
        for (int d = 0; d < E; ++d) inner[start + E * p + d] = E * Columns(i)[p] + d;
    }
  }
  outer[static_cast<int64_t>(R) * nv] = static_cast<int>(nnz);
  std::fill(m.valuePtr(), m.valuePtr() + nnz, 0.0);
  return m;
}

absl::Status OperatorAssembler::CheckFits(const SurfaceFits& fits) const {
  if (fits.options().method != FitMethod::kLHF)
    return absl::FailedPreconditionError("the GFD operators need LHF fits (height functions)");
  if (!fits.has_stencils() || fits.stencil_rows() < NumCoefficients(std::min(2, fits.options().degree)))
    return absl::FailedPreconditionError("the GFD operators need fits built with stencil rows up to order 2");
  const Neighborhoods& fnb = fits.neighborhoods();
  if (&fnb != nb_.get() && (fnb.offsets != nb_->offsets || fnb.indices != nb_->indices))
    return absl::InvalidArgumentError("the fits use other neighbourhoods than the operator pattern");
  return absl::OkStatus();
}

absl::Status OperatorAssembler::Assemble(OperatorKind kind, const SurfaceFits& fits, SparseMatrix* m,
                                         const RunContext& ctx) const {
  GF_RETURN_IF_ERROR(CheckFits(fits));
  const int nv = num_vertices();
  const int R = RowsPerVertex(kind), E = ColsPerPoint(kind);
  const int64_t nnz = kind == OperatorKind::kWeingarten ? 9 * static_cast<int64_t>(nv)
                                                         : static_cast<int64_t>(R) * E * row_offsets_[nv];
  const int64_t rows = kind == OperatorKind::kWeingarten ? 3 * static_cast<int64_t>(nv) : static_cast<int64_t>(R) * nv;
  if (m->rows() != rows || m->nonZeros() != nnz || !m->isCompressed() ||
      m->cols() != (kind == OperatorKind::kWeingarten ? 3 : E) * static_cast<int64_t>(nv))
    *m = Pattern(kind);
  double* values = m->valuePtr();

  return ParallelFor(nv, ctx, [&](int64_t vi) {
    const int i = static_cast<int>(vi);
    const HeightGeometry g = HeightGeometryAt(fits, i);
    const int n = nb_->Size(i);
    const StencilRows S{fits.stencil(i), n, fits.stencil_rows()};
    const Eigen::Matrix<double, 3, 2> P = g.J * g.Ginv;  // J^{+T}
    const double l2 = g.l * g.l;
    // M_ab[k] = S_ab[k] - f_ab (grad phi . grad f) / l^2 (5.1.18, 5.2.9)
    auto second = [&](int k, double* M) {
      const double gf = (g.fu * S(kU, k) + g.fv * S(kV, k)) / l2;
      M[0] = S(kUU, k) - g.fuu * gf;
      M[1] = S(kUV, k) - g.fuv * gf;
      M[2] = S(kVV, k) - g.fvv * gf;
    };
    const int64_t base = E * R * row_offsets_[i];
    switch (kind) {
      case OperatorKind::kGradient:
        for (int k = 0; k < n; ++k) {
          const Eigen::Vector3d d = P * Eigen::Vector2d(S(kU, k), S(kV, k));  // (5.1.3)
          for (int c = 0; c < 3; ++c) values[base + static_cast<int64_t>(c) * n + Slot(i, k)] = d(c);
        }
        break;
      case OperatorKind::kDivergence:
      case OperatorKind::kTangentialDivergence: {
        const Eigen::Matrix<double, 2, 3> Jp = P.transpose();  // J^+
        for (int k = 0; k < n; ++k) {
          const Eigen::Vector3d d = Jp.transpose() * Eigen::Vector2d(S(kU, k), S(kV, k));
          for (int c = 0; c < 3; ++c) values[base + 3 * Slot(i, k) + c] = d(c);
        }
        if (kind == OperatorKind::kTangentialDivergence)  // div(T psi) = div psi - 2 H n . psi
          for (int c = 0; c < 3; ++c) values[base + 3 * Slot(i, 0) + c] -= 2 * g.mean * g.normal(c);
        break;
      }
      case OperatorKind::kLaplaceBeltrami:
        for (int k = 0; k < n; ++k) {
          double M[3];
          second(k, M);
          values[base + Slot(i, k)] = g.Ginv(0, 0) * M[0] + 2 * g.Ginv(0, 1) * M[1] + g.Ginv(1, 1) * M[2];
        }
        break;
      case OperatorKind::kHessian:
        for (int k = 0; k < n; ++k) {
          double M[3];
          second(k, M);
          Eigen::Matrix2d Mk;
          Mk << M[0], M[1], M[1], M[2];
          const Eigen::Matrix3d Hk = P * Mk * P.transpose();
          for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) values[base + static_cast<int64_t>(3 * r + c) * n + Slot(i, k)] = Hk(r, c);
        }
        break;
      case OperatorKind::kWeingarten: {
        // dn = -J G^{-1} b G^{-1} J^T with b = H_f / l: k1, k2 on tangents, 0 on n.
        Eigen::Matrix2d b;
        b << g.fuu, g.fuv, g.fuv, g.fvv;
        b /= g.l;
        const Eigen::Matrix3d W = -P * b * P.transpose();
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) values[9 * static_cast<int64_t>(i) + 3 * r + c] = W(r, c);
        break;
      }
    }
  }, 1024);
}

absl::StatusOr<SparseMatrix> OperatorAssembler::Assemble(OperatorKind kind, const SurfaceFits& fits,
                                                         const RunContext& ctx) const {
  SparseMatrix m;
  GF_RETURN_IF_ERROR(Assemble(kind, fits, &m, ctx));
  return m;
}

namespace {
absl::StatusOr<SparseMatrix> OneShot(OperatorKind kind, const SurfaceFits& fits, const RunContext& ctx) {
  // The assembler shares the fits' neighbourhoods without owning them.
  const OperatorAssembler a(std::shared_ptr<const Neighborhoods>(&fits.neighborhoods(), [](const Neighborhoods*) {}));
  return a.Assemble(kind, fits, ctx);
}
}  // namespace

absl::StatusOr<SparseMatrix> GradientMatrix(const SurfaceFits& fits, const RunContext& ctx) {
  return OneShot(OperatorKind::kGradient, fits, ctx);
}
absl::StatusOr<SparseMatrix> DivergenceMatrix(const SurfaceFits& fits, bool tangential, const RunContext& ctx) {
  return OneShot(tangential ? OperatorKind::kTangentialDivergence : OperatorKind::kDivergence, fits, ctx);
}
absl::StatusOr<SparseMatrix> LaplaceBeltramiMatrix(const SurfaceFits& fits, const RunContext& ctx) {
  return OneShot(OperatorKind::kLaplaceBeltrami, fits, ctx);
}
absl::StatusOr<SparseMatrix> HessianMatrix(const SurfaceFits& fits, const RunContext& ctx) {
  return OneShot(OperatorKind::kHessian, fits, ctx);
}
absl::StatusOr<SparseMatrix> WeingartenMatrix(const SurfaceFits& fits, const RunContext& ctx) {
  return OneShot(OperatorKind::kWeingarten, fits, ctx);
}

CotanLaplacian BuildCotanLaplacian(const Mesh& mesh) {
  const int nv = mesh.NumVertices();
  CotanLaplacian c;
  c.mass.setZero(nv);
  std::vector<Eigen::Triplet<double>> t;
  t.reserve(12 * static_cast<size_t>(mesh.NumFaces()));
  auto triangle = [&](int a, int b, int d) {
    const int v[3] = {a, b, d};
    const Eigen::Vector3d p[3] = {mesh.positions.row(a), mesh.positions.row(b), mesh.positions.row(d)};
    const double twice_area = (p[1] - p[0]).cross(p[2] - p[0]).norm();
    for (int k = 0; k < 3; ++k) {
      c.mass(v[k]) += twice_area / 6;
      const Eigen::Vector3d e1 = p[(k + 1) % 3] - p[k], e2 = p[(k + 2) % 3] - p[k];
      const double w = twice_area > 0 ? 0.5 * e1.dot(e2) / twice_area : 0.0;  // cot at corner k / 2
      const int i = v[(k + 1) % 3], j = v[(k + 2) % 3];
      t.emplace_back(i, j, w);
      t.emplace_back(j, i, w);
      t.emplace_back(i, i, -w);
      t.emplace_back(j, j, -w);
    }
  };
  for (int f = 0; f < mesh.NumFaces(); ++f) {
    triangle(mesh.faces(f, 0), mesh.faces(f, 1), mesh.faces(f, 2));
    if (mesh.FaceSize(f) == 4) triangle(mesh.faces(f, 0), mesh.faces(f, 2), mesh.faces(f, 3));
  }
  c.stiffness.resize(nv, nv);
  c.stiffness.setFromTriplets(t.begin(), t.end());
  return c;
}

}  // namespace geomfit
