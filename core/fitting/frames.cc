#include "core/fitting/frames.h"

#include <cmath>

#include "core/util/parallel.h"

namespace geomfit {

LocalFrame FrameFromNormal(const Eigen::Vector3d& origin, const Eigen::Vector3d& n) {
  LocalFrame fr;
  fr.origin = origin;
  fr.normal = n;
  // Tangent from the coordinate axis least aligned with n (well conditioned).
  int axis = 0;
  n.cwiseAbs().minCoeff(&axis);
  Eigen::Vector3d a = Eigen::Vector3d::Unit(axis);
  fr.t1 = (a - a.dot(n) * n).normalized();
  fr.t2 = n.cross(fr.t1);
  return fr;
}

Eigen::Vector3d FaceNormal(const Mesh& mesh, int f) {
  auto p = [&](int i) -> Eigen::Vector3d { return mesh.positions.row(mesh.faces(f, i)).transpose(); };
  Eigen::Vector3d n = mesh.FaceSize(f) == 3 ? (p(1) - p(0)).cross(p(2) - p(0))
                                            : (p(2) - p(0)).cross(p(3) - p(1));
  const double len = n.norm();
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

Positions ApproximateVertexNormals(const Mesh& mesh, const Topology& topo,
                                   NormalWeighting weighting, int num_threads) {
  Positions normals(mesh.NumVertices(), 3);
  ParallelFor(mesh.NumVertices(), num_threads, [&](int64_t v) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    const Eigen::Vector3d x = mesh.positions.row(v).transpose();
    for (int i = 0; i < topo.NumVertexFaces(v); ++i) {
      const int f = topo.VertexFaces(v)[i];
      int c = 0;
      while (mesh.faces(f, c) != v) ++c;
      const Eigen::Vector3d a = mesh.positions.row(mesh.Next(f, c)).transpose() - x;
      const Eigen::Vector3d b = mesh.positions.row(mesh.Prev(f, c)).transpose() - x;
      const Eigen::Vector3d cr = a.cross(b);  // corner normal, |cr| = 2 x corner triangle area
      if (weighting == NormalWeighting::kArea) {
        sum += cr;
      } else {
        const double len = cr.norm();
        if (len > 0) sum += std::atan2(len, a.dot(b)) * cr / len;
      }
    }
    const double len = sum.norm();
    normals.row(v) = len > 0 ? Eigen::Vector3d(sum / len) : Eigen::Vector3d::Zero();
  });
  return normals;
}

}  // namespace geomfit
