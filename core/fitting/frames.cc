#include "core/fitting/frames.h"

#include <cmath>

#include "core/util/parallel.h"

namespace geomfit {

Eigen::Vector3d FaceNormal(const Mesh& mesh, int f) {
  auto p = [&](int i) -> Eigen::Vector3d { return mesh.positions.row(mesh.faces(f, i)).transpose(); };
  Eigen::Vector3d n = mesh.FaceSize(f) == 3 ? (p(1) - p(0)).cross(p(2) - p(0))
                                            : (p(2) - p(0)).cross(p(3) - p(1));
  const double len = n.norm();
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

Positions ApproximateVertexNormals(const Mesh& mesh, const Topology& topo, NormalWeighting weighting,
                                   int num_threads) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  // Each vertex sums its corner normals in the order of topo.VertexFaces. When those
  // rows are in increasing face order (a mesh's own topology) the faces are read in
  // storage order and each corner added to its vertex, instead of walking each vertex's
  // fan (on a mesh numbered in any order that was a cache miss per face): the same sums
  // bit for bit. A thread owns a range of vertices and scans every face for its corners.
  // Otherwise (a LocalityRelabelling's topology, rows in the source's face order, faces
  // stored near their vertices) each vertex walks its fan, its sum in registers; rows in
  // fan order (Topology::fan_rows) give each corner's two other ends as neighbours.
  const bool face_order = topo.vertex_faces_ascending || topo.num_vertices != nv;
  Positions normals(nv, 3);
  if (face_order) normals.setZero();
  const double* P = mesh.positions.data();
  // The normal of the corner at v between the spokes `after` and `before` (the corners
  // after and before v in its face), added to sum[0..3).
  auto add_spokes = [&](int32_t v, int32_t after, int32_t before, double* sum) __attribute__((always_inline)) {
    using Vec = Eigen::Map<const Eigen::Vector3d>;
    const Eigen::Vector3d x = Vec(P + 3 * static_cast<int64_t>(v));
    const Eigen::Vector3d a = Vec(P + 3 * static_cast<int64_t>(after)) - x;
    const Eigen::Vector3d b = Vec(P + 3 * static_cast<int64_t>(before)) - x;
    const Eigen::Vector3d cr = a.cross(b);  // corner normal, |cr| = 2 x corner triangle area
    if (weighting == NormalWeighting::kArea) {
      for (int k = 0; k < 3; ++k) sum[k] += cr[k];
    } else {
      const double len = cr.norm();
      if (len > 0) {
        const Eigen::Vector3d w = std::atan2(len, a.dot(b)) * cr / len;
        for (int k = 0; k < 3; ++k) sum[k] += w[k];
      }
    }
  };
  // The normal of corner c of face row idx (n corners), added to sum[0..3).
  auto add_corner = [&](const int32_t* idx, int n, int c, double* sum) __attribute__((always_inline)) {
    add_spokes(idx[c], idx[c + 1 < n ? c + 1 : 0], idx[c > 0 ? c - 1 : n - 1], sum);
  };
  auto store_unit = [&](int64_t v, const double* sum) {
    const Eigen::Vector3d s(sum[0], sum[1], sum[2]);
    const double len = s.norm();
    normals.row(v) = len > 0 ? Eigen::Vector3d(s / len) : Eigen::Vector3d::Zero();
  };
  ParallelForBlocks(nv, num_threads, [&](int64_t begin, int64_t end, int) {
    if (face_order) {
      double* const sums = normals.data();
      for (int f = 0; f < nf; ++f) {
        const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
        if (f + 8 < nf) {  // the corners' positions and sums 8 faces ahead: random reads
          const int32_t* ahead = idx + 32;
          for (int c = 0; c < 3; ++c) {
            __builtin_prefetch(P + 3 * static_cast<int64_t>(ahead[c]));
            __builtin_prefetch(sums + 3 * static_cast<int64_t>(ahead[c]), 1);
          }
        }
        const int n = idx[3] < 0 ? 3 : 4;
        for (int c = 0; c < n; ++c)
          if (idx[c] >= begin && idx[c] < end) add_corner(idx, n, c, sums + 3 * static_cast<int64_t>(idx[c]));
      }
      for (int64_t v = begin; v < end; ++v) store_unit(v, sums + 3 * v);
    } else if (topo.fan_rows) {
      // Rows in fan order: each corner's spokes are consecutive neighbours (no face row
      // read, no corner search), the corners in the same order as VertexFaces.
      for (int64_t v = begin; v < end; ++v) {
        double sum[3] = {0, 0, 0};
        const int32_t* spoke = topo.Neighbors(static_cast<int>(v));
        const int m = topo.NumNeighbors(static_cast<int>(v));
        for (int j = 0, nj = topo.NumVertexFaces(static_cast<int>(v)); j < nj; ++j)
          add_spokes(static_cast<int32_t>(v), spoke[j], spoke[j + 1 < m ? j + 1 : 0], sum);
        store_unit(v, sum);
      }
    } else {
      for (int64_t v = begin; v < end; ++v) {
        double sum[3] = {0, 0, 0};  // as the zeroed rows of the face-order path
        const int32_t* fan = topo.VertexFaces(static_cast<int>(v));
        for (int j = 0, nj = topo.NumVertexFaces(static_cast<int>(v)); j < nj; ++j) {
          const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(fan[j]);
          // v's corner, branch-free (rows start at any corner of an irregular mesh)
          const int c = (idx[1] == v) + 2 * (idx[2] == v) + 3 * (idx[3] == v);
          add_corner(idx, idx[3] < 0 ? 3 : 4, c, sum);
        }
        store_unit(v, sum);
      }
    }
  });
  return normals;
}

}  // namespace geomfit
