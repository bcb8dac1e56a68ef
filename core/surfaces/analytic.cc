#include "core/surfaces/analytic.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <tuple>
#include <vector>

#include <Eigen/Cholesky>

#include "absl/strings/str_cat.h"
#include "core/quantities/differentials.h"

namespace geomfit {
namespace {

using Eigen::Vector3d;

class Sphere final : public AnalyticSurface {
 public:
  explicit Sphere(double r) : r_(r) {}
  std::string Name() const override { return "sphere"; }
  ExactDifferentials At(const Vector3d& p) const override {
    return {p.normalized(), 1 / r_, 1 / (r_ * r_), 1 / r_, 1 / r_, Vector3d::Zero(), Vector3d::Zero()};
  }
  Vector3d Project(const Vector3d& p) const override { return r_ * p.normalized(); }

 private:
  double r_;
};

class Torus final : public AnalyticSurface {
 public:
  Torus(double R, double r) : R_(R), r_(r) {}
  std::string Name() const override { return "torus"; }
  ExactDifferentials At(const Vector3d& p) const override {
    const double u = std::atan2(p.y(), p.x());
    const double v = std::atan2(p.z(), std::hypot(p.x(), p.y()) - R_);
    ExactDifferentials e;
    e.normal = Vector3d(std::cos(v) * std::cos(u), std::cos(v) * std::sin(u), std::sin(v));
    const double tube = 1 / r_, ring = std::cos(v) / (R_ + r_ * std::cos(v));
    e.k1 = std::max(tube, ring);
    e.k2 = std::min(tube, ring);
    e.mean = 0.5 * (tube + ring);
    e.gaussian = tube * ring;
    const Vector3d along_tube(-std::sin(v) * std::cos(u), -std::sin(v) * std::sin(u), std::cos(v));
    const Vector3d along_ring(-std::sin(u), std::cos(u), 0);
    e.e1 = tube >= ring ? along_tube : along_ring;
    e.e2 = tube >= ring ? along_ring : along_tube;
    return e;
  }
  Vector3d Project(const Vector3d& p) const override {
    const double u = std::atan2(p.y(), p.x());
    const Vector3d c(R_ * std::cos(u), R_ * std::sin(u), 0);
    return c + r_ * (p - c).normalized();
  }

 private:
  double R_, r_;
};

class Ellipsoid final : public AnalyticSurface {
 public:
  Ellipsoid(double a, double b, double c) : ax_(a, b, c) {}
  std::string Name() const override { return "ellipsoid"; }
  ExactDifferentials At(const Vector3d& p) const override {
    const Vector3d a2 = ax_.cwiseProduct(ax_);
    const Vector3d g = p.cwiseQuotient(a2);  // gradient / 2 of the implicit function
    const double S = g.squaredNorm(), abc2 = a2.prod();
    ExactDifferentials e;
    e.normal = g.normalized();
    e.mean = (a2.sum() - p.squaredNorm()) / (2 * abc2 * std::pow(S, 1.5));
    e.gaussian = 1 / (abc2 * S * S);
    const double root = std::sqrt(std::max(0.0, e.mean * e.mean - e.gaussian));
    e.k1 = e.mean + root;
    e.k2 = e.mean - root;
    e.e1 = e.e2 = Vector3d::Zero();
    return e;
  }
  Vector3d Project(const Vector3d& p) const override {
    // Closest point x_i = a_i^2 p_i / (a_i^2 + t) with sum (x_i / a_i)^2 = 1; Newton on t.
    const Vector3d a2 = ax_.cwiseProduct(ax_);
    double t = 0;
    for (int it = 0; it < 50; ++it) {
      double F = -1, dF = 0;
      for (int i = 0; i < 3; ++i) {
        const double q = ax_(i) * p(i) / (a2(i) + t);
        F += q * q;
        dF += -2 * q * q / (a2(i) + t);
      }
      if (std::abs(F) < 1e-15 || dF == 0) break;
      t -= F / dF;
    }
    return Vector3d(a2(0) * p(0) / (a2(0) + t), a2(1) * p(1) / (a2(1) + t), a2(2) * p(2) / (a2(2) + t));
  }

