#include "core/reconstruction/surface.h"

#include <algorithm>
#include <cmath>
#include <random>

#include "absl/strings/str_format.h"
#include "core/fitting/wls.h"
#include "core/quantities/differentials.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

using Eigen::Vector3d;

// The linear point of a face and its derivatives in natural coordinates.
struct LinearPoint {
  int n;
  double N[4], dNdxi[4], dNdeta[4];
  Vector3d x, dxi, deta;
};

LinearPoint Linear(const Mesh& mesh, const FacePoint& p) {
  LinearPoint l;
  l.n = ShapeFunctions(mesh, p.face, p.xi, p.eta, l.N, l.dNdxi, l.dNdeta);
  l.x = l.dxi = l.deta = Vector3d::Zero();
  for (int i = 0; i < l.n; ++i) {
    const Vector3d xi = mesh.positions.row(mesh.faces(p.face, i)).transpose();
    l.x += l.N[i] * xi;
    l.dxi += l.dNdxi[i] * xi;
    l.deta += l.dNdeta[i] * xi;
  }
  return l;
}

}  // namespace

int ShapeFunctions(const Mesh& mesh, int face, double xi, double eta, double N[4], double dNdxi[4],
                   double dNdeta[4]) {
  if (mesh.FaceSize(face) == 3) {
    N[0] = 1 - xi - eta, N[1] = xi, N[2] = eta;
    dNdxi[0] = -1, dNdxi[1] = 1, dNdxi[2] = 0;
    dNdeta[0] = -1, dNdeta[1] = 0, dNdeta[2] = 1;
    return 3;
  }
  N[0] = (1 - xi) * (1 - eta), N[1] = xi * (1 - eta), N[2] = xi * eta, N[3] = (1 - xi) * eta;
  dNdxi[0] = -(1 - eta), dNdxi[1] = 1 - eta, dNdxi[2] = eta, dNdxi[3] = -eta;
  dNdeta[0] = -(1 - xi), dNdeta[1] = -xi, dNdeta[2] = xi, dNdeta[3] = 1 - xi;
  return 4;
}

absl::Status ValidateFacePoint(const Mesh& mesh, const FacePoint& p, int64_t index) {
  if (p.face < 0 || p.face >= mesh.NumFaces())
    return absl::InvalidArgumentError(absl::StrFormat(
        "point %d: face %d is out of range [0, %d)", index, p.face, mesh.NumFaces()));
  if (!std::isfinite(p.xi) || !std::isfinite(p.eta))
    return absl::InvalidArgumentError(absl::StrFormat("point %d: coordinates are not finite", index));
  constexpr double tol = 1e-9;
  const bool tri = mesh.FaceSize(p.face) == 3;
  const bool inside = tri ? (p.xi >= -tol && p.eta >= -tol && p.xi + p.eta <= 1 + tol)
                          : (p.xi >= -tol && p.eta >= -tol && p.xi <= 1 + tol && p.eta <= 1 + tol);
  if (!inside)
    return absl::InvalidArgumentError(absl::StrFormat(
        "point %d: natural coordinates (%g, %g) lie outside %s face %d (%s)", index, p.xi, p.eta,
        tri ? "triangle" : "quad", p.face, tri ? "need xi, eta >= 0 and xi + eta <= 1" : "need xi, eta in [0, 1]"));
  return absl::OkStatus();
}

SurfacePoint LinearSurface::Evaluate(const FacePoint& p) const {
  const LinearPoint l = Linear(mesh_, p);
  SurfacePoint s;
  s.position = l.x;
  s.jacobian << l.dxi, l.deta;
  s.normal = l.dxi.cross(l.deta).normalized();
  return s;
}

