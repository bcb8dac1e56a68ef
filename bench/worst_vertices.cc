// Which vertices carry the max-norm errors of a mesh family, and why (issue 16: Linf orders
// on marching-cubes meshes). For each mesh of the family and each degree: the error
// quantiles (50%, 99%, 99.9%, max) of the normal, H and K errors with their observed orders,
// and the `top` worst vertices of each with their stencil's shape: points, rings reached,
// radius / h (farthest point), nearest point / h, closest pair of stencil points / h,
// one-sidedness |mean tangential offset| / radius, valence, degree used, condition, the
// smallest angle of the vertex's faces.
//
// Usage: worst_vertices DMIN DMAX 'torus@/dir/mc%d_proj.obj' 40,60,80 [top=5]
// ('sphere@delaunay' 368,1450,5762: the unstructured Delaunay spheres of so many vertices.)
// Options of the fit by the environment as cgal_compare's: GF_RINGS, GF_MPF, GF_EPS, GF_NEARDUP.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "core/fitting/fit.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"

using namespace geomfit;

namespace {

double Quantile(std::vector<double> v, double q) {
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

struct Shape {
  int points, valence, degree_used;
  float rings, condition;
  double radius, nearest, closest_pair, one_sided, min_angle;
};

Shape StencilShape(const Mesh& mesh, const Topology& topo, const Neighborhoods& nb, const Differentials& d,
                   const AnalyticSurface& surf, int v, double h) {
  Shape s{};
  s.points = nb.Size(v);
  s.rings = nb.rings[v];
  s.valence = topo.NumNeighbors(v);
  s.degree_used = d.diagnostics[v].degree_used;
  s.condition = d.diagnostics[v].condition;
  const Eigen::Vector3d c = mesh.positions.row(v).transpose();
  const Eigen::Vector3d n = surf.At(c).normal;
  const int32_t* p = nb.Points(v);
  double rmax = 0, rmin = HUGE_VAL, pair = HUGE_VAL;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (int i = 1; i < s.points; ++i) {
    const Eigen::Vector3d x = mesh.positions.row(p[i]).transpose() - c;
    rmax = std::max(rmax, x.norm()), rmin = std::min(rmin, x.norm());
    mean += x - x.dot(n) * n;
    for (int j = 0; j < i; ++j)
      pair = std::min(pair, (mesh.positions.row(p[i]) - mesh.positions.row(p[j])).norm());
  }
  s.radius = rmax / h, s.nearest = rmin / h, s.closest_pair = pair / h;
  s.one_sided = (mean / (s.points - 1)).norm() / rmax;
  s.min_angle = 180;
  const Faces& F = mesh.faces.get();
  for (int k = 0; k < topo.NumVertexFaces(v); ++k) {
    const int f = topo.VertexFaces(v)[k];
    for (int a = 0; a < 3; ++a) {
      const Eigen::Vector3d x0 = mesh.positions.row(F(f, a)).transpose();
                            const Eigen::Vector3d x1 = mesh.positions.row(F(f, (a + 1) % 3)).transpose();
                            const Eigen::Vector3d x2 = mesh.positions.row(F(f, (a + 2) % 3)).transpose();
      const double cs = (x1 - x0).normalized().dot((x2 - x0).normalized());
      s.min_angle = std::min(s.min_angle, std::acos(std::clamp(cs, -1.0, 1.0)) * 180 / M_PI);
    }
  }
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 5) {
    std::fprintf(stderr, "usage: worst_vertices DMIN DMAX surface@pattern n1,n2,... [top]\n");
    return 2;
  }
  const int dmin = std::atoi(argv[1]), dmax = std::atoi(argv[2]);
  const std::string spec = argv[3];
  const std::string surf_name = spec.substr(0, spec.find('@')), pattern = spec.substr(spec.find('@') + 1);
  std::vector<int> ns;
  {
    std::stringstream ss(argv[4]);
    for (std::string s; std::getline(ss, s, ',');) ns.push_back(std::atoi(s.c_str()));
  }
  const int top = argc > 5 ? std::atoi(argv[5]) : 5;
  auto surface = NamedSurface(surf_name).value();
  const char* qname[3] = {"normal", "H", "K"};
  for (int d = dmin; d <= dmax; ++d) {
    std::vector<double> hs;
    std::vector<std::vector<double>> q(12);  // quantity x {50, 99, 99.9, max}
    for (int n : ns) {
      char path[1024];
      std::snprintf(path, sizeof path, pattern.c_str(), n);
      // "delaunay": GenerateDelaunaySphereMesh(n, 0.3) (with surface "sphere")
      Mesh mesh = pattern == "delaunay" ? GenerateDelaunaySphereMesh(n, 0.3) : ReadMesh(path).value();
      Topology topo = BuildTopology(mesh).value();
      FitOptions o;
      o.degree = d;
      if (const char* e = std::getenv("GF_RINGS")) o.rings = std::atof(e);
      if (const char* e = std::getenv("GF_MPF")) o.min_points_factor = std::atof(e);
      if (const char* e = std::getenv("GF_EPS")) o.weight_epsilon = std::atof(e);
      RingSpec spec = RingSpecFor(o);
      spec.count_near_duplicates = std::getenv("GF_NEARDUP") != nullptr;
      auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, spec));
      auto fits = FitSurface(mesh, topo, o, nb).value();
      Differentials df = ComputeDifferentials(*fits);
      const double h = AverageEdgeLength(mesh);
      hs.push_back(h);
      const int nv = mesh.NumVertices();
      std::vector<std::vector<double>> err(3, std::vector<double>(nv));
      double hmax = 0, kmax = 0;
      std::vector<ExactDifferentials> ex(nv);
      for (int v = 0; v < nv; ++v) {
        ex[v] = surface->At(mesh.positions.row(v).transpose());
        hmax = std::max(hmax, std::abs(ex[v].mean)), kmax = std::max(kmax, std::abs(ex[v].gaussian));
      }
      for (int v = 0; v < nv; ++v) {
        err[0][v] = (df.normals.row(v).transpose() - ex[v].normal).norm();
        err[1][v] = std::abs(df.mean(v) - ex[v].mean) / hmax;
        err[2][v] = std::abs(df.gaussian(v) - ex[v].gaussian) / kmax;
      }
      std::printf("degree %d  n %d  #V %d  h %.4e\n", d, n, nv, h);
      {  // the errors by condition decile: do the worst vertices have ill-conditioned fits?
        std::vector<int> by(nv);
        for (int v = 0; v < nv; ++v) by[v] = v;
        std::sort(by.begin(), by.end(), [&](int a, int b) { return df.diagnostics[a].condition < df.diagnostics[b].condition; });
        std::printf("  by condition decile (upper cond: max normal / H / K error over q99):\n   ");
        const double q99[3] = {Quantile(err[0], 0.99), Quantile(err[1], 0.99), Quantile(err[2], 0.99)};
        for (int b = 0; b < 10; ++b) {
          double m[3] = {0, 0, 0};
          for (int i = b * nv / 10; i < (b + 1) * nv / 10; ++i)
            for (int k = 0; k < 3; ++k) m[k] = std::max(m[k], err[k][by[i]] / q99[k]);
          std::printf(" %.0f:%.1f/%.1f/%.1f", df.diagnostics[by[(b + 1) * nv / 10 - 1]].condition, m[0], m[1], m[2]);
        }
        std::printf("\n");
      }
      for (int k = 0; k < 3; ++k) {
        const double qs[4] = {Quantile(err[k], 0.5), Quantile(err[k], 0.99), Quantile(err[k], 0.999),
                              *std::max_element(err[k].begin(), err[k].end())};
        for (int j = 0; j < 4; ++j) q[4 * k + j].push_back(qs[j]);
        std::printf("  %-6s q50 %.2e q99 %.2e q99.9 %.2e max %.2e\n", qname[k], qs[0], qs[1], qs[2], qs[3]);
        std::vector<int> idx(nv);
        for (int v = 0; v < nv; ++v) idx[v] = v;
        std::partial_sort(idx.begin(), idx.begin() + top, idx.end(),
                          [&](int a, int b) { return err[k][a] > err[k][b]; });
        std::printf("    %7s %9s %5s %4s %6s %5s %6s %6s %6s %5s %4s %4s %8s %6s\n", "vertex", "err", "x/q99",
                    "pts", "rings", "val", "r/h", "near/h", "pair/h", "1side", "deg", "minA", "cond", "nerr");
        for (int i = 0; i < top; ++i) {
          const int v = idx[i];
          const Shape s = StencilShape(mesh, topo, *nb, df, *surface, v, h);
          std::printf("    %7d %9.2e %5.1f %4d %6.1f %5d %6.2f %6.3f %6.3f %5.2f %4d %4.1f %8.1e %8.2e\n", v, err[k][v],
                      err[k][v] / qs[1], s.points, s.rings, s.valence, s.radius, s.nearest, s.closest_pair,
                      s.one_sided, s.degree_used, s.min_angle, s.condition, err[0][v]);
        }
      }
    }
    std::printf("degree %d orders (q50 q99 q99.9 max):", d);
    for (int k = 0; k < 3; ++k) {
      std::printf("  %s", qname[k]);
      for (int j = 0; j < 4; ++j) std::printf(" %.2f", ConvergenceOrder(hs, q[4 * k + j]));
    }
    std::printf("\n\n");
  }
  return 0;
}
