// Convergence study: errors and observed orders of fitted normals and curvatures on the
// project's analytic test meshes. Usage: convergence_study [surface] [method] [n0] [levels]
//   [dmin] [dmax] [2 = two-pass]; method lhf|lop|xu|lscm, "-svd" appended for the SVD solver.
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"
#include "core/util/timer.h"

using namespace geomfit;

int main(int argc, char** argv) {
  const std::string name = argc > 1 ? argv[1] : "torus";
  const std::string method = argc > 2 ? argv[2] : "lhf";
  const int n0 = argc > 3 ? std::atoi(argv[3]) : 8;
  const int levels = argc > 4 ? std::atoi(argv[4]) : 4;
  const int dmin = argc > 5 ? std::atoi(argv[5]) : 1, dmax = argc > 6 ? std::atoi(argv[6]) : 6;
  const bool two_pass = argc > 7 && std::string(argv[7]) == "2";
  auto surface = NamedSurface(name).value();
  std::printf("%s %s two_pass=%d\n deg     h          nrmL2    nrmLinf  HL2      HLinf    KL2      KLinf   downgraded\n",
              name.c_str(), method.c_str(), two_pass);
  for (int d = dmin; d <= dmax; ++d) {
    std::vector<double> hs, e[6];
    for (int l = 0; l < levels; ++l) {
      GeneratorOptions g;
      g.n = n0 << l;
      Mesh mesh = GenerateNamedMesh(name, g).value();
      FitOptions o;
      o.degree = d;
      o.two_pass = two_pass;
      o.method = method.rfind("lop", 0) == 0    ? FitMethod::kLOP
                 : method.rfind("xu", 0) == 0   ? FitMethod::kXu
                 : method.rfind("lscm", 0) == 0 ? FitMethod::kLSCM
                                                : FitMethod::kLHF;
      if (method.find("-svd") != std::string::npos) o.solver = WlsSolver::kSVD;
      auto diff = ComputeDifferentials(mesh, o).value();
      int down = 0;
      for (auto& dg : diff.diagnostics) down += (dg.flags & kFlagDowngraded) != 0;
      DifferentialErrors err = MeasureErrors(mesh, *surface, diff);
      hs.push_back(err.h);
      double v[6] = {err.normal.l2, err.normal.linf, err.mean.l2, err.mean.linf, err.gaussian.l2, err.gaussian.linf};
      std::printf(" %d  %6d %.3e", d, mesh.NumVertices(), err.h);
      for (int i = 0; i < 6; ++i) e[i].push_back(v[i]), std::printf(" %.2e", v[i]);
      std::printf("  %d\n", down);
    }
    std::printf(" order d=%d:          ", d);
    for (int i = 0; i < 6; ++i) std::printf(" %8.2f", ConvergenceOrder(hs, e[i]));
    std::printf("\n");
  }
}
