#include "core/reconstruction/meshing.h"

#include <algorithm>
#include <map>

#include "absl/strings/str_format.h"
#include "core/util/parallel.h"

namespace geomfit {
namespace {

// Lattice coordinates of a face's corner c and of node t (1..k-1) on its edge c -> c+1.
void EdgeNode(bool tri, int k, int c, int t, int* i, int* j) {
  if (tri) {
    const int ci[3][2] = {{0, 0}, {k, 0}, {0, k}};
    const int dir[3][2] = {{1, 0}, {-1, 1}, {0, -1}};
    *i = ci[c][0] + t * dir[c][0], *j = ci[c][1] + t * dir[c][1];
  } else {
    const int ci[4][2] = {{0, 0}, {k, 0}, {k, k}, {0, k}};
    const int dir[4][2] = {{1, 0}, {0, 1}, {-1, 0}, {0, -1}};
    *i = ci[c][0] + t * dir[c][0], *j = ci[c][1] + t * dir[c][1];
  }
}

bool Inside(bool tri, int k, int i, int j) { return tri ? i + j <= k : i <= k && j <= k; }

}  // namespace

FaceLattices BuildFaceLattices(const Mesh& mesh, const Topology& topo, int k) {
  FaceLattices L;
  L.order = k;
  const int nv = topo.num_vertices, nf = mesh.NumFaces();
  L.offsets.resize(nf + 1, 0);
  for (int f = 0; f < nf; ++f) L.offsets[f + 1] = L.offsets[f] + (mesh.FaceSize(f) == 3 ? (k + 1) * (k + 2) / 2 : (k + 1) * (k + 1));
  L.nodes.assign(L.offsets[nf], -1);
  std::map<std::pair<int, int>, int32_t> edge_first;  // (lo, hi) -> id of the node next to lo
  for (int f = 0; f < nf; ++f) {
    const bool tri = mesh.FaceSize(f) == 3;
    const int n = mesh.FaceSize(f);
    int32_t* ids = L.nodes.data() + L.offsets[f];
    auto at = [&](int i, int j) -> int32_t& { return ids[FaceLattices::Index(tri, k, i, j)]; };
    auto add = [&](double i, double j) {
      L.new_nodes.push_back({f, i / k, j / k});
      return static_cast<int32_t>(nv + L.new_nodes.size() - 1);
    };
    for (int c = 0; c < n; ++c) {
      int i, j;
      EdgeNode(tri, k, c, 0, &i, &j);
      at(i, j) = mesh.faces(f, c);
      const int a = mesh.faces(f, c), b = mesh.faces(f, (c + 1) % n);
      auto key = std::make_pair(std::min(a, b), std::max(a, b));
      auto it = edge_first.find(key);
      if (it == edge_first.end()) {  // first face on this edge numbers its nodes lo -> hi
        int32_t first = -1;
        for (int s = 1; s < k; ++s) {
          const int t = a < b ? s : k - s;
          EdgeNode(tri, k, c, t, &i, &j);
          const int32_t id = add(i, j);
          if (s == 1) first = id;
        }
        it = edge_first.emplace(key, first).first;
      }
      for (int t = 1; t < k; ++t) {  // node t from a; numbered from lo
        EdgeNode(tri, k, c, t, &i, &j);
        at(i, j) = it->second + (a < b ? t - 1 : k - 1 - t);
      }
    }
    for (int j = 1; j < k; ++j)
      for (int i = 1; i < k; ++i)
        if (Inside(tri, k, i, j) && (!tri || i + j < k)) at(i, j) = add(i, j);
  }
  return L;
}

namespace {

absl::StatusOr<Positions> EvaluateLattice(const ReconstructedSurface& surface, const FaceLattices& L,
                                          const RunContext& ctx) {
  const Mesh& mesh = surface.mesh();
  std::vector<SurfacePoint> pts;
  if (absl::Status s = EvaluatePoints(surface, L.new_nodes, &pts, ctx); !s.ok()) return s;
  Positions x(mesh.NumVertices() + pts.size(), 3);
  x.topRows(mesh.NumVertices()) = mesh.positions;
  for (size_t n = 0; n < pts.size(); ++n) x.row(mesh.NumVertices() + n) = pts[n].position.transpose();
  return x;
}

}  // namespace

absl::StatusOr<HighOrderMesh> MakeHighOrderMesh(const ReconstructedSurface& surface, const Topology& topo,
                                                int order, const RunContext& ctx) {
  if (order != 2 && order != 3)
    return absl::InvalidArgumentError(absl::StrFormat("element order %d is not supported (2 or 3)", order));
  const Mesh& mesh = surface.mesh();
  const FaceLattices L = BuildFaceLattices(mesh, topo, order);
  HighOrderMesh out;
  out.order = order;
  auto x = EvaluateLattice(surface, L, ctx);
  if (!x.ok()) return x.status();
  out.nodes = *std::move(x);
  out.offsets.push_back(0);
  for (int f = 0; f < mesh.NumFaces(); ++f) {
    const bool tri = mesh.FaceSize(f) == 3;
    const int n = mesh.FaceSize(f), k = order;
    const int32_t* ids = L.nodes.data() + L.offsets[f];
    auto id = [&](int i, int j) { return ids[FaceLattices::Index(tri, k, i, j)]; };
    int i, j;
    for (int c = 0; c < n; ++c) EdgeNode(tri, k, c, 0, &i, &j), out.elements.push_back(id(i, j));
    for (int c = 0; c < n; ++c)
      for (int t = 1; t < k; ++t) EdgeNode(tri, k, c, t, &i, &j), out.elements.push_back(id(i, j));
    for (int jj = 1; jj < k; ++jj)
      for (int ii = 1; ii < k; ++ii)
        if (!tri || ii + jj < k) out.elements.push_back(id(ii, jj));
    out.offsets.push_back(static_cast<int32_t>(out.elements.size()));
  }
  return out;
}

absl::StatusOr<Mesh> RefineMesh(const ReconstructedSurface& surface, const Topology& topo, int factor,
                                const RunContext& ctx) {
  if (factor < 2 || factor > 8)
    return absl::InvalidArgumentError(absl::StrFormat("refinement factor %d is out of range [2, 8]", factor));
  const Mesh& mesh = surface.mesh();
  const FaceLattices L = BuildFaceLattices(mesh, topo, factor);
  Mesh out;
  auto x = EvaluateLattice(surface, L, ctx);
  if (!x.ok()) return x.status();
  out.positions = *std::move(x);
  std::vector<Eigen::Matrix<int32_t, 1, 4>> faces;
  const int k = factor;
  for (int f = 0; f < mesh.NumFaces(); ++f) {
    const bool tri = mesh.FaceSize(f) == 3;
    const int32_t* ids = L.nodes.data() + L.offsets[f];
    auto id = [&](int i, int j) { return ids[FaceLattices::Index(tri, k, i, j)]; };
    for (int j = 0; j < k; ++j)
      for (int i = 0; i < k; ++i) {
        if (!tri) {
          faces.push_back({id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)});
        } else if (i + j < k) {
          faces.push_back({id(i, j), id(i + 1, j), id(i, j + 1), -1});
          if (i + j < k - 1) faces.push_back({id(i + 1, j), id(i + 1, j + 1), id(i, j + 1), -1});
        }
      }
  }
  Faces& out_faces = out.faces.Mutable();
  out_faces.resize(faces.size(), 4);
  for (size_t f = 0; f < faces.size(); ++f) out_faces.row(f) = faces[f];
  return out;
}

}  // namespace geomfit
