// Noise-aware fitting (FitOptions::noise) on perturbed meshes against CGAL Jet_fitting_3
// at equal degree. Every vertex of a generated mesh moves along the exact normal by
// alpha_v h^k (PerturbAlongNormals, the controlled-noise tests of 3.3); errors are measured
// at the unperturbed points (MeasureErrors). CGAL is fed the noise mode's stencils (d/2+1
// rings grown to 3x the coefficients: the larger of the two, CGAL's best case) and, as
// "CGAL-d", the default stencils.
//
// Usage: noise_study [surfaces=torus,bump] [powers=2,3] [degrees=2,3,4] [n list=16,32,64]
//                    [alpha=0.1] [smoothing passes list=-1]
// A surface may also name external meshes, one per entry of the n list (printf patterns):
// `torus@/dir/gmsh_L%d.obj` perturbs the mesh read (vertices on the surface), and
// `torus@/dir/mc%d_raw.obj@/dir/mc%d_proj.obj` fits the first (alpha = 0: as read) and
// measures at the second's vertices (same numbering, on the surface).
// Overrides of the noise mode's fit (experiments): NOISE_MPF (min points factor),
// NOISE_RINGS, NOISE_ND (normal_degree: a normal pre-fit after smoothing). NOISE_DIAG=1
// prints the errors within 3 rings of the boundary and inside separately.
// NOISE_DUMP=prefix writes per-vertex exact / fitted H, K and normal errors of the noise
// mode and CGAL to prefix_{noise,cgal}_SURFACE_dD_nN.txt (error distributions).
// NOISE_AUTO=1 adds a series "auto" (FitOptions::noise = kAuto, otherwise default options).
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench/cgal_jet.h"
#include "bench/bench_args.h"
#include "core/fitting/fit.h"
#include "core/fitting/noise.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"
#include "core/util/timer.h"

using namespace geomfit;

namespace {

struct Series {
  std::string name;
  std::vector<DifferentialErrors> errors;
};

void Print(const Series& s, const std::vector<double>& hs, const Series* ref) {
  std::printf("  %-12s", s.name.c_str());
  for (const DifferentialErrors& e : s.errors)
    std::printf(" | %8.2e %8.2e %8.2e %8.2e", e.normal.l2, e.normal.linf, e.mean.l2, e.gaussian.l2);
  auto order = [&](auto get) {
    std::vector<double> v;
    for (const DifferentialErrors& e : s.errors) v.push_back(get(e));
    return ConvergenceOrder(hs, v);
  };
  std::printf(" || orders %5.2f %5.2f %5.2f %5.2f", order([](auto& e) { return e.normal.l2; }),
              order([](auto& e) { return e.normal.linf; }), order([](auto& e) { return e.mean.l2; }),
              order([](auto& e) { return e.gaussian.l2; }));
  if (ref) {  // worst ratio to the reference over levels and the four norms
    double worst = 0;
    for (size_t i = 0; i < s.errors.size(); ++i) {
      const DifferentialErrors &a = s.errors[i], &b = ref->errors[i];
      for (double r : {a.normal.l2 / b.normal.l2, a.normal.linf / b.normal.linf, a.mean.l2 / b.mean.l2,
                       a.gaussian.l2 / b.gaussian.l2})
        worst = std::max(worst, r);
    }
    std::printf(" | max ratio to %s %.2f", ref->name.c_str(), worst);
  }
  std::printf("\n");
}

// Rings from the boundary (BFS over edges); closed meshes: all large.
std::vector<int> BoundaryDistance(const Topology& topo) {
  std::vector<int> dist(topo.num_vertices, 1 << 20), queue;
  for (int v = 0; v < topo.num_vertices; ++v)
    if (topo.is_boundary[v]) dist[v] = 0, queue.push_back(v);
  for (size_t i = 0; i < queue.size(); ++i)
    for (int k = 0; k < topo.NumNeighbors(queue[i]); ++k) {
      const int w = topo.Neighbors(queue[i])[k];
      if (dist[w] > dist[queue[i]] + 1) dist[w] = dist[queue[i]] + 1, queue.push_back(w);
    }
  return dist;
}

// NOISE_DIAG: errors near the boundary (<= 3 rings) and inside, separately.
void Diagnose(const char* what, const Mesh& clean, const AnalyticSurface& surface, const Differentials& d,
              const Topology& topo) {
  const std::vector<int> dist = BoundaryDistance(topo);
  std::vector<uint8_t> near(dist.size()), inside(dist.size());
  for (size_t v = 0; v < dist.size(); ++v) near[v] = dist[v] <= 3, inside[v] = dist[v] > 3;
  const DifferentialErrors a = MeasureErrors(clean, surface, d, inside);
  std::printf("    diag %-8s inside: n %8.2e %8.2e H %8.2e K %8.2e", what, a.normal.l2, a.normal.linf, a.mean.l2,
              a.gaussian.l2);
  if (std::count(near.begin(), near.end(), 1) > 0) {
    const DifferentialErrors b = MeasureErrors(clean, surface, d, near);
    std::printf(" | near boundary: n %8.2e %8.2e H %8.2e K %8.2e", b.normal.l2, b.normal.linf, b.mean.l2,
                b.gaussian.l2);
  }
  std::printf("\n");
}

// NOISE_DUMP=prefix: per-vertex exact and fitted H, K and normal errors (text, one row per
// vertex) of `d`, to study the error distributions.
void Dump(const std::string& path, const Mesh& clean, const AnalyticSurface& surface, const Differentials& d) {
  FILE* f = std::fopen(path.c_str(), "w");
  if (!f) return;
  for (int v = 0; v < clean.NumVertices(); ++v) {
    const ExactDifferentials e = surface.At(clean.positions.row(v).transpose());
    std::fprintf(f, "%.9g %.9g %.9g %.9g %.9g\n", e.mean, e.gaussian, d.mean(v), d.gaussian(v),
                 (d.normals.row(v).transpose() - e.normal).norm());
  }
  std::fclose(f);
}

}  // namespace