SurfacePoint WalfSurface::Evaluate(const FacePoint& p) const {
  const LinearPoint l = Linear(mesh_, p);
  SurfacePoint s;
  s.position.setZero();
  s.jacobian.setZero();
  Vector3d normal = Vector3d::Zero();
  for (int i = 0; i < l.n; ++i) {
    const int v = mesh_.faces(p.face, i);
    // q_i: vertex i's fit at the projection of the linear point onto its frame (4.1.1).
    SurfaceFits::LocalPoint q = fits_->Evaluate(v, l.x);
    const LocalFrame& fr = fits_->frame(v);
    // d q_i / d xi = q_u (t1 . dx/dxi) + q_v (t2 . dx/dxi), plus the shape-function term.
    Vector3d dqdxi = q.du * fr.t1.dot(l.dxi) + q.dv * fr.t2.dot(l.dxi);
    Vector3d dqdeta = q.du * fr.t1.dot(l.deta) + q.dv * fr.t2.dot(l.deta);
    if (fits_->diagnostics(v).degree_used == 1) {
      // A tangent plane over-shoots the surface by as much as the chord under-shoots it:
      // for a quadratic surface sum_i N_i (plane_i - f)(x) = -1/2 sum_i N_i |x - x_i|^2_H,
      // the linear interpolant's error with the opposite sign. Their mean cancels the
      // O(h^2) term, so a degree-1 vertex contributes (x + q_i) / 2.
      q.position = 0.5 * (l.x + q.position);
      dqdxi = 0.5 * (l.dxi + dqdxi);
      dqdeta = 0.5 * (l.deta + dqdeta);
    }
    s.position += l.N[i] * q.position;  // (4.3.11)
    s.jacobian.col(0) += l.dNdxi[i] * q.position + l.N[i] * dqdxi;
    s.jacobian.col(1) += l.dNdeta[i] * q.position + l.N[i] * dqdeta;
    normal += l.N[i] * q.normal;  // (4.3.12)
  }
  s.normal = normal * (1 / std::sqrt(normal.squaredNorm()));
  return s;
}

CmfSurface::CmfSurface(const Mesh& mesh, std::shared_ptr<const SurfaceFits> fits, int threads)
    : mesh_(mesh), fits_(std::move(fits)), normals_(mesh.NumVertices(), 3) {
  ParallelFor(mesh.NumVertices(), threads, [&](int64_t v) {
    const int iv = static_cast<int>(v);
    const Vector3d n = fits_->diagnostics(iv).degree_used >= 1 ? DifferentialsFromJet(fits_->Jet(iv)).normal
                                                               : fits_->frame(iv).normal;
    normals_.row(v) = n.transpose();
  });
}

