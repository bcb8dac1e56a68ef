#include "core/fitting/fit.h"

#include <atomic>
#include <cmath>


#include "absl/strings/str_format.h"
#include "core/fitting/small_qr.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

constexpr int kMaxCoef = NumCoefficients(kMaxDegree);

// 1 / (j! k!) for the Taylor basis of (2.3.1).
double InvFactorialProduct(int j, int k) {
  static const double f[] = {1, 1, 2, 6, 24, 120, 720};
  return 1.0 / (f[j] * f[k]);
}

// Everything a vertex fit reads, and where it writes.
struct FitInput {
  const Mesh& mesh;
  const Neighborhoods& nb;
  const Positions& normals;  // per-vertex normals for frames and the safeguard weights
  const FitOptions& o;
  bool stencils;
};

struct FitOutput {
  LocalFrame* frame;
  double* coefficients;  // dims x ncoef
  VertexDiagnostics* diag;
  double* stencil;       // ncoef x stencil size, or null
};

// The weighted-least-squares fit of one vertex (2.2-2.4): Taylor-basis Vandermonde
// (2.3.2) with weights (2.2.1), column scaling (2.6.6), Householder QR with the
// condition safeguard that drops whole trailing degrees (2.4).
void FitVertex(int v, const FitInput& in, const FitOutput& out) {
  const FitOptions& o = in.o;
  const int n_pts = in.nb.Size(v);
  const int32_t* pts = in.nb.Points(v);
  const int dims = o.method == FitMethod::kLHF ? 1 : 3;
  const int ncoef = NumCoefficients(o.degree);
  const int first_col = o.interpolate ? 1 : 0;  // c00 is fixed by interpolation
  VertexDiagnostics& diag = *out.diag;
  diag.degree_requested = static_cast<int8_t>(o.degree);
  std::fill(out.coefficients, out.coefficients + dims * ncoef, 0.0);

  const Eigen::Vector3d x0 = in.mesh.positions.row(v).transpose();
  const Eigen::Vector3d m0 = in.normals.row(v).transpose();
  if (m0.squaredNorm() == 0) {  // isolated vertex: no faces, no frame
    diag.flags |= kFlagIsolated;
    *out.frame = FrameFromNormal(x0, Eigen::Vector3d::UnitZ());
    return;
  }
  const LocalFrame frame = FrameFromNormal(x0, m0);
  *out.frame = frame;

  // Local coordinates and safeguard factors gamma_i (2.2.1).
  const double cos_cut = std::cos(o.safeguard_angle_deg * M_PI / 180.0);
  Eigen::Matrix<double, kMaxStencil, 3> uvw;
  Eigen::Matrix<double, kMaxStencil, 1> gamma;
  Eigen::Matrix<int16_t, kMaxStencil, 1> row_point;  // row -> index in the stencil
  int rows = 0;
  double radius2 = 0;
  for (int i = first_col; i < n_pts; ++i) {  // the centre is row 0 unless interpolating
    const int p = pts[i];
    const double g = i == 0 ? 1.0 : in.normals.row(p).dot(m0);
    if (g < cos_cut || g <= 0) continue;
    const Eigen::Vector3d d = in.mesh.positions.row(p).transpose() - x0;
    uvw.row(rows) << d.dot(frame.t1), d.dot(frame.t2), d.dot(frame.normal);
    gamma(rows) = g;
    row_point(rows) = static_cast<int16_t>(i);
    radius2 = std::max(radius2, uvw(rows, 0) * uvw(rows, 0) + uvw(rows, 1) * uvw(rows, 1));
    ++rows;
  }
  diag.points = static_cast<int16_t>(rows + first_col);
  const int needed = ncoef - first_col;
  if (rows < needed) diag.flags |= kFlagTooFewPoints;
  if (rows == 0 || radius2 == 0) return;
  const double h = std::sqrt(radius2);  // distances are scaled by the stencil radius

  // Weighted Vandermonde [A | B] with right-hand sides (2.3.5), column-major, ld = rows.
  const int cols = needed, ld = rows;
  double a[kMaxStencil * (kMaxCoef + 3)];
  double* B = a + cols * ld;
  for (int r = 0; r < rows; ++r) {
    const double u = uvw(r, 0) / h, w_v = uvw(r, 1) / h;
    // (2.2.1): w = gamma / (sqrt(|u|^2 + eps))^(d/2), as an integer power of s^(1/4).
    const double s4 = std::sqrt(std::sqrt(u * u + w_v * w_v + o.weight_epsilon));
    double denom = s4;
    for (int e = 1; e < o.degree; ++e) denom *= s4;
    const double weight = gamma(r) / denom;
    double upow[kMaxDegree + 1] = {1}, vpow[kMaxDegree + 1] = {1};
    for (int e = 1; e <= o.degree; ++e) upow[e] = upow[e - 1] * u, vpow[e] = vpow[e - 1] * w_v;
    int c = 0;
    for (int p = first_col; p <= o.degree; ++p)
      for (int k = 0; k <= p; ++k)
        a[(c++) * ld + r] = weight * upow[p - k] * vpow[k] * InvFactorialProduct(p - k, k);
    if (dims == 1) {
      B[r] = weight * uvw(r, 2);
    } else {
      const Eigen::Vector3d d = in.mesh.positions.row(pts[row_point(r)]).transpose() - x0;
      for (int q = 0; q < 3; ++q) B[q * ld + r] = weight * d(q);
    }
    gamma(r) = weight;  // keep the row weight for the stencil operator
  }
  // Column scaling by 2-norms (2.6.6).
  double scale[kMaxCoef];
  for (int c = 0; c < cols; ++c) {
    double norm2 = 0;
    for (int r = 0; r < rows; ++r) norm2 += a[c * ld + r] * a[c * ld + r];
    scale[c] = norm2 > 0 ? 1 / std::sqrt(norm2) : 1.0;
    for (int r = 0; r < rows; ++r) a[c * ld + r] *= scale[c];
  }
  double tau[kMaxCoef];
  HouseholderQRInPlace(a, ld, rows, cols, dims, tau);  // [A | B] -> [R | Q^T B]
  const int kq = std::min(rows, cols);

  // Condition safeguard (2.4): the leading k x k block of R factors the first k columns
  // and inv(R)'s leading block inverts it, so 1-norms of every leading block are prefix
  // maxima of column sums: one triangular inverse prices every degree.
  int usable = kq;  // columns before the first (numerically) zero pivot
  const double tiny = 1e-13 * std::max(1.0, std::abs(a[0]));
  for (int c = 0; c < kq; ++c)
    if (!(std::abs(a[c * ld + c]) > tiny)) { usable = c; break; }
  double rinv[kMaxCoef * kMaxCoef];
  InvertUpper(a, ld, usable, rinv);
  double colsum_r[kMaxCoef], colsum_i[kMaxCoef];
  for (int c = 0; c < usable; ++c) {
    colsum_r[c] = colsum_i[c] = 0;
    for (int i = 0; i <= c; ++i) colsum_r[c] += std::abs(a[c * ld + i]), colsum_i[c] += std::abs(rinv[c * usable + i]);
    if (c > 0) colsum_r[c] = std::max(colsum_r[c], colsum_r[c - 1]), colsum_i[c] = std::max(colsum_i[c], colsum_i[c - 1]);
  }
  int degree = o.degree, k = 0;
  double cond = 0;
  for (; degree >= 1; --degree) {
    k = NumCoefficients(degree) - first_col;
    if (k > usable) continue;
    cond = colsum_r[k - 1] * colsum_i[k - 1];
    if (cond <= o.cond_threshold[degree]) break;
  }
  diag.condition = static_cast<float>(cond);
  if (degree < 1) {
    diag.degree_used = 0;
    diag.flags |= kFlagDowngraded;
    return;
  }
  if (degree < o.degree) diag.flags |= kFlagDowngraded;
  diag.degree_used = static_cast<int8_t>(degree);
  diag.rank = static_cast<int16_t>(k + first_col);

  // y = R_k^-1 (Q^T b)_k, then undo the column and radius scaling.
  double hp[kMaxDegree + 1];
  hp[0] = 1;
  for (int p = 1; p <= degree; ++p) hp[p] = hp[p - 1] * h;
  for (int d = 0; d < dims; ++d) {
    double y[kMaxCoef];
    for (int i = k - 1; i >= 0; --i) {  // back substitution
      double sum = B[d * ld + i];
      for (int l = i + 1; l < k; ++l) sum -= a[l * ld + i] * y[l];
      y[i] = sum / a[i * ld + i];
    }
    double* c_out = out.coefficients + d * ncoef;
    int c = 0;
    for (int p = first_col; p <= degree; ++p)
      for (int kk = 0; kk <= p; ++kk, ++c) c_out[TaylorIndex(p - kk, kk)] = scale[c] * y[c] / hp[p];
  }

  if (out.stencil) {
    // Operator rows: coefficients = S R_k^-1 Q_k^T Omega g (g = values at the rows, minus
    // the centre value when interpolating), i.e. row c of the operator is
    // S_c / h^p * sum_l Rinv(c, l) (Q e_l)^T Omega.
    std::fill(out.stencil, out.stencil + static_cast<size_t>(ncoef) * n_pts, 0.0);
    double q[kMaxCoef * kMaxStencil];  // columns Q e_l, l < k
    for (int l = 0; l < k; ++l) {
      double* ql = q + l * rows;
      std::fill(ql, ql + rows, 0.0);
      ql[l] = 1;
      ApplyQ(a, ld, rows, kq, tau, ql);
    }
    int c = 0;
    for (int p = first_col; p <= degree; ++p) {
      for (int kk = 0; kk <= p; ++kk, ++c) {
        double* row = out.stencil + static_cast<size_t>(TaylorIndex(p - kk, kk)) * n_pts;
        double sum = 0;
        for (int r = 0; r < rows; ++r) {
          double acc = 0;
          for (int l = c; l < k; ++l) acc += rinv[l * usable + c] * q[l * rows + r];
          const double val = gamma(r) * acc * scale[c] / hp[p];
          row[row_point(r)] = val;
          sum += val;
        }
        if (o.interpolate) row[0] -= sum;
      }
    }
    if (o.interpolate) out.stencil[0] = 1.0;  // c00 = g(centre)
  }
}

}  // namespace

