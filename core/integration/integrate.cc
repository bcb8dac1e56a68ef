#include "core/integration/integrate.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "core/fitting/wls.h"
#include "core/integration/quadrature.h"
#include "core/reconstruction/features.h"
#include "core/util/parallel.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

absl::Status CheckField(const Eigen::MatrixXd& a, int rows, int cols, const char* name) {
  if (a.size() == 0) return absl::OkStatus();
  if (a.rows() != rows || (cols > 0 && a.cols() != cols))
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s has shape %d x %d; expected %d x %s (one row per vertex)", name, a.rows(), a.cols(), rows,
        cols > 0 ? std::to_string(cols) : "k"));
  for (Eigen::Index i = 0; i < a.rows(); ++i)
    for (Eigen::Index j = 0; j < a.cols(); ++j)
      if (!std::isfinite(a(i, j)))
        return absl::InvalidArgumentError(absl::StrFormat("%s: value at vertex %d, column %d is not finite", name, i, j));
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<Integrals> Integrate(const ReconstructedSurface& surface, const IntegrationInput& in,
                                    const RunContext& ctx) {
  const Mesh& mesh = surface.mesh();
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  if (absl::Status s = CheckField(in.scalars, nv, 0, "scalar field"); !s.ok()) return s;
  if (absl::Status s = CheckField(in.vectors, nv, 3, "vector field"); !s.ok()) return s;
  // Sharp features (4.1.4): the geometry is the feature surface's (faces follow the
  // ridge curves); fields are blended from the one-sided fits over the split mesh (same
  // faces), with nodal values copied to every side of a split vertex.
  const auto* feature = dynamic_cast<const FeatureSurface*>(&surface);
  const ReconstructedSurface& base = feature ? feature->inner() : surface;
  const Mesh& fmesh = base.mesh();  // vertex ids of the field blend
  const auto* walf = dynamic_cast<const WalfSurface*>(&base);
  if (!walf && !dynamic_cast<const LinearSurface*>(&base))
    return absl::InvalidArgumentError(
        "integration supports the linear and WALF surfaces (with or without sharp features) only");
  const int degree = walf ? walf->fits().options().degree : 1;
  const int qdeg = in.quadrature_degree > 0 ? in.quadrature_degree : std::max(4, degree + 2);
  if (qdeg > kMaxQuadratureDegree)
    return absl::InvalidArgumentError(absl::StrFormat(
        "quadrature degree %d is out of range [1, %d]", qdeg, kMaxQuadratureDegree));

  // Nodal fields side by side: scalars, then the vector's three components.
  const int ns = static_cast<int>(in.scalars.cols()), nfield = ns + (in.vectors.size() ? 3 : 0);
  if (ns > 29) return absl::InvalidArgumentError(absl::StrFormat("%d scalar fields; at most 29 per call", ns));
  Eigen::MatrixXd values(nv, nfield);
  if (ns) values.leftCols(ns) = in.scalars;
  if (in.vectors.size()) values.rightCols(3) = in.vectors;
  if (feature && nfield) {
    const std::vector<int32_t>& original = feature->features().split_to_original;
    Eigen::MatrixXd split(static_cast<Eigen::Index>(original.size()), nfield);
    for (size_t v = 0; v < original.size(); ++v) split.row(v) = values.row(original[v]);
    values = std::move(split);
  }

  // WALF fields: per-vertex Taylor coefficients of each field from the stencil
  // operators of the geometry fits (same frames, weights and degree) (4.3.13).
  const int ncoef = NumCoefficients(degree);
  std::vector<double> coef;
  if (walf && nfield) {
    const SurfaceFits& fits = walf->fits();
    if (!fits.has_stencils())
      return absl::FailedPreconditionError("field integration needs fits built with stencil operators");
    coef.assign(static_cast<size_t>(fmesh.NumVertices()) * nfield * ncoef, 0.0);
    GF_RETURN_IF_ERROR(ParallelFor(fmesh.NumVertices(), ctx, [&](int64_t v) {
      const int n = fits.neighborhoods().Size(static_cast<int>(v));
      const int32_t* pts = fits.neighborhoods().Points(static_cast<int>(v));
      const double* S = fits.stencil(static_cast<int>(v));
      for (int f = 0; f < nfield; ++f)
        for (int c = 0; c < ncoef; ++c) {
          double sum = 0;
          for (int k = 0; k < n; ++k) sum += S[c * n + k] * values(pts[k], f);
          coef[(static_cast<size_t>(v) * nfield + f) * ncoef + c] = sum;
        }
    }, 256, "integrate: fields"));
  }

  const QuadratureRule tri = TriangleRule(qdeg), quad = QuadRule(qdeg);
  // Per-face sums, added in face order afterwards: identical for any thread count.
  const int ncol = 3 + nfield;
  Eigen::MatrixXd per_face = Eigen::MatrixXd::Zero(nf, ncol);
  GF_RETURN_IF_ERROR(ParallelFor(nf, ctx, [&](int64_t f) {
    const QuadratureRule& rule = mesh.FaceSize(static_cast<int>(f)) == 3 ? tri : quad;
    double N[4], dNa[4], dNb[4], phi[32];
    for (int q = 0; q < rule.size(); ++q) {
      const FacePoint fp{static_cast<int32_t>(f), rule.xi[q], rule.eta[q]};
      const SurfacePoint sp = surface.Evaluate(fp);
      const Eigen::Vector3d n = sp.jacobian.col(0).cross(sp.jacobian.col(1));  // j1 x j2 (4.3.4)
      const double w = rule.weight[q];
      per_face(f, 0) += w * n.norm();                   // area (4.3.2)
      per_face(f, 1) += w * sp.position.dot(n) / 3.0;   // volume (4.3.16)
      if (!nfield) continue;
      const int nn = ShapeFunctions(fmesh, fp.face, fp.xi, fp.eta, N, dNa, dNb);
      std::fill(phi, phi + nfield, 0.0);
      Eigen::Vector3d x = Eigen::Vector3d::Zero();
      double lin[32] = {};  // the linear interpolant of the fields
      for (int i = 0; i < nn; ++i) {
        x += N[i] * fmesh.positions.row(fmesh.faces(f, i)).transpose();
        for (int k = 0; k < nfield; ++k) lin[k] += N[i] * values(fmesh.faces(f, i), k);
      }
      if (!walf) std::copy(lin, lin + nfield, phi);
      for (int i = 0; walf && i < nn; ++i) {
        const int v = fmesh.faces(f, i);
        const LocalFrame& fr = walf->fits().frame(v);
        const double u = (x - fr.origin).dot(fr.t1), t = (x - fr.origin).dot(fr.t2);
        // A degree-1 vertex contributes the mean of its plane and the linear interpolant,
        // whose O(h^2) errors cancel, as for the geometry (WalfSurface::Evaluate).
        const bool planar = walf->fits().diagnostics(v).degree_used == 1;
        for (int k = 0; k < nfield; ++k) {
          double val;
          EvalTaylor(&coef[(static_cast<size_t>(v) * nfield + k) * ncoef], degree, u, t, &val, nullptr, nullptr);
          phi[k] += N[i] * (planar ? 0.5 * (val + lin[k]) : val);
        }
      }
      for (int k = 0; k < ns; ++k) per_face(f, 3 + k) += w * phi[k] * n.norm();
      if (in.vectors.size()) per_face(f, 2) += w * Eigen::Vector3d(phi[ns], phi[ns + 1], phi[ns + 2]).dot(n);
    }
  }, 64, "integrate"));
  Integrals out;
  out.quadrature_points = tri.size();
  out.scalars.assign(ns, 0.0);
  for (int f = 0; f < nf; ++f) {
    out.area += per_face(f, 0);
    out.volume += per_face(f, 1);
    out.flux += per_face(f, 2);
    for (int k = 0; k < ns; ++k) out.scalars[k] += per_face(f, 3 + k);
  }
  if (!in.area) out.area = 0;
  if (!in.volume) out.volume = 0;
  return out;
}

}  // namespace geomfit
