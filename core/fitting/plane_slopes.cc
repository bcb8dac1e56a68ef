#include "core/fitting/plane_slopes.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Dense>

#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

using Vec3 = Eigen::Vector3d;
using Mat23 = Eigen::Matrix<double, 2, 3>;

// A vertex's plane fit in its frame (pass 1): the gradient g (c10, c01) and the map B from
// the Hessian (h20, h11, h02) to the gradient's O(h) error.
struct PlaneBias {
  Eigen::Vector2d g = Eigen::Vector2d::Zero();
  Mat23 B = Mat23::Zero();
  bool ok = false;
};

Vec3 Position(const Mesh& mesh, int64_t v) { return mesh.positions.row(v).transpose(); }

PlaneBias PlaneWithBias(const Mesh& mesh, const Neighborhoods& nb, const LocalFrame* frames, int v, double cos_cut,
                        double weight_epsilon) {
  PlaneBias out;
  const LocalFrame& fr = frames[v];
  const Vec3 x0 = Position(mesh, v);
  const int32_t* pts = nb.Points(v);
  const int size = nb.Size(v);
  double r2max = 0;  // the stencil's squared radius (2.2.1)
  for (int i = 1; i < size; ++i) {
    if (!(frames[pts[i]].normal.dot(fr.normal) >= cos_cut)) continue;
    const Vec3 d = Position(mesh, pts[i]) - x0;
    r2max = std::max(r2max, std::pow(d.dot(fr.t1), 2) + std::pow(d.dot(fr.t2), 2));
  }
  if (!(r2max > 0)) return out;
  Eigen::Matrix2d A = Eigen::Matrix2d::Zero();
  Eigen::Vector2d b = Eigen::Vector2d::Zero();
  Mat23 M = Mat23::Zero();
  for (int i = 1; i < size; ++i) {
    const double gamma = frames[pts[i]].normal.dot(fr.normal);  // (2.2.1)
    if (!(gamma >= cos_cut)) continue;
    const Vec3 d = Position(mesh, pts[i]) - x0;
    const double u = d.dot(fr.t1), w = d.dot(fr.t2);
    const double wt = gamma * gamma / std::sqrt((u * u + w * w) / r2max + weight_epsilon);  // row weight squared
    const Eigen::Vector2d p(u, w);
    A += wt * p * p.transpose();
    b += wt * d.dot(fr.normal) * p;
    M.col(0) += wt * 0.5 * u * u * p, M.col(1) += wt * u * w * p, M.col(2) += wt * 0.5 * w * w * p;
  }
  if (!(A.determinant() > 1e-12 * A.trace() * A.trace())) return out;
  const Eigen::Matrix2d inv = A.inverse();
  out.g = inv * b, out.B = inv * M, out.ok = true;
  return out;
}

// Pass 2 at vertex v: its corrected unit normal, or false (see plane_slopes.h).
bool CorrectedNormal(const Mesh& mesh, const Neighborhoods& nb, const LocalFrame* frames,
                     const std::vector<PlaneBias>& bias, int v, double cos_cut, Vec3& normal) {
  const LocalFrame& fr = frames[v];
  const PlaneBias& own = bias[v];
  const Vec3 x0 = Position(mesh, v);
  const int32_t* pts = nb.Points(v);
  const int size = nb.Size(v);
  Eigen::Matrix3d N = Eigen::Matrix3d::Zero();
  Eigen::Vector3d r = Eigen::Vector3d::Zero();
  int rows = 0;
  for (int i = 1; i < size; ++i) {
    const int j = pts[i];
    const LocalFrame& fj = frames[j];
    if (!bias[j].ok || !(fj.normal.dot(fr.normal) >= cos_cut)) continue;
    const Vec3 nj = fj.normal - bias[j].g[0] * fj.t1 - bias[j].g[1] * fj.t2;  // j's plain normal (not unit)
    const double nm = nj.dot(fr.normal);
    if (!(nm > 0)) continue;
    const Eigen::Vector2d G(-nj.dot(fr.t1) / nm, -nj.dot(fr.t2) / nm);
    const Vec3 d = Position(mesh, j) - x0;
    const Eigen::Vector2d p(d.dot(fr.t1), d.dot(fr.t2));
    Eigen::Matrix2d R;
    R << fj.t1.dot(fr.t1), fj.t2.dot(fr.t1), fj.t1.dot(fr.t2), fj.t2.dot(fr.t2);
    Mat23 J;  // d(G_j - g) / d(h20, h11, h02)
    for (int k = 0; k < 3; ++k) {
      Eigen::Matrix2d E = Eigen::Matrix2d::Zero();
      E(k / 2, (k + 1) / 2) = E((k + 1) / 2, k / 2) = 1;  // k = 0: (0,0); 1: (0,1), (1,0); 2: (1,1)
      const Eigen::Matrix2d Ej = R.transpose() * E * R;
      J.col(k) = E * p + R * (bias[j].B * Eigen::Vector3d(Ej(0, 0), Ej(0, 1), Ej(1, 1))) - own.B.col(k);
    }
    N += J.transpose() * J;
    r += J.transpose() * (G - own.g);
    ++rows;
  }
  if (rows < 2) return false;
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(N);
  if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 1e-12 * N.trace())) return false;
  const Eigen::Vector2d a = own.g - own.B * ldlt.solve(r);
  const Vec3 n = fr.normal - a[0] * fr.t1 - a[1] * fr.t2;
  const double len = n.norm();
  if (!(len > 0 && len < HUGE_VAL)) return false;
  normal = n / len;
  return true;
}

}  // namespace

absl::Status RefinePlaneNormals(const Mesh& mesh, const Neighborhoods& nb, double cos_cut, double weight_epsilon,
                                const RunContext& ctx, const VertexDiagnostics* diagnostics, LocalFrame* frames,
                                double* coefficients, int num_coefficients) {
  const int64_t nv = mesh.NumVertices();
  std::vector<PlaneBias> bias(nv);
  GF_RETURN_IF_ERROR(ParallelFor(nv, ctx, [&](int64_t v) {
    if (diagnostics[v].degree_used >= 1)
      bias[v] = PlaneWithBias(mesh, nb, frames, static_cast<int>(v), cos_cut, weight_epsilon);
  }));
  std::vector<Vec3> normal(nv);
  std::vector<uint8_t> refined(nv, 0);
  GF_RETURN_IF_ERROR(ParallelFor(nv, ctx, [&](int64_t v) {
    if (bias[v].ok) refined[v] = CorrectedNormal(mesh, nb, frames, bias, static_cast<int>(v), cos_cut, normal[v]);
  }));
  for (int64_t v = 0; v < nv; ++v) {  // the gradient of the corrected normal in the fit's frame
    const LocalFrame& fr = frames[v];
    const double nm = normal[v].dot(fr.normal);
    if (!refined[v] || !(nm > 0)) continue;
    double* c = coefficients + v * num_coefficients;
    c[TaylorIndex(1, 0)] = -normal[v].dot(fr.t1) / nm, c[TaylorIndex(0, 1)] = -normal[v].dot(fr.t2) / nm;
  }
  return absl::OkStatus();
}

}  // namespace geomfit