SurfacePoint CmfSurface::Evaluate(const FacePoint& p) const {
  const LinearPoint l = Linear(mesh_, p);
  const FitOptions& o = fits_->options();
  const int nv = l.n;
  // Moving frame from the blended vertex normals (4.1.6).
  Vector3d n = Vector3d::Zero();
  int verts[4];
  for (int i = 0; i < nv; ++i) {
    verts[i] = mesh_.faces(p.face, i);
    n += l.N[i] * normals_.row(verts[i]).transpose();
  }
  n.normalize();
  const LocalFrame frame = FrameFromNormal(l.x, n);
  // Union of the vertex stencils; gamma_j = sum_i (n_i . n_j)^+ over the stencils that
  // hold j (4.1.8)-(4.1.9), the distance factor being applied by SolveWls.
  const double eta = std::cos(o.safeguard_angle_deg * M_PI / 180.0);
  int32_t ids[4 * kMaxStencil];
  int count = 0;
  for (int i = 0; i < nv; ++i) {
    const Neighborhoods& stencils = fits_->neighborhoods();
    for (int k = 0; k < stencils.Size(verts[i]); ++k) ids[count++] = stencils.Points(verts[i])[k];
  }
  std::sort(ids, ids + count);
  count = static_cast<int>(std::unique(ids, ids + count) - ids);
  struct Candidate {
    int j;
    double gamma, dist2;
  };
  Candidate cand[4 * kMaxStencil];
  int nc = 0;
  const Neighborhoods& nb = fits_->neighborhoods();
  for (int k = 0; k < count; ++k) {
    const int j = ids[k];
    double gamma = 0;
    for (int i = 0; i < nv; ++i) {
      const int32_t* pts = nb.Points(verts[i]);
      if (std::find(pts, pts + nb.Size(verts[i]), j) == pts + nb.Size(verts[i])) continue;
      const double c = normals_.row(verts[i]).dot(normals_.row(j));
      if (c >= eta) gamma += c;
    }
    if (gamma > 0) cand[nc++] = {j, gamma, (mesh_.positions.row(j).transpose() - l.x).squaredNorm()};
  }
  if (nc > kMaxStencil) {  // a huge union: keep the nearest points
    std::nth_element(cand, cand + kMaxStencil, cand + nc,
                     [](const Candidate& a, const Candidate& b) { return a.dist2 < b.dist2; });
    nc = kMaxStencil;
  }
  WlsProblem P;
  P.dims = 1;
  P.rows = nc;
  for (int r = 0; r < nc; ++r) {
    const Vector3d d = mesh_.positions.row(cand[r].j).transpose() - l.x;
    P.u[r] = d.dot(frame.t1);
    P.v[r] = d.dot(frame.t2);
    P.rhs[0][r] = d.dot(frame.normal);
    P.gamma[r] = cand[r].gamma;
  }
  WlsSettings S;
  S.degree = o.degree;
  S.interpolate = false;  // the origin is not a data point
  S.weight_epsilon = o.weight_epsilon;
  S.cond_threshold = o.cond_threshold;
  S.oscillation_safeguard = o.oscillation_safeguard;
  double c[kMaxCoefficients];
  const WlsSolution sol = SolveWls(P, S, c);
  SurfacePoint s;
  if (sol.degree_used < 1) {  // no usable fit: the linear point
    s.position = l.x;
    s.normal = n;
  } else {
    s.position = l.x + c[0] * frame.normal;
    s.normal = (frame.normal - c[1] * frame.t1 - c[2] * frame.t2).normalized();
  }
  // Jacobian of the CMF surface is not evaluated in closed form; the linear map's
  // derivatives projected onto the CMF tangent plane approximate it to O(h^2).
  const Eigen::Matrix3d proj = Eigen::Matrix3d::Identity() - s.normal * s.normal.transpose();
  s.jacobian << proj * l.dxi, proj * l.deta;
  return s;
}

std::unique_ptr<ReconstructedSurface> MakeSurface(ReconstructionMethod method, const Mesh& mesh,
                                                  std::shared_ptr<const SurfaceFits> fits, int threads) {
  switch (method) {
    case ReconstructionMethod::kWalf: return std::make_unique<WalfSurface>(mesh, std::move(fits));
    case ReconstructionMethod::kCmf: return std::make_unique<CmfSurface>(mesh, std::move(fits), threads);
    case ReconstructionMethod::kLinear: break;
  }
  return std::make_unique<LinearSurface>(mesh);
}

std::vector<FacePoint> RandomFacePoints(const Mesh& mesh, int per_face, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0, 1);
  std::vector<FacePoint> pts;
  pts.reserve(static_cast<size_t>(mesh.NumFaces()) * per_face);
  for (int f = 0; f < mesh.NumFaces(); ++f)
    for (int k = 0; k < per_face; ++k) {
      double a = unit(rng), b = unit(rng);
      if (mesh.FaceSize(f) == 3 && a + b > 1) a = 1 - a, b = 1 - b;  // fold into the triangle
      pts.push_back({f, a, b});
    }
  return pts;
}

absl::Status EvaluatePoints(const ReconstructedSurface& surface, const std::vector<FacePoint>& points,
                            std::vector<SurfacePoint>* out, const RunContext& ctx) {
  for (size_t i = 0; i < points.size(); ++i) {
    absl::Status s = ValidateFacePoint(surface.mesh(), points[i], static_cast<int64_t>(i));
    if (!s.ok()) return s;
  }
  out->resize(points.size());
  return ParallelFor(
      static_cast<int64_t>(points.size()), ctx, [&](int64_t i) { (*out)[i] = surface.Evaluate(points[i]); }, 256,
      "evaluate points");
}

}  // namespace geomfit