 private:
  Vector3d ax_;
};

// z = f(x, y) = exp(-81/16 ((x-.5)^2 + (y-.5)^2)) (3.3.2), normals upward.
class GaussianBump final : public AnalyticSurface {
 public:
  std::string Name() const override { return "bump"; }
  struct Derivs { double f, fx, fy, fxx, fxy, fyy; };
  static Derivs Eval(double x, double y) {
    constexpr double a = 81.0 / 16.0;
    const double dx = x - 0.5, dy = y - 0.5, f = std::exp(-a * (dx * dx + dy * dy));
    return {f, -2 * a * dx * f, -2 * a * dy * f, (4 * a * a * dx * dx - 2 * a) * f,
            4 * a * a * dx * dy * f, (4 * a * a * dy * dy - 2 * a) * f};
  }
  ExactDifferentials At(const Vector3d& p) const override {
    const Derivs d = Eval(p.x(), p.y());
    const double l2 = 1 + d.fx * d.fx + d.fy * d.fy, l = std::sqrt(l2);
    ExactDifferentials e;
    e.normal = Vector3d(-d.fx, -d.fy, 1) / l;
    e.mean = -((1 + d.fy * d.fy) * d.fxx - 2 * d.fx * d.fy * d.fxy + (1 + d.fx * d.fx) * d.fyy) / (2 * l2 * l);
    e.gaussian = (d.fxx * d.fyy - d.fxy * d.fxy) / (l2 * l2);
    const double root = std::sqrt(std::max(0.0, e.mean * e.mean - e.gaussian));
    e.k1 = e.mean + root;
    e.k2 = e.mean - root;
    // Directions from the exact jet of the graph x(u, v) = (u, v, f(u, v)).
    SurfaceJet jet;
    jet.x = Vector3d(p.x(), p.y(), d.f);
    jet.J << 1, 0, 0, 1, d.fx, d.fy;
    jet.xuu = Vector3d(0, 0, d.fxx);
    jet.xuv = Vector3d(0, 0, d.fxy);
    jet.xvv = Vector3d(0, 0, d.fyy);
    const PointDifferentials pd = DifferentialsFromJet(jet);
    e.e1 = pd.e1;
    e.e2 = pd.e2;
    return e;
  }
  Vector3d Project(const Vector3d& p) const override {
    double x = p.x(), y = p.y();
    for (int it = 0; it < 30; ++it) {  // Gauss-Newton on |(x, y, f(x, y)) - p|^2
      const Derivs d = Eval(x, y);
      const double r = d.f - p.z();
      const Eigen::Vector2d g(x - p.x() + r * d.fx, y - p.y() + r * d.fy);
      Eigen::Matrix2d H;
      H << 1 + d.fx * d.fx, d.fx * d.fy, d.fx * d.fy, 1 + d.fy * d.fy;
      const Eigen::Vector2d step = H.ldlt().solve(g);
      x -= step.x();
      y -= step.y();
      if (step.norm() < 1e-16) break;
    }
    return Vector3d(x, y, Eval(x, y).f);
  }
};

// A (nu x nv)-cell grid over the unit square, optionally periodic, with jittered vertex
// parameters and each cell split along a random diagonal (or kept as a quad).
struct ParamGrid {
  std::vector<Eigen::Vector2d> params;
  Faces faces;
};

ParamGrid MakeParamGrid(int nu, int nv, bool periodic, const GeneratorOptions& o) {
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> jit(-o.jitter, o.jitter);
  std::bernoulli_distribution coin(0.5);
  const int cu = periodic ? nu : nu + 1, cv = periodic ? nv : nv + 1;
  ParamGrid g;
  g.params.resize(static_cast<size_t>(cu) * cv);
  for (int j = 0; j < cv; ++j)
    for (int i = 0; i < cu; ++i) {
      double di = jit(rng), dj = jit(rng);
      if (!periodic) {  // boundary vertices slide along the boundary; corners stay
        if (i == 0 || i == nu) di = 0;
        if (j == 0 || j == nv) dj = 0;
      }
      g.params[static_cast<size_t>(j) * cu + i] = Eigen::Vector2d((i + di) / nu, (j + dj) / nv);
    }
  auto id = [&](int i, int j) { return (j % cv) * cu + (i % cu); };
  g.faces.resize(static_cast<Eigen::Index>(nu) * nv * (o.quads ? 1 : 2), 4);
  int f = 0;
  for (int j = 0; j < nv; ++j)
    for (int i = 0; i < nu; ++i) {
      const int a = id(i, j), b = id(i + 1, j), c = id(i + 1, j + 1), d = id(i, j + 1);
      if (o.quads) {
        g.faces.row(f++) << a, b, c, d;
      } else if (coin(rng)) {
        g.faces.row(f++) << a, b, c, -1;
        g.faces.row(f++) << a, c, d, -1;
      } else {
        g.faces.row(f++) << a, b, d, -1;
        g.faces.row(f++) << b, c, d, -1;
      }
    }
  return g;
}

}  // namespace

std::unique_ptr<AnalyticSurface> MakeSphere(double radius) { return std::make_unique<Sphere>(radius); }
std::unique_ptr<AnalyticSurface> MakeTorus(double R, double r) { return std::make_unique<Torus>(R, r); }
std::unique_ptr<AnalyticSurface> MakeEllipsoid(double a, double b, double c) {
  return std::make_unique<Ellipsoid>(a, b, c);
}
std::unique_ptr<AnalyticSurface> MakeGaussianBump() { return std::make_unique<GaussianBump>(); }

Mesh GenerateTorusMesh(const GeneratorOptions& o, double R, double r) {
  const ParamGrid g = MakeParamGrid(3 * o.n, o.n, /*periodic=*/true, o);
  Mesh m;
  m.faces = g.faces;
  m.positions.resize(g.params.size(), 3);
  for (size_t i = 0; i < g.params.size(); ++i) {
    const double u = 2 * M_PI * g.params[i].x(), v = 2 * M_PI * g.params[i].y();
    m.positions.row(i) << (R + r * std::cos(v)) * std::cos(u), (R + r * std::cos(v)) * std::sin(u),
        r * std::sin(v);
  }
  return m;
}

namespace {
// Keeps the faces `keep` accepts and the vertices they use (renumbered in order).
template <typename Keep>
Mesh CompactFaces(const Mesh& in, Keep&& keep) {
  std::vector<int> map(in.NumVertices(), -1);
  std::vector<int> faces;
  for (int f = 0; f < in.NumFaces(); ++f)
    if (keep(f)) faces.push_back(f);
  Mesh m;
  Faces& mf = m.faces.Mutable();
  mf.resize(static_cast<Eigen::Index>(faces.size()), 4);
  int nv = 0;
  for (size_t k = 0; k < faces.size(); ++k)
    for (int c = 0; c < 4; ++c) {
      const int v = in.faces(faces[k], c);
      if (v >= 0 && map[v] < 0) map[v] = nv++;
      mf(static_cast<Eigen::Index>(k), c) = v < 0 ? -1 : map[v];
    }
  m.positions.resize(nv, 3);
  for (int v = 0; v < in.NumVertices(); ++v)
    if (map[v] >= 0) m.positions.row(map[v]) = in.positions.row(v);
  return m;
}
}  // namespace

Mesh GenerateOpenCylinderMesh(const GeneratorOptions& o, double radius) {
  const int nu = 4 * o.n, nv = 2 * o.n;
  const ParamGrid g = MakeParamGrid(nu, nv, /*periodic=*/false, o);
  Mesh m;
  m.faces = g.faces;
  for (int f = 0; f < m.NumFaces(); ++f)  // weld the seam: column nu onto column 0
    for (int c = 0; c < 4; ++c)
      if (m.faces(f, c) >= 0 && m.faces(f, c) % (nu + 1) == nu) m.faces.Mutable()(f, c) -= nu;
  m.positions.resize(g.params.size(), 3);
  for (size_t i = 0; i < g.params.size(); ++i) {
    const double t = 2 * M_PI * g.params[i].x();
    m.positions.row(i) << radius * std::cos(t), radius * std::sin(t), 2 * g.params[i].y() - 1;
  }
  return CompactFaces(m, [](int) { return true; });
}

Mesh GenerateHemisphereMesh(const GeneratorOptions& o, double radius) {
  const Mesh s = GenerateSphereMesh(o, radius);
  return CompactFaces(s, [&](int f) {
    double z = 0;
    for (int c = 0; c < s.FaceSize(f); ++c) z += s.positions(s.faces(f, c), 2);
    return z > 0;
  });
}

Mesh GenerateBumpMesh(const GeneratorOptions& o) {
  const ParamGrid g = MakeParamGrid(o.n, o.n, /*periodic=*/false, o);
  Mesh m;
  m.faces = g.faces;
  m.positions.resize(g.params.size(), 3);
  for (size_t i = 0; i < g.params.size(); ++i) {
    const double x = g.params[i].x(), y = g.params[i].y();
    m.positions.row(i) << x, y, GaussianBump::Eval(x, y).f;
  }
  return m;
}

Mesh GenerateDelaunaySphereMesh(int vertices, double jitter, uint64_t seed, double radius) {
  const int n = std::max(vertices, 4);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uniform(-1, 1);
  const double golden = M_PI * (3 - std::sqrt(5.0)), spacing = std::sqrt(4 * M_PI / n);
  std::vector<Vector3d> p(n);
  for (int i = 0; i < n; ++i) {
    const double z = 1 - (2 * i + 1.0) / n, r = std::sqrt(1 - z * z);
    p[i] = Vector3d(r * std::cos(golden * i), r * std::sin(golden * i), z);
    if (jitter > 0) {
      const Vector3d d(uniform(rng), uniform(rng), uniform(rng));
      p[i] = (p[i] + jitter * spacing * (d - d.dot(p[i]) * p[i])).normalized();
    }
  }
  // Incremental convex hull (all points are on it). Faces stay outward: a new face
  // (a, b, q) takes the horizon edge a -> b in the orientation of the visible face.
  // Start from four spread-out points (a tetrahedron of positive volume).
  const int t[4] = {0, n / 3, 2 * n / 3, n - 1};
  std::vector<Eigen::Vector3i> faces = {{t[0], t[2], t[1]}, {t[0], t[1], t[3]}, {t[1], t[2], t[3]}, {t[2], t[0], t[3]}};
  const Vector3d inside = (p[t[0]] + p[t[1]] + p[t[2]] + p[t[3]]) / 4;
  auto outward = [&](const Eigen::Vector3i& f) {
    return (p[f(1)] - p[f(0)]).cross(p[f(2)] - p[f(0)]);
  };
  for (Eigen::Vector3i& f : faces)
    if (outward(f).dot(p[f(0)] - inside) < 0) std::swap(f(1), f(2));
  for (int q = 1; q < n - 1; ++q) {
    if (q == t[1] || q == t[2]) continue;
    std::set<std::pair<int, int>> edges;  // directed edges of the visible faces
    std::vector<Eigen::Vector3i> kept;
    kept.reserve(faces.size() + 2);
    for (const Eigen::Vector3i& f : faces) {
      if (outward(f).dot(p[q] - p[f(0)]) > 1e-15) {
        for (int k = 0; k < 3; ++k) edges.emplace(f(k), f((k + 1) % 3));
      } else {
        kept.push_back(f);
      }
    }
    for (const auto& [a, b] : edges)
      if (!edges.count({b, a})) kept.emplace_back(a, b, q);
    faces = std::move(kept);
  }
  Mesh m;
  m.positions.resize(n, 3);
  for (int i = 0; i < n; ++i) m.positions.row(i) = radius * p[i].transpose();
  Faces& mf = m.faces.Mutable();
  mf.setConstant(static_cast<Eigen::Index>(faces.size()), 4, -1);
  for (size_t f = 0; f < faces.size(); ++f) mf.row(f).head<3>() = faces[f].transpose();
  return m;
}

Mesh GenerateSphereMesh(const GeneratorOptions& o, double radius) {
  // Cubed sphere: six n x n grids on the cube, welded on a lattice, mapped with the
  // equiangular warp tan(pi/4 c) and normalized; then jittered along the sphere.
  const int n = o.n;
  std::mt19937_64 rng(o.seed);
  std::bernoulli_distribution coin(0.5);
  std::map<std::tuple<int, int, int>, int> index;
  std::vector<Vector3d> pts;
  auto vertex = [&](const Eigen::Vector3i& lat) {
    auto [it, inserted] = index.emplace(std::make_tuple(lat.x(), lat.y(), lat.z()), static_cast<int>(pts.size()));
    if (inserted) {
      Vector3d c = (2.0 * lat.cast<double>() / n).array() - 1.0;
      for (int k = 0; k < 3; ++k) c(k) = std::tan(M_PI / 4 * c(k));
      pts.push_back(c.normalized());
    }
    return it->second;
  };
  std::vector<Eigen::Vector4i> faces;
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      // Tangent axes (a, b) with e_a x e_b = outward normal (+/- e_axis).
      int a = (axis + 1) % 3, b = (axis + 2) % 3;
      if (side == 0) std::swap(a, b);
      for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i) {
          auto lat = [&](int di, int dj) {
            Eigen::Vector3i l;
            l(axis) = side ? n : 0;
            l(a) = i + di;
            l(b) = j + dj;
            return vertex(l);
          };
          const int v00 = lat(0, 0), v10 = lat(1, 0), v11 = lat(1, 1), v01 = lat(0, 1);
          if (coin(rng)) {
            faces.emplace_back(v00, v10, v11, -1);
            faces.emplace_back(v00, v11, v01, -1);
          } else {
            faces.emplace_back(v00, v10, v01, -1);
            faces.emplace_back(v10, v11, v01, -1);
          }
        }
    }
  std::uniform_real_distribution<double> jit(-1, 1);
  const double spacing = M_PI / 2 / n;
  Mesh m;
  m.positions.resize(pts.size(), 3);
  for (size_t i = 0; i < pts.size(); ++i) {
    Vector3d t(jit(rng), jit(rng), jit(rng));
    t -= t.dot(pts[i]) * pts[i];
    const Vector3d p = (pts[i] + o.jitter * spacing * t / std::max(1.0, t.norm())).normalized();
    m.positions.row(i) = radius * p;
  }
  Faces& mf = m.faces.Mutable();
  mf.resize(faces.size(), 4);
  for (size_t f = 0; f < faces.size(); ++f) mf.row(f) = faces[f].transpose();
  // Narrow cells near the cube's corners can fold under jitter: put the vertices of any
  // face that turns too far from the sphere's normal back where they were.
  for (bool changed = true; changed;) {
    changed = false;
    for (int f = 0; f < m.NumFaces(); ++f) {
      const Vector3d a = m.positions.row(m.faces(f, 0)), b = m.positions.row(m.faces(f, 1)),
                     c = m.positions.row(m.faces(f, 2));
      if ((b - a).cross(c - a).normalized().dot((a + b + c).normalized()) > 0.5) continue;
      for (int i = 0; i < 3; ++i) {
        const int v = m.faces(f, i);
        if (m.positions.row(v) != radius * pts[v].transpose()) m.positions.row(v) = radius * pts[v].transpose(), changed = true;
      }
    }
  }
  return m;
}