SurfaceJet SurfaceFits::Jet(int v) const {
  const LocalFrame& fr = frames_[v];
  const double* c = coefficients(v);
  const int n = num_coefficients();
  auto at = [&](int d, int j, int k) { return TaylorIndex(j, k) < n ? c[d * n + TaylorIndex(j, k)] : 0.0; };
  SurfaceJet jet;
  if (dims() == 1) {
    jet.x = fr.origin + at(0, 0, 0) * fr.normal;
    jet.J.col(0) = fr.t1 + at(0, 1, 0) * fr.normal;
    jet.J.col(1) = fr.t2 + at(0, 0, 1) * fr.normal;
    jet.xuu = at(0, 2, 0) * fr.normal;
    jet.xuv = at(0, 1, 1) * fr.normal;
    jet.xvv = at(0, 0, 2) * fr.normal;
  } else {
    for (int d = 0; d < 3; ++d) {
      jet.x(d) = fr.origin(d) + at(d, 0, 0);
      jet.J(d, 0) = at(d, 1, 0);
      jet.J(d, 1) = at(d, 0, 1);
      jet.xuu(d) = at(d, 2, 0);
      jet.xuv(d) = at(d, 1, 1);
      jet.xvv(d) = at(d, 0, 2);
    }
  }
  return jet;
}