int main(int argc, char** argv) {
  const auto surfaces = SplitList(argc > 1 ? argv[1] : nullptr, "torus,bump");
  const auto powers = SplitList(argc > 2 ? argv[2] : nullptr, "2,3");
  const auto degrees = SplitList(argc > 3 ? argv[3] : nullptr, "2,3,4");
  const auto ns = SplitList(argc > 4 ? argv[4] : nullptr, "16,32,64");
  const double alpha = argc > 5 ? std::atof(argv[5]) : 0.1;
  const auto passes = SplitList(argc > 6 ? argv[6] : nullptr, "-1");
  std::printf("columns per level: normal L2, normal Linf, H L2, K L2; orders in the same order; "
              "alpha = %g\n", alpha);
  for (const std::string& name : surfaces) {
    std::vector<std::string> parts;  // surface[@fit pattern[@measure pattern]]
    {
      std::stringstream ss(name);
      for (std::string s; std::getline(ss, s, '@');) parts.push_back(s);
    }
    auto surface = NamedSurface(parts[0]).value();
    auto load = [&](const std::string& pattern, const std::string& n) {
      char path[1024];
      std::snprintf(path, sizeof path, pattern.c_str(), std::atoi(n.c_str()));
      return ReadMesh(path).value();
    };
    for (const std::string& pw : powers) {
      for (const std::string& ds : degrees) {
        const int k = std::atoi(pw.c_str()), d = std::atoi(ds.c_str());
        std::vector<Series> series;
        series.push_back({"default", {}});
        for (const std::string& p : passes) series.push_back({"noise sp=" + p, {}});
        const bool with_auto = std::getenv("NOISE_AUTO") != nullptr;
        if (with_auto) series.push_back({"auto", {}});
        series.push_back({"CGAL", {}});
        series.push_back({"CGAL-d", {}});
        std::vector<double> hs;
        for (const std::string& n : ns) {
          GeneratorOptions g;
          g.n = std::atoi(n.c_str());
          const Mesh clean = parts.size() > 1 ? load(parts.back(), n) : GenerateNamedMesh(name, g).value();
          const Mesh base = parts.size() > 2 ? load(parts[1], n) : clean;
          const Mesh mesh = alpha > 0 ? PerturbAlongNormals(base, *surface, alpha, k) : base;
          const Topology topo = BuildTopology(mesh).value();
          hs.push_back(AverageEdgeLength(clean));
          if (std::getenv("NOISE_ESTIMATE_ONLY")) {
            const NoiseEstimate est =
                EstimateNoise(mesh, topo, ApproximateVertexNormals(mesh, topo, NormalWeighting::kArea)).value();
            std::printf("%s O(h^%d) a=%g n=%s nv=%d: ratio %.4f sextic %.3f cubic %.3f level/h %.2e -> %s\n", name.c_str(), k,
                        alpha, n.c_str(), mesh.NumVertices(), est.residual_ratio, est.sextic_ratio, est.cubic_ratio, est.noise_over_h,
                        est.noisy ? "noisy" : "clean");
            continue;
          }
          FitOptions o;
          o.degree = d;
          Stopwatch watch;
          const Differentials def = ComputeDifferentials(*FitSurface(mesh, topo, o).value());
          std::vector<double> secs = {watch.Seconds()};
          series[0].errors.push_back(MeasureErrors(clean, *surface, def));
          for (size_t i = 0; i < passes.size(); ++i) {
            FitOptions on = o;
            on.noise = NoiseMode::kOn;
            on.smoothing_passes = std::atoi(passes[i].c_str());
            if (const char* e = std::getenv("NOISE_MPF")) on.min_points_factor = std::atof(e);
            if (const char* e = std::getenv("NOISE_RINGS")) on.rings = std::atof(e);
            if (const char* e = std::getenv("NOISE_ND")) on.normal_degree = std::atoi(e);
            watch = Stopwatch();
            const Differentials dn = ComputeDifferentials(*FitSurface(mesh, topo, on).value());
            secs.push_back(watch.Seconds());
            series[1 + i].errors.push_back(MeasureErrors(clean, *surface, dn));
            if (std::getenv("NOISE_DIAG")) Diagnose("noise", clean, *surface, dn, topo);
            if (const char* e = std::getenv("NOISE_DUMP"))
              Dump(std::string(e) + "_noise_" + parts[0] + "_d" + ds + "_n" + n + ".txt", clean, *surface, dn);
          }
          if (with_auto) {
            FitOptions au = o;
            au.noise = NoiseMode::kAuto;
            watch = Stopwatch();
            const Differentials da = ComputeDifferentials(*FitSurface(mesh, topo, au).value());
            secs.push_back(watch.Seconds());
            series[1 + passes.size()].errors.push_back(MeasureErrors(clean, *surface, da));
          }
          FitOptions on = o;
          on.noise = NoiseMode::kOn;
          int few = 0;
          const Neighborhoods nb = BuildNeighborhoods(topo, mesh, RingSpecFor(on));
          const Differentials dc = CgalDifferentials(mesh, nb, d, def.normals, &few);
          series[series.size() - 2].errors.push_back(MeasureErrors(clean, *surface, dc));
          if (std::getenv("NOISE_DIAG")) Diagnose("CGAL", clean, *surface, dc, topo);
          if (const char* e = std::getenv("NOISE_DUMP"))
            Dump(std::string(e) + "_cgal_" + parts[0] + "_d" + ds + "_n" + n + ".txt", clean, *surface, dc);
          const Neighborhoods nbd = BuildNeighborhoods(topo, mesh, RingSpecFor(o));
          series.back().errors.push_back(MeasureErrors(clean, *surface, CgalDifferentials(mesh, nbd, d, def.normals, &few)));
          const Positions normals = ApproximateVertexNormals(mesh, topo, NormalWeighting::kArea);
          const NoiseEstimate est = EstimateNoise(mesh, topo, normals).value();
          std::printf("%s O(h^%d) d=%d n=%s: noise estimate ratio %.3f sextic %.3f level/h %.2e curvature h %.3f grow %.1f -> %s; fit s",
                      name.c_str(), k, d, n.c_str(), est.residual_ratio, est.sextic_ratio, est.noise_over_h, est.curvature_h,
                      NoiseSmoothingPointsFactor(est, 2, 3), NoisyAt(est, d) ? "noisy" : "clean");
          for (double t : secs) std::printf(" %.2f", t);
          std::printf("\n");
        }
        if (std::getenv("NOISE_ESTIMATE_ONLY")) continue;
        std::printf("%s, O(h^%d) perturbation, degree %d\n", name.c_str(), k, d);
        const Series& cgal = series[series.size() - 2];
        for (const Series& s : series) Print(s, hs, &s == &cgal ? nullptr : &cgal);
        // The finest level against the better CGAL run per norm (issue 16's comparison).
        const DifferentialErrors &c = cgal.errors.back(), &cd = series.back().errors.back();
        for (size_t i = 1; i + 2 < series.size(); ++i) {
          const DifferentialErrors& e = series[i].errors.back();
          auto ratio = [](double a, double b, double b2) { return a / std::min(b, b2); };
          std::printf("  %-12s finest level / best CGAL: normal %.2f (Linf %.2f) H %.2f (Linf %.2f) K %.2f (Linf %.2f)\n",
                      series[i].name.c_str(), ratio(e.normal.l2, c.normal.l2, cd.normal.l2),
                      ratio(e.normal.linf, c.normal.linf, cd.normal.linf), ratio(e.mean.l2, c.mean.l2, cd.mean.l2),
                      ratio(e.mean.linf, c.mean.linf, cd.mean.linf), ratio(e.gaussian.l2, c.gaussian.l2, cd.gaussian.l2),
                      ratio(e.gaussian.linf, c.gaussian.linf, cd.gaussian.linf));
        }
        // The best CGAL's finest-level errors (the tests' hard-coded references).
        std::printf("  best CGAL    finest level: normal %.3e (Linf %.3e) H %.3e (Linf %.3e) K %.3e (Linf %.3e)\n",
                    std::min(c.normal.l2, cd.normal.l2), std::min(c.normal.linf, cd.normal.linf),
                    std::min(c.mean.l2, cd.mean.l2), std::min(c.mean.linf, cd.mean.linf),
                    std::min(c.gaussian.l2, cd.gaussian.l2), std::min(c.gaussian.linf, cd.gaussian.linf));
      }
    }
  }
  return 0;
}