Mesh GenerateEllipsoidMesh(const GeneratorOptions& o, double a, double b, double c) {
  Mesh m = GenerateSphereMesh(o, 1.0);
  for (int i = 0; i < m.NumVertices(); ++i) {
    m.positions(i, 0) *= a;
    m.positions(i, 1) *= b;
    m.positions(i, 2) *= c;
  }
  return m;
}

Mesh GenerateCylinderMesh(int n) {
  const int around = 4 * n, rows = 2 * n, rings = n;
  std::vector<Vector3d> pts;
  std::vector<Eigen::Vector4i> faces;
  auto ring_point = [&](double r, int i, double z) {
    const double a = 2 * M_PI * i / around;
    return Vector3d(r * std::cos(a), r * std::sin(a), z);
  };
  // Side rows j = 0..rows at z = -1 + 2 j / rows; vertex (i, j) = j * around + i.
  for (int j = 0; j <= rows; ++j)
    for (int i = 0; i < around; ++i) pts.push_back(ring_point(1, i, -1 + 2.0 * j / rows));
  for (int j = 0; j < rows; ++j)
    for (int i = 0; i < around; ++i) {
      const int a = j * around + i, b = j * around + (i + 1) % around, c = b + around, d = a + around;
      faces.emplace_back(a, b, c, -1);
      faces.emplace_back(a, c, d, -1);
    }
  // Caps: rings k = 1..rings-1 inside the rim, then the centre; outward = -z at the bottom.
  for (int top = 0; top < 2; ++top) {
    const double z = top ? 1 : -1;
    std::vector<int> prev(around);
    for (int i = 0; i < around; ++i) prev[i] = (top ? rows : 0) * around + i;  // the rim
    for (int k = rings - 1; k >= 1; --k) {
      std::vector<int> cur(around);
      for (int i = 0; i < around; ++i) cur[i] = static_cast<int>(pts.size()), pts.push_back(ring_point(double(k) / rings, i, z));
      for (int i = 0; i < around; ++i) {
        const int a = prev[i], b = prev[(i + 1) % around], c = cur[(i + 1) % around], d = cur[i];
        if (top) faces.emplace_back(a, b, c, -1), faces.emplace_back(a, c, d, -1);
        else faces.emplace_back(a, c, b, -1), faces.emplace_back(a, d, c, -1);
      }
      prev = cur;
    }
    const int centre = static_cast<int>(pts.size());
    pts.emplace_back(0, 0, z);
    for (int i = 0; i < around; ++i) {
      if (top) faces.emplace_back(prev[i], prev[(i + 1) % around], centre, -1);
      else faces.emplace_back(prev[i], centre, prev[(i + 1) % around], -1);
    }
  }
  Mesh m;
  m.positions.resize(pts.size(), 3);
  for (size_t i = 0; i < pts.size(); ++i) m.positions.row(i) = pts[i].transpose();
  Faces& mf = m.faces.Mutable();
  mf.resize(faces.size(), 4);
  for (size_t f = 0; f < faces.size(); ++f) mf.row(f) = faces[f].transpose();
  return m;
}

