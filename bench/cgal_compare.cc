// Accuracy side by side at equal degree: geomfit (LHF, default FitOptions) against CGAL's
// Jet_fitting_3 (CGAL::Monge_via_jet_fitting, d_fitting = d, d_monge = 2), both fed the
// SAME per-vertex stencils (BuildNeighborhoods(RingSpecFor(options))), errors measured
// with MeasureErrors (core/surfaces/errors.h) against the exact surface.
//
// Usage: cgal_compare [dmin=2] [dmax=4] [surfaces=torus,bump] [n list=16,32,64]
// (degree 1: CGAL's degree-1 jet gives normals only; its H and K are NaN and left out of the summary)
//
// A surface may also name external meshes: `torus@/dir/gmsh_L%d.obj` reads one mesh per
// entry of the n list (printf pattern), errors against the named exact surface at each
// vertex; `torus@/dir/mc%d_raw.obj@/dir/mc%d_proj.obj` fits the first (noisy) meshes and
// measures at the second's vertices (the same numbering, positions on the surface).
//
// Environment overrides of our fit only: GF_RINGS, GF_MPF, GF_EPS, GF_ND (normal_degree),
// GF_HERM (hermite_hessian), GF_SLOPES (slope_refinement),
// GF_QH (quadratic_hermite: 1 = on), GF_CH (cubic_hermite: 0 = off), GF_PH (plane_hermite: 0 = off), GF_JH (jet_hermite: 1 = on, 0 = off; unset = the default: on at degree 5 only), GF_TWO (two_pass); of CGAL's stencils only: GF_CGAL_RINGS, GF_CGAL_MPF; of both:
// GF_NOISE (the noise mode's stencils), GF_NEARDUP (RingSpec::count_near_duplicates).
//
// CGAL's results are converted to the project's conventions in bench/cgal_jet.h.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <omp.h>

#include "bench/cgal_jet.h"
#include "core/fitting/fit.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"
#include "core/util/timer.h"

using namespace geomfit;

namespace {

struct Row {
  std::string surface;
  int n, degree, nv;
  double h;
  DifferentialErrors ours, cgal;
  double ours_s, cgal_s;
  int downgraded, cgal_too_few;
  double stencil;
};

void PrintErr(const char* who, const DifferentialErrors& e, double secs) {
  std::printf("  %-7s %9.2e %9.2e %9.2e %9.2e %9.2e %9.2e", who, e.normal.l2, e.normal.linf, e.mean.l2,
              e.mean.linf, e.gaussian.l2, e.gaussian.linf);
  if (secs >= 0) std::printf(" %8.3f", secs);
  std::printf("\n");
}

// The six norms in print order.
std::vector<double> Norms(const DifferentialErrors& e) {
  return {e.normal.l2, e.normal.linf, e.mean.l2, e.mean.linf, e.gaussian.l2, e.gaussian.linf};
}

}  // namespace

