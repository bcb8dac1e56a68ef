#include "core/fitting/frames.h"

#include <cmath>
#include <memory>
#include <vector>

#include "core/util/parallel.h"

namespace geomfit {

Eigen::Vector3d FaceNormal(const Mesh& mesh, int f) {
  auto p = [&](int i) -> Eigen::Vector3d { return mesh.positions.row(mesh.faces(f, i)).transpose(); };
  Eigen::Vector3d n = mesh.FaceSize(f) == 3 ? (p(1) - p(0)).cross(p(2) - p(0))
                                            : (p(2) - p(0)).cross(p(3) - p(1));
  const double len = n.norm();
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

namespace {

constexpr int kMaxOwnerThreads = 64;

/// The face-order corner sums on `threads` threads without each scanning every face:
/// thread t owns the vertices v with (v * mul) >> 32 == t (contiguous ranges). The
/// faces are split in `threads` blocks; each block lists its corners (4 f + c, in
/// face then corner order) by owner, then each owner adds its corners block by block:
/// every vertex gets its corners in increasing face order, as the serial scan adds
/// them (the same sums bit for bit). Then each owner normalizes its vertices.
template <typename AddCorner>
void CornerSumsByOwner(const Mesh& mesh, int threads, const AddCorner& add_corner, double* sums) {
  const int64_t nv = mesh.NumVertices(), nf = mesh.NumFaces();
  const uint64_t mul = (static_cast<uint64_t>(threads) << 32) / static_cast<uint64_t>(nv);
  const auto owner = [mul](int32_t v) { return static_cast<int>((static_cast<uint64_t>(v) * mul) >> 32); };
  const int32_t* faces = mesh.faces.data();
  // count[b * threads + t]: corners of face block b owned by t; then their list's start.
  std::vector<int64_t> count(static_cast<size_t>(threads) * threads + 1, 0);
  ParallelForBlocks(nf, threads, [&](int64_t begin, int64_t end, int b) {
    int64_t* c = count.data() + static_cast<int64_t>(b) * threads;
    for (int64_t f = begin; f < end; ++f) {
      const int32_t* idx = faces + 4 * f;
      for (int k = 0; k < 3; ++k) ++c[owner(idx[k])];
      if (idx[3] >= 0) ++c[owner(idx[3])];
    }
  });
  // Lists ordered owner-major: owner t's lists of blocks 0, 1, ... are contiguous.
  std::vector<int64_t> start(count.size());
  int64_t at = 0;
  for (int t = 0; t < threads; ++t)
    for (int b = 0; b < threads; ++b) start[b * threads + t] = at, at += count[b * threads + t];
  start.back() = at;
  std::unique_ptr<uint32_t[]> corners(new uint32_t[at]);
  ParallelForBlocks(nf, threads, [&](int64_t begin, int64_t end, int b) {
    int64_t cursor[kMaxOwnerThreads];
    for (int t = 0; t < threads; ++t) cursor[t] = start[b * threads + t];
    for (int64_t f = begin; f < end; ++f) {
      const int32_t* idx = faces + 4 * f;
      const uint32_t e = static_cast<uint32_t>(4 * f);
      for (int k = 0; k < 3; ++k) corners[cursor[owner(idx[k])]++] = e + k;
      if (idx[3] >= 0) corners[cursor[owner(idx[3])]++] = e + 3;
    }
  });
  const double* P = mesh.positions.data();
  ParallelForBlocks(threads, threads, [&](int64_t t, int64_t, int) {
    const int64_t first = start[t], last = t + 1 < threads ? start[t + 1] : at;
    for (int64_t i = first; i < last; ++i) {
      if (i + 8 < last) {  // the corner's position and sum 8 ahead: random reads
        const int64_t w = faces[corners[i + 8]];
        __builtin_prefetch(P + 3 * w);
        __builtin_prefetch(sums + 3 * w, 1);
      }
      const uint32_t e = corners[i];
      const int32_t* idx = faces + (e & ~3u);
      add_corner(idx, idx[3] < 0 ? 3 : 4, static_cast<int>(e & 3));
    }
    // Its vertices: [lo, hi) with lo the first v whose (v * mul) >> 32 reaches t.
    const auto lo = [&](int64_t u) {
      return std::min<int64_t>(nv, static_cast<int64_t>(((static_cast<uint64_t>(u) << 32) + mul - 1) / mul));
    };
    for (int64_t v = lo(t), hi = lo(t + 1); v < hi; ++v) {
      Eigen::Map<Eigen::Vector3d> n(sums + 3 * v);
      const Eigen::Vector3d sum = n;
      const double len = sum.norm();
      n = len > 0 ? Eigen::Vector3d(sum / len) : Eigen::Vector3d::Zero();
    }
  });
}

}  // namespace

Positions ApproximateVertexNormals(const Mesh& mesh, const Topology& topo, NormalWeighting weighting,
                                   int num_threads) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  Positions normals = Positions::Zero(nv, 3);
  const double* P = mesh.positions.data();
  // Adds the normal of corner c of face row idx (n corners) to its vertex's sum.
  auto add_corner = [&](const int32_t* idx, int n, int c) {
    using Vec = Eigen::Map<const Eigen::Vector3d>;
    const int32_t v = idx[c];
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
  };
  // Each vertex sums its corner normals in the order of topo.VertexFaces. When those
  // rows are in increasing face order (a mesh's own topology) the faces are read in
  // storage order and each corner added to its vertex, instead of walking each vertex's
  // fan (on a mesh numbered in any order that was a cache miss per face): the same sums
  // bit for bit. A thread owns a range of vertices and scans every face for its corners.
  // Otherwise (a LocalityRelabelling's topology, rows in the source's face order, faces
  // stored near their vertices) each vertex walks its fan.
  const bool face_order = topo.vertex_faces_ascending || topo.num_vertices != nv;
  const int threads = static_cast<int>(std::min<int64_t>(ResolveThreads(num_threads), nv));
  if (face_order && threads > 1 && threads <= kMaxOwnerThreads && nf < (1 << 29)) {
    CornerSumsByOwner(mesh, threads, add_corner, normals.data());
    return normals;
  }
  ParallelForBlocks(nv, num_threads, [&](int64_t begin, int64_t end, int) {
    if (face_order) {
      for (int f = 0; f < nf; ++f) {
        const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(f);
        if (f + 8 < nf) {  // the corners' positions and sums 8 faces ahead: random reads
          const int32_t* ahead = idx + 32;
          for (int c = 0; c < 3; ++c) {
            __builtin_prefetch(P + 3 * static_cast<int64_t>(ahead[c]));
            __builtin_prefetch(normals.data() + 3 * static_cast<int64_t>(ahead[c]), 1);
          }
        }
        const int n = idx[3] < 0 ? 3 : 4;
        for (int c = 0; c < n; ++c)
          if (idx[c] >= begin && idx[c] < end) add_corner(idx, n, c);
      }
    } else {
      for (int64_t v = begin; v < end; ++v)
        for (int j = 0; j < topo.NumVertexFaces(static_cast<int>(v)); ++j) {
          const int32_t* idx = mesh.faces.data() + 4 * static_cast<int64_t>(topo.VertexFaces(static_cast<int>(v))[j]);
          // v's corner, branch-free (rows start at any corner of an irregular mesh)
          const int c = (idx[1] == v) + 2 * (idx[2] == v) + 3 * (idx[3] == v);
          add_corner(idx, idx[3] < 0 ? 3 : 4, c);
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
