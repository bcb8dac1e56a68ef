// The dissertation's comparison of parametrizations and solvers (3.3): Table 3.3 timings
// and Figs 3.2-3.10 accuracy of Xu-2, LOP-2, LHF-2..4, LSCM-2..4 (and LHF with the SVD
// solver) on the same meshes. One thread; time = FitSurface + ComputeDifferentials (the
// neighbourhoods are built outside the timing, as the text's Table 3.3 times the fits).
//
// Usage: methods_study [surfaces=torus,bump] [n list=16,32,64,128] [repeats=3]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "bench/bench_args.h"
#include "core/fitting/fit.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"
#include "core/util/timer.h"

using namespace geomfit;

namespace {

struct Method {
  std::string name;
  FitMethod method;
  int degree;
  WlsSolver solver;
};

}  // namespace

int main(int argc, char** argv) {
  const auto surfaces = SplitList(argc > 1 ? argv[1] : nullptr, "torus,bump");
  const auto ns = SplitList(argc > 2 ? argv[2] : nullptr, "16,32,64,128");
  const int repeats = argc > 3 ? std::atoi(argv[3]) : 3;
  const std::vector<Method> methods = {
      {"Xu-2", FitMethod::kXu, 2, WlsSolver::kQR},       {"LOP-2", FitMethod::kLOP, 2, WlsSolver::kQR},
      {"LHF-2", FitMethod::kLHF, 2, WlsSolver::kQR},     {"LHF-2-svd", FitMethod::kLHF, 2, WlsSolver::kSVD},
      {"LHF-3", FitMethod::kLHF, 3, WlsSolver::kQR},     {"LHF-4", FitMethod::kLHF, 4, WlsSolver::kQR},
      {"LSCM-2", FitMethod::kLSCM, 2, WlsSolver::kQR},   {"LSCM-3", FitMethod::kLSCM, 3, WlsSolver::kQR},
      {"LSCM-4", FitMethod::kLSCM, 4, WlsSolver::kQR},   {"LHF-4-svd", FitMethod::kLHF, 4, WlsSolver::kSVD}};
  std::printf("time: best of %d, one thread, FitSurface + ComputeDifferentials (ms); errors as "
              "core/surfaces/errors.h; Xu-2 errors over interior vertices on open surfaces\n",
              repeats);
  for (const std::string& name : surfaces) {
    auto surface = NamedSurface(name).value();
    std::printf("\n%s\n  %-10s %7s %7s %9s %9s %9s %9s %9s %8s\n", name.c_str(), "method", "n", "#tri",
                "ms", "ktri/s", "nrmL2", "nrmLinf", "HL2", "KL2");
    for (const Method& m : methods) {
      std::vector<double> hs, e[4];
      for (const std::string& n : ns) {
        GeneratorOptions g;
        g.n = std::atoi(n.c_str());
        const Mesh mesh = GenerateNamedMesh(name, g).value();
        const Topology topo = BuildTopology(mesh).value();
        FitOptions o;
        o.degree = m.degree;
        o.method = m.method;
        o.solver = m.solver;
        auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(o), 1));
        double best = 1e30;
        Differentials d;
        for (int r = 0; r < repeats; ++r) {
          Stopwatch t;
          auto fits = FitSurface(mesh, topo, o, nb, {}, RunContext(nullptr, 1)).value();
          d = ComputeDifferentials(*fits, kAllQuantities, RunContext(nullptr, 1)).value();
          best = std::min(best, t.Seconds());
        }
        std::vector<uint8_t> mask;
        if (m.method == FitMethod::kXu && topo.num_boundary_edges) {
          mask.resize(mesh.NumVertices());
          for (int v = 0; v < mesh.NumVertices(); ++v) mask[v] = !topo.is_boundary[v];
        }
        const DifferentialErrors err = MeasureErrors(mesh, *surface, d, mask);
        hs.push_back(err.h);
        const double v[4] = {err.normal.l2, err.normal.linf, err.mean.l2, err.gaussian.l2};
        for (int i = 0; i < 4; ++i) e[i].push_back(v[i]);
        std::printf("  %-10s %7s %7d %9.2f %9.0f %9.2e %9.2e %9.2e %9.2e\n", m.name.c_str(), n.c_str(),
                    mesh.NumFaces(), best * 1e3, mesh.NumFaces() / best / 1e3, v[0], v[1], v[2], v[3]);
      }
      std::printf("  %-10s orders %45.2f %9.2f %9.2f %9.2f\n", m.name.c_str(), ConvergenceOrder(hs, e[0]),
                  ConvergenceOrder(hs, e[1]), ConvergenceOrder(hs, e[2]), ConvergenceOrder(hs, e[3]));
    }
  }
  return 0;
}
