#include "core/reconstruction/features.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include <Eigen/Dense>

#include "absl/strings/str_format.h"
#include "core/fitting/frames.h"

namespace geomfit {
namespace {

using Eigen::Vector3d;
using Edge = std::pair<int32_t, int32_t>;

Edge Key(int a, int b) { return {std::min(a, b), std::max(a, b)}; }

int Find(std::vector<int>& parent, int i) {
  while (parent[i] != i) i = parent[i] = parent[parent[i]];
  return i;
}

// Ridge curves: chains of feature edges from corner to corner, then closed loops.
std::vector<std::vector<int32_t>> TraceCurves(int nv, const std::vector<Edge>& edges, const std::vector<int32_t>& valence) {
  std::vector<std::vector<int32_t>> adj(nv);
  for (auto [a, b] : edges) adj[a].push_back(b), adj[b].push_back(a);
  std::map<Edge, bool> used;
  std::vector<std::vector<int32_t>> curves;
  auto walk = [&](int start, int next) {
    std::vector<int32_t> c = {start};
    int prev = start, cur = next;
    used[Key(prev, cur)] = true;
    while (true) {
      c.push_back(cur);
      if (valence[cur] != 2 || cur == start) break;
      const int nxt = adj[cur][0] == prev ? adj[cur][1] : adj[cur][0];
      if (used[Key(cur, nxt)]) break;
      used[Key(cur, nxt)] = true;
      prev = cur, cur = nxt;
    }
    curves.push_back(std::move(c));
  };
  for (int v = 0; v < nv; ++v)
    if (valence[v] != 2)
      for (int w : adj[v])
        if (!used[Key(v, w)]) walk(v, w);
  for (auto [a, b] : edges)
    if (!used[Key(a, b)]) walk(a, b);  // closed loops: first vertex repeated at the end
  return curves;
}

}  // namespace

bool Features::IsFeature(int a, int b) const { return std::binary_search(edges.begin(), edges.end(), Key(a, b)); }

absl::StatusOr<Features> DetectFeatures(const Mesh& mesh, const Topology& topo, const FeatureOptions& o) {
  if (!(o.angle_deg > 0 && o.angle_deg <= 180))
    return absl::InvalidArgumentError(absl::StrFormat("feature angle %g is out of range (0, 180]", o.angle_deg));
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  std::map<Edge, std::vector<int>> edge_faces;
  for (int f = 0; f < nf; ++f)
    for (int i = 0, n = mesh.FaceSize(f); i < n; ++i) edge_faces[Key(mesh.faces(f, i), mesh.faces(f, (i + 1) % n))].push_back(f);
  Features F;
  const double cos_cut = std::cos(o.angle_deg * M_PI / 180);
  for (const auto& [e, faces] : edge_faces)
    if (faces.size() == 2 && FaceNormal(mesh, faces[0]).dot(FaceNormal(mesh, faces[1])) < cos_cut) F.edges.push_back(e);
  for (auto [a, b] : o.marked) {
    if (!edge_faces.count(Key(a, b)))
      return absl::InvalidArgumentError(absl::StrFormat("marked feature edge (%d, %d) is not an edge of the mesh", a, b));
    if (edge_faces[Key(a, b)].size() == 2) F.edges.push_back(Key(a, b));
  }
  std::sort(F.edges.begin(), F.edges.end());
  F.edges.erase(std::unique(F.edges.begin(), F.edges.end()), F.edges.end());
  F.valence.assign(nv, 0);
  for (auto [a, b] : F.edges) ++F.valence[a], ++F.valence[b];
  F.curves = TraceCurves(nv, F.edges, F.valence);

  // Virtual split: faces around a vertex joined through non-feature edges form one
  // side; every side beyond the first gets its own copy of the vertex.
  F.split.faces = mesh.faces;
  F.split_to_original.resize(nv);
  std::iota(F.split_to_original.begin(), F.split_to_original.end(), 0);
  std::vector<Vector3d> extra;
  for (int v = 0; v < nv; ++v) {
    if (F.valence[v] < 2) continue;  // one feature edge ends inside a smooth fan: no split
    const int k = topo.NumVertexFaces(v);
    std::vector<int> parent(k);
    std::iota(parent.begin(), parent.end(), 0);
    for (int i = 0; i < k; ++i)
      for (int j = i + 1; j < k; ++j) {
        const int f = topo.VertexFaces(v)[i], g = topo.VertexFaces(v)[j];
        for (int c = 0; c < mesh.FaceSize(f); ++c) {
          const int w = mesh.faces(f, c);
          if (w == v || F.IsFeature(v, w)) continue;
          bool in_g = false;
          for (int d = 0; d < mesh.FaceSize(g); ++d) in_g |= mesh.faces(g, d) == w;
          bool adjacent = false;  // w next to v in f (an edge, not a quad diagonal)
          const int n = mesh.FaceSize(f);
          for (int d = 0; d < n; ++d)
            if (mesh.faces(f, d) == v) adjacent = mesh.faces(f, (d + 1) % n) == w || mesh.faces(f, (d + n - 1) % n) == w;
          if (in_g && adjacent) parent[Find(parent, i)] = Find(parent, j);
        }
      }
    std::map<int, int32_t> side_id;
    for (int i = 0; i < k; ++i) {
      const int root = Find(parent, i);
      if (!side_id.count(root)) {
        side_id[root] = side_id.empty() ? v : static_cast<int32_t>(nv + extra.size());
        if (side_id[root] != v) extra.push_back(mesh.positions.row(v).transpose()), F.split_to_original.push_back(v);
      }
      const int f = topo.VertexFaces(v)[i];
      for (int c = 0; c < mesh.FaceSize(f); ++c)
        if (mesh.faces(f, c) == v) F.split.faces(f, c) = side_id[root];
    }
  }
  F.split.positions.resize(nv + extra.size(), 3);
  F.split.positions.topRows(nv) = mesh.positions;
  for (size_t i = 0; i < extra.size(); ++i) F.split.positions.row(nv + i) = extra[i].transpose();
  return F;
}

FeatureSurface::FeatureSurface(const Mesh& mesh, std::shared_ptr<const Features> features,
                               std::unique_ptr<ReconstructedSurface> surface, int degree)
    : mesh_(mesh), features_(std::move(features)), surface_(std::move(surface)), degree_(degree) {
  // One-dimensional fits along every ridge curve (4.1.4), one per curve node, keyed by
  // the directed edge that leaves the node along the curve.
  for (const std::vector<int32_t>& c : features_->curves) {
    const int m = static_cast<int>(c.size());
    const bool closed = m > 2 && c.front() == c.back();
    const int nodes = closed ? m - 1 : m;
    auto at = [&](int i) { return closed ? c[((i % nodes) + nodes) % nodes] : c[std::clamp(i, 0, m - 1)]; };
    for (int i = 0; i < nodes; ++i) {
      const Vector3d x0 = mesh.positions.row(at(i)).transpose();
      CurveFit fit;
      fit.origin = x0;
      const int lo = closed ? i - 1 : std::max(i - 1, 0), hi = closed ? i + 1 : std::min(i + 1, m - 1);
      fit.tangent = (mesh.positions.row(at(hi)) - mesh.positions.row(at(lo))).transpose().normalized();
      fit.n1 = FrameFromNormal(x0, fit.tangent).t1;
      fit.n2 = fit.tangent.cross(fit.n1);
      // Window of neighbours along the curve (interpolating at the node).
      std::vector<int> window;
      const int w = degree + 1;
      for (int j = i - w; j <= i + w; ++j)
        if (j != i && (closed || (j >= 0 && j < m))) window.push_back(at(j));
      const int deg = std::min<int>(degree, static_cast<int>(window.size()) - 1);
      if (deg >= 1) {
        double h = 0;
        for (int v : window) h = std::max(h, std::abs(fit.tangent.dot(mesh.positions.row(v).transpose() - x0)));
        Eigen::MatrixXd A(window.size(), deg);
        Eigen::MatrixXd B(window.size(), 2);
        for (size_t r = 0; r < window.size(); ++r) {
          const Vector3d d = mesh.positions.row(window[r]).transpose() - x0;
          const double s = fit.tangent.dot(d) / h;
          const double wgt = 1 / std::pow(s * s + 0.01, 0.25 * deg);
          for (int p = 1; p <= deg; ++p) A(r, p - 1) = wgt * std::pow(s, p);
          B(r, 0) = wgt * fit.n1.dot(d);
          B(r, 1) = wgt * fit.n2.dot(d);
        }
        const Eigen::MatrixXd C = A.colPivHouseholderQr().solve(B);
        for (int p = 1; p <= deg; ++p) fit.c1[p] = C(p - 1, 0) / std::pow(h, p), fit.c2[p] = C(p - 1, 1) / std::pow(h, p);
        fit.degree = deg;
      }
      const int next = closed ? at(i + 1) : (i + 1 < m ? c[i + 1] : -1);
      const int prev = closed ? at(i - 1) : (i > 0 ? c[i - 1] : -1);
      if (next >= 0) fits_.emplace(std::make_pair(at(i), next), fit);
      if (prev >= 0) fits_.emplace(std::make_pair(at(i), prev), fit);
    }
  }
}

Vector3d FeatureSurface::CurvePoint(int a, int b, double t) const {
  const Vector3d xa = mesh_.positions.row(a).transpose(), xb = mesh_.positions.row(b).transpose();
  const Vector3d x = (1 - t) * xa + t * xb;
  auto eval = [&](int v, int other) -> Vector3d {
    auto it = fits_.find({v, other});
    if (it == fits_.end()) return x;
    const CurveFit& f = it->second;
    const double s = f.tangent.dot(x - f.origin);
    double y1 = 0, y2 = 0, sp = 1;
    for (int p = 1; p <= f.degree; ++p) sp *= s, y1 += f.c1[p] * sp, y2 += f.c2[p] * sp;
    return f.origin + s * f.tangent + y1 * f.n1 + y2 * f.n2;
  };
  return (1 - t) * eval(a, b) + t * eval(b, a);  // WALF for curves
}

SurfacePoint FeatureSurface::Evaluate(const FacePoint& p) const {
  SurfacePoint s = surface_->Evaluate(p);
  // On a feature edge of the face, the ridge curve decides the position.
  const int n = mesh_.FaceSize(p.face);
  constexpr double tol = 1e-14;
  for (int c = 0; c < n; ++c) {
    const int a = mesh_.faces(p.face, c), b = mesh_.faces(p.face, (c + 1) % n);
    if (!features_->IsFeature(a, b)) continue;
    double t = -1;
    if (n == 3) {
      if (c == 0 && std::abs(p.eta) < tol) t = p.xi;
      if (c == 1 && std::abs(p.xi + p.eta - 1) < tol) t = p.eta;
      if (c == 2 && std::abs(p.xi) < tol) t = 1 - p.eta;
    } else {
      if (c == 0 && std::abs(p.eta) < tol) t = p.xi;
      if (c == 1 && std::abs(p.xi - 1) < tol) t = p.eta;
      if (c == 2 && std::abs(p.eta - 1) < tol) t = 1 - p.xi;
      if (c == 3 && std::abs(p.xi) < tol) t = 1 - p.eta;
    }
    if (t >= 0) {
      s.position = CurvePoint(a, b, t);
      break;
    }
  }
  return s;
}

}  // namespace geomfit
