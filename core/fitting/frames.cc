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

Positions ApproximateVertexNormals(const Mesh& mesh, const Topology& /*topo*/,
                                   NormalWeighting weighting, int num_threads) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  Positions normals = Positions::Zero(nv, 3);
  // Corner normals summed face by face (the faces are read in storage order, not
  // through each vertex's fan: on a mesh numbered in any order that was a cache miss per
  // face). Each vertex receives its corners in increasing face order, the order of
  // topo.VertexFaces, so its sum is the per-vertex loop's bit for bit. A thread owns a
  // range of vertices and scans every face for its corners.
  const double* P = mesh.positions.data();
  ParallelForBlocks(nv, num_threads, [&](int64_t begin, int64_t end, int) {
    for (int f = 0; f < nf; ++f) {
      const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
      const int n = idx[3] < 0 ? 3 : 4;
      for (int c = 0; c < n; ++c) {
        const int32_t v = idx[c];
        if (v < begin || v >= end) continue;
        using Vec = Eigen::Map<const Eigen::Vector3d>;
        const Eigen::Vector3d x = Vec(P + 3 * static_cast<int64_t>(v));
        const Eigen::Vector3d a = Vec(P + 3 * static_cast<int64_t>(idx[c + 1 < n ? c + 1 : 0])) - x;
        const Eigen::Vector3d b = Vec(P + 3 * static_cast<int64_t>(idx[c > 0 ? c - 1 : n - 1])) - x;
        const Eigen::Vector3d cr = a.cross(b);  // corner normal, |cr| = 2 x corner triangle area
        double* sum = normals.data() + 3 * static_cast<int64_t>(v);
        if (weighting == NormalWeighting::kArea) {
          for (int k = 0; k < 3; ++k) sum[k] += cr[k];
        } else {
          const double len = cr.norm();
          if (len > 0) {
            const Eigen::Vector3d w = std::atan2(len, a.dot(b)) * cr / len;
            for (int k = 0; k < 3; ++k) sum[k] += w[k];
          }
        }
      }
    }
    for (int64_t v = begin; v < end; ++v) {
      const Eigen::Vector3d sum = normals.row(v).transpose();
      const double len = sum.norm();
      normals.row(v) = len > 0 ? Eigen::Vector3d(sum / len) : Eigen::Vector3d::Zero();
    }
  });
  return normals;
}

}  // namespace geomfit
