// Chapter 6 studies (bench/README.md, "Membranes").
//   membrane_study torus [degrees]     the §6.4.1 torus expansion on five levels (328 ... 85k
//                                      vertices): L2 / L-inf relative pressure errors and rates
//   membrane_study throughput [threads] interface-pressure throughput at ~10k and ~100k
//                                      vertices (reference fit and membrane evaluation apart)
//   membrane_study newton [n] [degree] [solver]  the pressure-load solve of the unit sphere
//                                      (solver: umfpack[,amd], sparselu, klu, bicgstab-ilut,
//                                      gmres[,onering][,fixed][,gs=S][,restart=R][,amd])
//                                      under [p] = 2 (cubed sphere of level n), one thread,
//                                      time split (fit, assembly, factorization, solve), CPU
//                                      seconds (getrusage) and peak resident memory
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <sys/resource.h>

#include "absl/strings/str_split.h"
#include "core/mechanics/membrane.h"
#include "core/mechanics/pressure_solve.h"
#include "core/operators/operators.h"
#include "core/surfaces/analytic.h"
#include "core/util/timer.h"

using namespace geomfit;

namespace {

double CpuSeconds() {
  rusage u;
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_utime.tv_usec * 1e-6 + u.ru_stime.tv_sec + u.ru_stime.tv_usec * 1e-6;
}
double PeakResidentMb() {
  rusage u;
  getrusage(RUSAGE_SELF, &u);
  return u.ru_maxrss / 1024.0;
}

MembraneOptions Material() {
  MembraneOptions m;
  m.E = 100;
  m.nu = 0.2;
  return m;
}

double TorusPhi(const Eigen::Vector3d& x) { return std::atan2(x.z(), std::hypot(x.x(), x.y()) - 1.0); }

void Torus(const std::vector<int>& degrees) {
  const MembraneOptions mat = Material();
  std::printf("degree  vertices      L2 rel.    L-inf rel.\n");
  for (int d : degrees) {
    std::vector<double> l2s, lis;
    for (int n : {10, 21, 42, 84, 168}) {
      GeneratorOptions g;
      g.n = n;
      const Mesh m = GenerateTorusMesh(g);
      const Topology topo = BuildTopology(m).value();
      Positions y(m.NumVertices(), 3);
      Eigen::VectorXd exact(m.NumVertices());
      for (int i = 0; i < m.NumVertices(); ++i) {
        const Eigen::Vector3d x = m.positions.row(i).transpose();
        const double t = std::atan2(x.y(), x.x()), f = TorusPhi(x);
        const double A = 1 + 0.3 * std::cos(f), A1 = 1.05 + 0.32 * std::cos(f);
        y.row(i) << A1 * std::cos(t), A1 * std::sin(t), 0.32 * std::sin(f);
        const double lt = A1 / A, lp = 0.32 / 0.3, et = (lt * lt - 1) / 2, ep = (lp * lp - 1) / 2;
        const double tt = mat.Lambda() * (et + ep) + 2 * mat.Mu() * et;
        const double tp = mat.Lambda() * (et + ep) + 2 * mat.Mu() * ep;
        exact(i) = tt * std::cos(f) / A1 + tp / 0.32;
      }
      FitOptions fit;
      fit.degree = d;
      const MembraneFields f = ComputeMembrane(m, topo, y, mat, fit).value();
      const Eigen::VectorXd e = f.pressure - exact;
      const double l2 = e.norm() / exact.norm();
      const double li = (e.array().abs() / exact.array().abs()).maxCoeff();
      l2s.push_back(l2), lis.push_back(li);
      std::printf("%6d  %8d  %10.3e  %10.3e\n", d, m.NumVertices(), l2, li);
    }
    std::printf("degree %d rates log2(e1/e5)/4: L2 %.2f, L-inf %.2f\n", d, std::log2(l2s.front() / l2s.back()) / 4,
                std::log2(lis.front() / lis.back()) / 4);
  }
}

void Throughput(int threads) {
  const RunContext ctx = RunContext().WithThreads(threads);
  std::printf("vertices  degree  fit (s)  membrane (s)  membrane vertices/s  fit+membrane vertices/s\n");
  for (int n : {41, 129}) {
    GeneratorOptions g;
    g.n = n;
    const Mesh m = GenerateSphereMesh(g);
    const Topology topo = BuildTopology(m).value();
    const Positions y = 1.1 * m.positions;
    for (int d : {2, 4}) {
      FitOptions fit;
      fit.degree = d;
      Stopwatch w;
      auto fits = FitForOperators(m, topo, fit, nullptr, ctx).value();
      const double fit_s = w.Seconds();
      double best = 1e30;
      for (int rep = 0; rep < 3; ++rep) {
        w = Stopwatch();
        const MembraneFields f = ComputeMembrane(*fits, m.positions, y, Material(), ctx).value();
        best = std::min(best, w.Seconds());
      }
      std::printf("%8d  %6d  %7.3f  %12.4f  %19.3g  %23.3g\n", m.NumVertices(), d, fit_s, best,
                  m.NumVertices() / best, m.NumVertices() / (best + fit_s));
    }
  }
}

void Newton(int n, int degree, const std::string& solver) {
  GeneratorOptions g;
  g.n = n;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  PressureSolveOptions o;
  o.material = Material();
  o.fit.degree = degree;
  const bool ilut = solver == "bicgstab-ilut";
  // "gmres[,onering][,fixed][,tol=T][,max=M][,restart=R][,gs=S]": GMRES (compact
  // preconditioner, Eisenstat-Walker forcing and the options' Gauss-Seidel sweeps unless
  // told otherwise), UMFPACK for the preconditioner; ",amd" anywhere: UMFPACK's own
  // ordering instead of METIS.
  o.krylov = solver.rfind("gmres", 0) == 0;
  if (o.krylov) {
    for (const std::string& t : std::vector<std::string>(absl::StrSplit(solver, ','))) {
      if (t == "onering") o.krylov_preconditioner = KrylovPreconditioner::kOneRing;
      if (t == "fixed") o.krylov_forcing = false;
      if (t.rfind("tol=", 0) == 0) o.krylov_tolerance = std::atof(t.c_str() + 4);
      if (t.rfind("max=", 0) == 0) o.krylov_forcing_max = std::atof(t.c_str() + 4);
      if (t.rfind("gs=", 0) == 0) o.krylov_smoothing = std::atoi(t.c_str() + 3);
      if (t.rfind("restart=", 0) == 0) o.krylov_restart = std::atoi(t.c_str() + 8);
    }
  }
  const std::string direct = solver.substr(0, solver.find(','));
  if (solver.find(",amd") != std::string::npos) o.solver.umfpack_metis = false;  // UMFPACK's own ordering
  o.solver.kind = o.krylov ? SolverKind::kUmfpack : ParseSolverKind(ilut ? "bicgstab" : direct).value();
  if (ilut) o.solver.preconditioner = Preconditioner::kIlut;
  Eigen::setNbThreads(1);  // one core: no OpenMP in Eigen's products either
  const double cpu0 = CpuSeconds();
  const Stopwatch w;
  auto r = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o, RunContext().WithThreads(1),
                             [&](const NewtonIteration& it) {
                               std::printf("  iteration %d: residual %.3e step %.3e, %d GMRES iterations (%.1f s)\n",
                                           it.iteration, it.residual, it.step, it.krylov_iterations, w.Seconds());
                             });
  if (!r.ok()) {
    std::printf("sphere %d vertices, degree %d: %s\n", m.NumVertices(), degree, r.status().ToString().c_str());
    return;
  }
  double e = 0;
  const double r1 = 1.0080320;
  for (int i = 0; i < m.NumVertices(); ++i) e = std::max(e, std::abs(r->deformed.row(i).norm() - r1));
  const double cpu = CpuSeconds() - cpu0;
  if (o.krylov) std::printf("  preconditioner solves %.2f s\n", r->precondition_ms / 1e3);
  std::printf("  CPU %.2f s, peak resident %.0f MB\n", cpu, PeakResidentMb());
  std::printf("sphere %d vertices, degree %d, %s: %.2f s total (fit %.2f, assemble %.2f, factorize %.2f, solve %.2f); "
              "%d factorizations, %d GMRES iterations, residual %.2e, max |r - r1| %.2e\n",
              m.NumVertices(), degree, solver.c_str(), w.Seconds(), r->fit_ms / 1e3, r->assemble_ms / 1e3,
              r->factorize_ms / 1e3, r->solve_ms / 1e3, r->factorizations, r->krylov_iterations, r->residual, e);
  if (r->fell_back_to_krylov) std::printf("  (the direct factorization ran out of memory: GMRES took over)\n");
}

}  // namespace

int main(int argc, char** argv) {
  const std::string what = argc > 1 ? argv[1] : "torus";
  if (what == "torus") {
    std::vector<int> degrees;
    for (int i = 2; i < argc; ++i) degrees.push_back(std::atoi(argv[i]));
    if (degrees.empty()) degrees = {2, 3, 4};
    Torus(degrees);
  } else if (what == "throughput") {
    Throughput(argc > 2 ? std::atoi(argv[2]) : 1);
  } else if (what == "newton") {
    Newton(argc > 2 ? std::atoi(argv[2]) : 29, argc > 3 ? std::atoi(argv[3]) : 4, argc > 4 ? argv[4] : "umfpack");
  } else {
    std::fprintf(stderr, "usage: membrane_study torus [degrees] | throughput [threads] | newton [n] [degree] [solver]\n");
    return 2;
  }
  return 0;
}
