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

// Ridge-curve fit windows end where the chord from the node turns more than this from
// the curve tangent (see FeatureSurface).
constexpr double kMaxChordAngleDeg = 30;

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
        if (mesh.faces(f, c) == v) F.split.faces.Mutable()(f, c) = side_id[root];
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
      // Window of neighbours along the curve (interpolating at the node): up to degree + 1
      // on each side, each side ending where the curve stops being a tame graph over the
      // tangent: a chord at more than kMaxChordAngleDeg to it (on a circle the chord to
      // the node at arc angle theta makes theta / 2, so 60 degrees of arc) or a tangential
      // coordinate that stops growing. On coarse meshes of small holes (14 nodes on a
      // circle) the full window spanned 100-130 degrees of arc, where the offsets are no
      // polynomial of the tangential coordinate, and the faces missed the ridge by half
      // the chord-to-arc area (bench/README.md, issue 16 item 4).
      std::vector<int> window;
      const int w = degree + 1;
      const double max_cos = std::cos(kMaxChordAngleDeg * M_PI / 180);
      for (int dir : {-1, 1}) {
        double last_s = 0;
        for (int j = i + dir; std::abs(j - i) <= w; j += dir) {
          if (!closed && (j < 0 || j >= m)) break;
          if (closed && std::abs(j - i) >= nodes) break;
          const Vector3d d = mesh.positions.row(at(j)).transpose() - x0;
          const double s = dir * fit.tangent.dot(d);
          if (!(s > last_s) || s < max_cos * d.norm()) break;
          last_s = s;
          window.push_back(at(j));
        }
      }
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

Vector3d FeatureSurface::CurvePoint(int a, int b, double t, Vector3d* dt) const {
  const Vector3d xa = mesh_.positions.row(a).transpose(), xb = mesh_.positions.row(b).transpose();
  const Vector3d x = (1 - t) * xa + t * xb;
  // Vertex v's curve fit at x, and its derivative along t.
  auto eval = [&](int v, int other, Vector3d* d) -> Vector3d {
    auto it = fits_.find({v, other});
    if (it == fits_.end()) {
      *d = xb - xa;
      return x;
    }
    const CurveFit& f = it->second;
    const double s = f.tangent.dot(x - f.origin);
    double y1 = 0, y2 = 0, d1 = 0, d2 = 0, sp = 1;  // sp = s^(p-1)
    for (int p = 1; p <= f.degree; ++p) {
      d1 += p * f.c1[p] * sp, d2 += p * f.c2[p] * sp;
      sp *= s;
      y1 += f.c1[p] * sp, y2 += f.c2[p] * sp;
    }
    *d = f.tangent.dot(xb - xa) * (f.tangent + d1 * f.n1 + d2 * f.n2);
    return f.origin + s * f.tangent + y1 * f.n1 + y2 * f.n2;
  };
  Vector3d da, db;
  const Vector3d ea = eval(a, b, &da), eb = eval(b, a, &db);
  if (dt) *dt = eb - ea + (1 - t) * da + t * db;
  return (1 - t) * ea + t * eb;  // WALF for curves
}

SurfacePoint FeatureSurface::Evaluate(const FacePoint& p) const {
  SurfacePoint s = surface_->Evaluate(p);
  const int n = mesh_.FaceSize(p.face);
  // Each feature edge (a, b) of the face adds w * (C(t) - S(t)): its ridge curve's offset
  // from the one-sided surface at edge parameter t, with weight w = 1 on the edge and 0
  // at the opposite corner (triangles: w = l_a + l_b, t = l_b / w in barycentrics; quads:
  // the bilinear coordinate across the edge). On the edge the face meets the curve.
  const double xi = p.xi, eta = p.eta;
  for (int c = 0; c < n; ++c) {
    const int a = mesh_.faces(p.face, c), b = mesh_.faces(p.face, (c + 1) % n);
    if (!features_->IsFeature(a, b)) continue;
    // w, t and their (xi, eta) derivatives; the edge point's natural coordinates at t.
    double w, t, w_xi, w_eta, t_xi, t_eta;
    Eigen::Vector2d e0, e1;  // edge point = e0 + t e1
    if (n == 3) {
      const double l[3] = {1 - xi - eta, xi, eta};
      const double l_xi[3] = {-1, 1, 0}, l_eta[3] = {-1, 0, 1};
      const int ia = c, ib = (c + 1) % 3;
      w = l[ia] + l[ib];
      if (w < 1e-12) continue;  // the opposite corner: no offset
      t = l[ib] / w;
      w_xi = l_xi[ia] + l_xi[ib], w_eta = l_eta[ia] + l_eta[ib];
      t_xi = (l_xi[ib] - t * w_xi) / w, t_eta = (l_eta[ib] - t * w_eta) / w;
      const Eigen::Vector2d corner[3] = {{0, 0}, {1, 0}, {0, 1}};
      e0 = corner[ia], e1 = corner[ib] - corner[ia];
    } else {
      switch (c) {
        case 0: w = 1 - eta, t = xi, w_xi = 0, w_eta = -1, t_xi = 1, t_eta = 0, e0 = {0, 0}, e1 = {1, 0}; break;
        case 1: w = xi, t = eta, w_xi = 1, w_eta = 0, t_xi = 0, t_eta = 1, e0 = {1, 0}, e1 = {0, 1}; break;
        case 2: w = eta, t = 1 - xi, w_xi = 0, w_eta = 1, t_xi = -1, t_eta = 0, e0 = {1, 1}, e1 = {-1, 0}; break;
        default: w = 1 - xi, t = 1 - eta, w_xi = -1, w_eta = 0, t_xi = 0, t_eta = -1, e0 = {0, 1}, e1 = {0, -1}; break;
      }
      if (w < 1e-12) continue;
    }
    const Eigen::Vector2d e = e0 + t * e1;
    const SurfacePoint edge = surface_->Evaluate({p.face, e.x(), e.y()});
    Vector3d dcurve;
    const Vector3d offset = CurvePoint(a, b, t, &dcurve) - edge.position;
    const Vector3d doffset = dcurve - edge.jacobian * e1;  // d/dt of the offset
    s.position += w * offset;
    s.jacobian.col(0) += w_xi * offset + w * t_xi * doffset;
    s.jacobian.col(1) += w_eta * offset + w * t_eta * doffset;
  }
  return s;
}

}  // namespace geomfit