double CylinderDistance(const Vector3d& p) {
  const double r = std::hypot(p.x(), p.y()), z = std::abs(p.z());
  const double rim = std::hypot(r - 1, z - 1);
  const double side = z <= 1 ? std::abs(r - 1) : rim, cap = r <= 1 ? std::abs(z - 1) : rim;
  return std::min(side, cap);
}

absl::StatusOr<Mesh> GenerateNamedMesh(const std::string& name, const GeneratorOptions& o) {
  if (o.n < 2 || o.n > 4096) return absl::InvalidArgumentError(absl::StrCat("level ", o.n, " is out of range [2, 4096]"));
  if (!(o.jitter >= 0 && o.jitter <= 0.3))
    return absl::InvalidArgumentError(absl::StrCat("jitter ", o.jitter, " is out of range [0, 0.3]"));
  GeneratorOptions q = o;
  if (name == "sphere") return GenerateSphereMesh(o);
  if (name == "torus") return GenerateTorusMesh(o);
  if (name == "ellipsoid") return GenerateEllipsoidMesh(o, 1.0, 0.8, 0.6);
  if (name == "bump") return GenerateBumpMesh(o);
  if (name == "quadtorus") return q.quads = true, GenerateTorusMesh(q);
  if (name == "cylinder") return GenerateCylinderMesh(o.n);
  return absl::InvalidArgumentError(
      absl::StrCat("unknown surface '", name, "' (sphere, torus, ellipsoid, bump, quadtorus, cylinder)"));
}

