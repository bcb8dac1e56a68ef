#include "core/reconstruction/projection.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Dense>

#include "absl/strings/str_format.h"
#include "core/surfaces/analytic.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

using Eigen::Vector3d;

// Closest point of triangle abc to p as barycentric weights (s, t) of b and c (Ericson,
// Real-Time Collision Detection, 5.1.5).
Eigen::Vector2d ClosestOnTriangle(const Vector3d& p, const Vector3d& a, const Vector3d& b, const Vector3d& c) {
  const Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return {0, 0};
  const Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return {1, 0};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return {d1 / (d1 - d3), 0};
  const Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return {0, 1};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return {0, d2 / (d2 - d6)};
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {1 - w, w};
  }
  const double denom = 1 / (va + vb + vc);
  return {vb * denom, vc * denom};
}

FacePoint Clamp(const Mesh& mesh, FacePoint p) {
  p.xi = std::clamp(p.xi, 0.0, 1.0);
  p.eta = std::clamp(p.eta, 0.0, 1.0);
  if (mesh.FaceSize(p.face) == 3 && p.xi + p.eta > 1) {
    const double s = p.xi + p.eta;
    p.xi /= s;
    p.eta /= s;
  }
  return p;
}

// Gauss-Newton on (xi, eta) towards the closest point of `surface` to x, within the face.
FacePoint Refine(const ReconstructedSurface& surface, const Vector3d& x, FacePoint p, int iterations) {
  for (int it = 0; it < iterations; ++it) {
    const SurfacePoint s = surface.Evaluate(p);
    const Eigen::Matrix2d JtJ = s.jacobian.transpose() * s.jacobian;
    const Eigen::Vector2d step = JtJ.ldlt().solve(s.jacobian.transpose() * (x - s.position));
    if (!step.allFinite()) break;
    p = Clamp(surface.mesh(), {p.face, p.xi + step.x(), p.eta + step.y()});
    if (step.norm() < 1e-15) break;
  }
  return p;
}

}  // namespace

PointLocator::PointLocator(const Mesh& mesh, const Topology& topo) : mesh_(mesh), topo_(topo) {
  lo_ = mesh.positions.colwise().minCoeff().transpose();
  const Vector3d hi = mesh.positions.colwise().maxCoeff().transpose();
  const double h = std::max(AverageEdgeLength(mesh), 1e-12 * std::max(1.0, (hi - lo_).norm()));
  cell_ = 2 * h;
  for (int k = 0; k < 3; ++k) dims_(k) = std::clamp(static_cast<int>((hi(k) - lo_(k)) / cell_) + 1, 1, 1024);
  const int64_t ncells = static_cast<int64_t>(dims_(0)) * dims_(1) * dims_(2);
  std::vector<int32_t> cell_of(mesh.NumVertices());
  cell_offsets_.assign(ncells + 1, 0);
  for (int v = 0; v < mesh.NumVertices(); ++v) {
    Eigen::Vector3i c;
    for (int k = 0; k < 3; ++k) c(k) = std::clamp(static_cast<int>((mesh.positions(v, k) - lo_(k)) / cell_), 0, dims_(k) - 1);
    cell_of[v] = (c(2) * dims_(1) + c(1)) * dims_(0) + c(0);
    ++cell_offsets_[cell_of[v] + 1];
  }
  for (int64_t c = 0; c < ncells; ++c) cell_offsets_[c + 1] += cell_offsets_[c];
  cell_vertices_.resize(mesh.NumVertices());
  std::vector<int32_t> fill(cell_offsets_.begin(), cell_offsets_.end() - 1);
  for (int v = 0; v < mesh.NumVertices(); ++v) cell_vertices_[fill[cell_of[v]]++] = v;
}