size_t SurfaceFits::Bytes() const {
  return sizeof(*this) + frames_.size() * sizeof(LocalFrame) + coefficients_.size() * 8 +
         diagnostics_.size() * sizeof(VertexDiagnostics) + stencil_offsets_.size() * 8 +
         stencils_.size() * 8;
}

class SurfaceFitter {
 public:
  static absl::StatusOr<std::shared_ptr<const SurfaceFits>> Fit(
      const Mesh& mesh, const Topology& topo, const FitOptions& o,
      std::shared_ptr<const Neighborhoods> nb, const FitRequest& req) {
    if (absl::Status s = ValidateFitOptions(o); !s.ok()) return s;
    if (topo.num_vertices != mesh.NumVertices() || topo.num_faces != mesh.NumFaces())
      return absl::InvalidArgumentError(absl::StrFormat(
          "topology (%d vertices, %d faces) does not match the mesh (%d vertices, %d faces)",
          topo.num_vertices, topo.num_faces, mesh.NumVertices(), mesh.NumFaces()));
    if (!nb) nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(o), o.num_threads));
    if (static_cast<int>(nb->offsets.size()) != mesh.NumVertices() + 1)
      return absl::InvalidArgumentError("neighborhoods do not match the mesh");

    Positions normals = ApproximateVertexNormals(mesh, topo, o.frame_normals, o.num_threads);
    auto fits = std::make_shared<SurfaceFits>();
    for (int pass = 0; pass < (o.two_pass ? 2 : 1); ++pass) {
      if (pass == 1) {  // frames and safeguard weights from the first pass's fitted normals
        ParallelFor(mesh.NumVertices(), o.num_threads, [&](int64_t v) {
          if (fits->diagnostics_[v].degree_used < 1) return;
          const SurfaceJet jet = fits->Jet(static_cast<int>(v));
          Eigen::Vector3d n = jet.J.col(0).cross(jet.J.col(1));
          if (n.dot(normals.row(v)) < 0) n = -n;
          if (n.norm() > 0) normals.row(v) = n.normalized();
        });
      }
      fits = std::make_shared<SurfaceFits>();
      if (absl::Status s = FitAll(mesh, topo, o, nb, normals, req, *fits); !s.ok()) return s;
    }
    return std::shared_ptr<const SurfaceFits>(std::move(fits));
  }

 private:
  static absl::Status FitAll(const Mesh& mesh, const Topology& topo, const FitOptions& o,
                             const std::shared_ptr<const Neighborhoods>& nb, const Positions& normals,
                             const FitRequest& req, SurfaceFits& f) {
    const int nv = mesh.NumVertices();
    f.options_ = o;
    f.neighborhoods_ = nb;
    f.frames_.resize(nv);
    f.coefficients_.assign(static_cast<size_t>(nv) * f.dims() * f.num_coefficients(), 0.0);
    f.diagnostics_.assign(nv, VertexDiagnostics{});
    if (req.stencils) {
      f.stencil_offsets_.resize(nv + 1);
      f.stencil_offsets_[0] = 0;
      for (int v = 0; v < nv; ++v)
        f.stencil_offsets_[v + 1] = f.stencil_offsets_[v] + static_cast<size_t>(f.num_coefficients()) * nb->Size(v);
      f.stencils_.assign(f.stencil_offsets_[nv], 0.0);
    }
    const FitInput in{mesh, *nb, normals, o, req.stencils};
    std::atomic<bool> stop{false};
    constexpr int64_t kGrain = 512;
    ParallelFor((nv + kGrain - 1) / kGrain, o.num_threads, [&](int64_t chunk) {
      if (stop.load(std::memory_order_relaxed)) return;
      if (req.cancel && req.cancel->IsCancelled()) {
        stop = true;
        return;
      }
      const int64_t end = std::min<int64_t>(nv, (chunk + 1) * kGrain);
      for (int64_t v = chunk * kGrain; v < end; ++v) {
        if (topo.is_boundary[v]) f.diagnostics_[v].flags |= kFlagBoundary;
        FitOutput out{&f.frames_[v], f.coefficients_.data() + v * f.dims() * f.num_coefficients(),
                      &f.diagnostics_[v], req.stencils ? f.stencils_.data() + f.stencil_offsets_[v] : nullptr};
        FitVertex(static_cast<int>(v), in, out);
      }
    }, 1);
    if (stop) return req.cancel->Check().ok() ? absl::CancelledError("computation cancelled") : req.cancel->Check();
    return absl::OkStatus();
  }
};

absl::StatusOr<std::shared_ptr<const SurfaceFits>> FitSurface(
    const Mesh& mesh, const Topology& topo, const FitOptions& options,
    std::shared_ptr<const Neighborhoods> neighborhoods, const FitRequest& request) {
  return SurfaceFitter::Fit(mesh, topo, options, std::move(neighborhoods), request);
}

}  // namespace geomfit