absl::StatusOr<std::unique_ptr<AnalyticSurface>> NamedSurface(const std::string& name) {
  if (name == "sphere") return MakeSphere();
  if (name == "torus" || name == "quadtorus") return MakeTorus();
  if (name == "ellipsoid") return MakeEllipsoid(1.0, 0.8, 0.6);
  if (name == "bump") return MakeGaussianBump();
  return absl::InvalidArgumentError(absl::StrCat("unknown surface '", name, "'"));
}

Mesh PerturbAlongNormals(const Mesh& mesh, const AnalyticSurface& surface, double alpha, int power,
                         uint64_t seed) {
  Mesh out = mesh;
  const double scale = alpha * std::pow(AverageEdgeLength(mesh), power);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> gauss(0.0, 0.5);
  for (int v = 0; v < mesh.NumVertices(); ++v) {
    const double a = std::clamp(gauss(rng), -1.0, 1.0);
    out.positions.row(v) += a * scale * surface.At(mesh.positions.row(v).transpose()).normal.transpose();
  }
  return out;
}

double AverageEdgeLength(const Mesh& mesh) {
  // Each edge once, summed in the order the faces first name it, with an open-addressing
  // set of the keys (a, b), a < b (a std::set of pairs cost ~130 ms on 87k vertices).
  const int64_t corners = 4 * static_cast<int64_t>(mesh.NumFaces());
  int shift = 64;
  while ((uint64_t{1} << (64 - shift)) < static_cast<uint64_t>(corners + corners / 2 + 1)) --shift;
  const uint64_t mask = (uint64_t{1} << (64 - shift)) - 1, kEmpty = ~uint64_t{0};
  std::vector<uint64_t> seen(mask + 1, kEmpty);
  double sum = 0;
  int64_t edges = 0;
  for (int f = 0; f < mesh.NumFaces(); ++f) {
    const int n = mesh.FaceSize(f);
    for (int i = 0; i < n; ++i) {
      int a = mesh.faces(f, i), b = mesh.faces(f, (i + 1) % n);
      if (a > b) std::swap(a, b);
      const uint64_t key = (static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32) | static_cast<uint32_t>(b);
      uint64_t slot = shift == 64 ? 0 : (key * 0x9E3779B97F4A7C15ull) >> shift;
      while (seen[slot] != kEmpty && seen[slot] != key) slot = (slot + 1) & mask;
      if (seen[slot] == key) continue;
      seen[slot] = key;
      ++edges;
      sum += (mesh.positions.row(a) - mesh.positions.row(b)).norm();
    }
  }
  return edges == 0 ? 0 : sum / edges;
}

}  // namespace geomfit