int main(int argc, char** argv) {
  const int dmin = argc > 1 ? std::atoi(argv[1]) : 2;
  const int dmax = argc > 2 ? std::atoi(argv[2]) : 4;
  std::vector<std::string> surfaces;
  {
    std::stringstream ss(argc > 3 ? argv[3] : "torus,bump");
    for (std::string s; std::getline(ss, s, ',');) surfaces.push_back(s);
  }
  std::vector<int> ns;
  {
    std::stringstream ss(argc > 4 ? argv[4] : "16,32,64");
    for (std::string s; std::getline(ss, s, ',');) ns.push_back(std::atoi(s.c_str()));
  }
  std::printf("geomfit (LHF, default FitOptions) vs CGAL Monge_via_jet_fitting(d, 2) on the same stencils\n"
              "errors as core/surfaces/errors.h: normals L2 = sqrt(mean |dn|^2), Linf = max |dn|;\n"
              "H and K relative: L2 = |dk|_2/|k|_2, Linf = max|dk|/max|k|. time = wall seconds "
              "(fit+quantities / CGAL loop), %d OpenMP threads\n\n",
              omp_get_max_threads());
  std::vector<Row> rows;
  for (const std::string& name : surfaces) {
    std::vector<std::string> parts;  // surface[@fit pattern[@measure pattern]]
    {
      std::stringstream ss(name);
      for (std::string s; std::getline(ss, s, '@');) parts.push_back(s);
    }
    auto surface = NamedSurface(parts[0]).value();
    auto load = [&](const std::string& pattern, int n) {
      char path[1024];
      std::snprintf(path, sizeof path, pattern.c_str(), n);
      return ReadMesh(path).value();
    };
    for (int d = dmin; d <= dmax; ++d) {
      std::printf("%s, degree %d\n    n     #V   stencil  h         downgr  CGAL<ncoef\n", name.c_str(), d);
      std::printf("  %-7s %9s %9s %9s %9s %9s %9s %8s\n", "", "nrmL2", "nrmLinf", "HL2", "HLinf", "KL2",
                  "KLinf", "time_s");
      for (int n : ns) {
        GeneratorOptions g;
        g.n = n;
        Mesh mesh = parts.size() > 1 ? load(parts[1], n) : GenerateNamedMesh(name, g).value();
        const Mesh at = parts.size() > 2 ? load(parts[2], n) : mesh;  // where errors are measured
        Topology topo = BuildTopology(mesh).value();
        FitOptions o;
        o.degree = d;
        if (std::getenv("GF_NOISE")) o.noise = NoiseMode::kOn;  // both: the noise mode's stencils
        const auto spec_for = [](const FitOptions& f) {  // GF_NEARDUP: both fits' stencils
          RingSpec s = RingSpecFor(f);
          s.count_near_duplicates = std::getenv("GF_NEARDUP") != nullptr;
          return s;
        };
        auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, spec_for(o)));
        FitOptions ours_o = o;  // experiment overrides (CGAL keeps the default stencils)
        if (const char* e = std::getenv("GF_RINGS")) ours_o.rings = std::atof(e);
        if (const char* e = std::getenv("GF_MPF")) ours_o.min_points_factor = std::atof(e);
        if (const char* e = std::getenv("GF_EPS")) ours_o.weight_epsilon = std::atof(e);
        if (const char* e = std::getenv("GF_ND")) ours_o.normal_degree = std::atoi(e);
        if (std::getenv("GF_HERM")) ours_o.hermite_hessian = true;  // Hermite curvatures
        if (const char* e = std::getenv("GF_SLOPES")) ours_o.slope_refinement = std::atoi(e);  // slope passes
        if (const char* e = std::getenv("GF_QH")) ours_o.quadratic_hermite = std::atoi(e) != 0;  // degree-2 operator refinement
        if (const char* e = std::getenv("GF_CH")) ours_o.cubic_hermite = std::atoi(e) != 0;  // degree-3 Hermite
        if (const char* e = std::getenv("GF_JH")) ours_o.jet_hermite = std::atoi(e) != 0 ? JetHermiteMode::kOn : JetHermiteMode::kOff;  // degree-4/5 Hermite
        if (const char* e = std::getenv("GF_PH")) ours_o.plane_hermite = std::atoi(e) != 0;  // degree-1 Hermite normals
        if (std::getenv("GF_TWO")) ours_o.two_pass = true;  // refit in the first pass's fitted normals
        auto ours_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, spec_for(ours_o)));
        Row r;
        r.surface = name, r.n = n, r.degree = d, r.nv = mesh.NumVertices();
        r.stencil = double(nb->indices.size()) / mesh.NumVertices();
        Stopwatch t;
        auto fits = FitSurface(mesh, topo, ours_o, ours_nb).value();
        Differentials ours = ComputeDifferentials(*fits);
        r.ours_s = t.Seconds();
        r.downgraded = 0;
        for (auto& dg : ours.diagnostics) r.downgraded += (dg.flags & kFlagDowngraded) != 0;
        // CGAL on other stencils (its best ones may be larger than ours): GF_CGAL_RINGS,
        // GF_CGAL_MPF override the rings / min_points_factor of CGAL's stencils only.
        auto cgal_nb = nb;
        if (std::getenv("GF_CGAL_RINGS") || std::getenv("GF_CGAL_MPF")) {
          FitOptions co = o;
          if (const char* e = std::getenv("GF_CGAL_RINGS")) co.rings = std::atof(e);
          if (const char* e = std::getenv("GF_CGAL_MPF")) co.min_points_factor = std::atof(e);
          cgal_nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, spec_for(co)));
        }
        Stopwatch tc;
        Differentials cgal = CgalDifferentials(mesh, *cgal_nb, d, ours.normals, &r.cgal_too_few);
        r.cgal_s = tc.Seconds();
        r.ours = MeasureErrors(at, *surface, ours);
        r.cgal = MeasureErrors(at, *surface, cgal);
        r.h = r.ours.h;
        std::printf("  %4d %7d %6.1f  %.3e  %6d  %6d\n", n, r.nv, r.stencil, r.h, r.downgraded, r.cgal_too_few);
        PrintErr("geomfit", r.ours, r.ours_s);
        PrintErr("CGAL", r.cgal, r.cgal_s);
        if (!topo.num_boundary_edges) {
          rows.push_back(r);
          continue;
        }
        std::vector<uint8_t> interior(mesh.NumVertices());
        for (int v = 0; v < mesh.NumVertices(); ++v) interior[v] = !topo.is_boundary[v];
        std::printf("  interior vertices only (%d boundary vertices excluded):\n",
                    mesh.NumVertices() - static_cast<int>(std::count(interior.begin(), interior.end(), 1)));
        PrintErr("geomfit", MeasureErrors(at, *surface, ours, interior), -1);
        PrintErr("CGAL", MeasureErrors(at, *surface, cgal, interior), -1);
        rows.push_back(r);
      }
      // Observed orders over the three meshes (least-squares slope of log err vs log h).
      std::vector<double> hs;
      std::vector<std::vector<double>> eo(6), ec(6);
      for (const Row& r : rows) {
        if (r.surface != name || r.degree != d) continue;
        hs.push_back(r.h);
        auto a = Norms(r.ours), b = Norms(r.cgal);
        for (int i = 0; i < 6; ++i) eo[i].push_back(a[i]), ec[i].push_back(b[i]);
      }
      std::printf("  order geomfit");
      for (int i = 0; i < 6; ++i) std::printf(" %9.2f", ConvergenceOrder(hs, eo[i]));
      std::printf("\n  order CGAL   ");
      for (int i = 0; i < 6; ++i) std::printf(" %9.2f", ConvergenceOrder(hs, ec[i]));
      std::printf("\n\n");
    }
  }
  // Summary: in how many (surface, n, degree, norm) cells is geomfit's error <= CGAL's?
  const char* names[6] = {"nrmL2", "nrmLinf", "HL2", "HLinf", "KL2", "KLinf"};
  int le = 0, total = 0;
  double worst = 0;
  std::string worst_at;
  for (const Row& r : rows) {
    auto a = Norms(r.ours), b = Norms(r.cgal);
    for (int i = 0; i < 6; ++i) {
      if (!std::isfinite(b[i])) continue;  // CGAL's degree-1 jets: normals only
      ++total;
      if (a[i] <= b[i]) ++le;
      if (a[i] / b[i] > worst) {
        worst = a[i] / b[i];
        worst_at = r.surface + " n=" + std::to_string(r.n) + " d=" + std::to_string(r.degree) + " " + names[i];
      }
    }
  }
  std::printf("summary: geomfit error <= CGAL error in %d of %d cells (all vertices); "
              "largest ratio geomfit/CGAL = %.3f at %s\n",
              le, total, worst, worst_at.c_str());
  return 0;
}