int PointLocator::NearestVertex(const Vector3d& x) const {
  Eigen::Vector3i c;
  for (int k = 0; k < 3; ++k) c(k) = std::clamp(static_cast<int>(std::floor((x(k) - lo_(k)) / cell_)), 0, dims_(k) - 1);
  int best = -1;
  double best_d2 = std::numeric_limits<double>::infinity();
  const int max_ring = dims_.maxCoeff();
  for (int r = 0; r <= max_ring; ++r) {
    // Cells at Chebyshev distance r; stop once no closer vertex can lie further out.
    for (int k = std::max(0, c(2) - r); k <= std::min(dims_(2) - 1, c(2) + r); ++k)
      for (int j = std::max(0, c(1) - r); j <= std::min(dims_(1) - 1, c(1) + r); ++j)
        for (int i = std::max(0, c(0) - r); i <= std::min(dims_(0) - 1, c(0) + r); ++i) {
          if (std::max({std::abs(i - c(0)), std::abs(j - c(1)), std::abs(k - c(2))}) != r) continue;
          const int cell = (k * dims_(1) + j) * dims_(0) + i;
          for (int q = cell_offsets_[cell]; q < cell_offsets_[cell + 1]; ++q) {
            const int v = cell_vertices_[q];
            const double d2 = (mesh_.positions.row(v).transpose() - x).squaredNorm();
            if (d2 < best_d2) best_d2 = d2, best = v;
          }
        }
    if (best >= 0 && r * cell_ >= std::sqrt(best_d2) + cell_) break;
  }
  return best;
}

FacePoint PointLocator::Closest(const Vector3d& x) const {
  const int v0 = NearestVertex(x);
  FacePoint best{topo_.NumVertexFaces(v0) ? topo_.VertexFaces(v0)[0] : 0, 0, 0};
  double best_d2 = std::numeric_limits<double>::infinity();
  auto try_face = [&](int f) {
    auto P = [&](int i) -> Vector3d { return mesh_.positions.row(mesh_.faces(f, i)).transpose(); };
    if (mesh_.FaceSize(f) == 3) {
      const Eigen::Vector2d st = ClosestOnTriangle(x, P(0), P(1), P(2));
      const double d2 = (P(0) + st.x() * (P(1) - P(0)) + st.y() * (P(2) - P(0)) - x).squaredNorm();
      if (d2 < best_d2) best_d2 = d2, best = {f, st.x(), st.y()};
      return;
    }
    // Quads: the closer of the triangles (0,1,2), (0,2,3) seeds Gauss-Newton on the bilinear map.
    LinearSurface linear(mesh_);
    const Eigen::Vector2d a = ClosestOnTriangle(x, P(0), P(1), P(2)), b = ClosestOnTriangle(x, P(0), P(2), P(3));
    const Vector3d pa = P(0) + a.x() * (P(1) - P(0)) + a.y() * (P(2) - P(0));
    const Vector3d pb = P(0) + b.x() * (P(2) - P(0)) + b.y() * (P(3) - P(0));
    FacePoint seed = (pa - x).squaredNorm() <= (pb - x).squaredNorm() ? FacePoint{f, a.x() + a.y(), a.y()}
                                                                        : FacePoint{f, b.x(), b.x() + b.y()};
    seed = Refine(linear, x, Clamp(mesh_, seed), 8);
    const double d2 = (linear.Evaluate(seed).position - x).squaredNorm();
    if (d2 < best_d2) best_d2 = d2, best = seed;
  };
  // Faces of the nearest vertex and of its neighbours.
  for (int i = 0; i < topo_.NumVertexFaces(v0); ++i) try_face(topo_.VertexFaces(v0)[i]);
  for (int n = 0; n < topo_.NumNeighbors(v0); ++n) {
    const int w = topo_.Neighbors(v0)[n];
    for (int i = 0; i < topo_.NumVertexFaces(w); ++i) try_face(topo_.VertexFaces(w)[i]);
  }
  return best;
}

absl::Status ProjectPoints(const ReconstructedSurface& surface, const Topology& topo, const Positions& points,
                           std::vector<ProjectedPoint>* out, const RunContext& ctx) {
  for (Eigen::Index i = 0; i < points.rows(); ++i)
    if (!points.row(i).allFinite())
      return absl::InvalidArgumentError(absl::StrFormat("point %d has a non-finite coordinate", i));
  const PointLocator locator(surface.mesh(), topo);
  out->resize(points.rows());
  return ParallelFor(
      points.rows(), ctx,
      [&](int64_t i) {
        const Vector3d x = points.row(i).transpose();
        ProjectedPoint& p = (*out)[i];
        p.where = Refine(surface, x, locator.Closest(x), 6);
        p.point = surface.Evaluate(p.where);
        p.distance = (p.point.position - x).norm();
      },
      64, "project");
}

}  // namespace geomfit
