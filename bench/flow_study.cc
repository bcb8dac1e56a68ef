// Chapter 5 studies (bench/README.md, "Flows").
//   flow_study table [cubed|delaunay|jittered]
//                      Table 5.1 protocol (unit sphere, 50 x 1e-3, degree 4) on the three
//                      levels, beside the cotan (Dziuk) implicit MCF with lumped mass.
//   flow_study steps [sizes] [threads] [solver] [mcf|surface_diffusion] [scheme]
//                      semi-implicit MCF and SD step times split into fit / assemble /
//                      solve (median of steps 2..4), and a degree-4 fit of the same mesh.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/SparseCholesky>

#include "core/flow/flow.h"
#include "core/integration/integrate.h"
#include "core/reconstruction/surface.h"
#include "core/surfaces/analytic.h"
#include "core/surfaces/errors.h"
#include "core/util/timer.h"

using namespace geomfit;

namespace {

Mesh Sphere(int n) {
  GeneratorOptions g;
  g.n = n;
  return GenerateSphereMesh(g);
}

double MaxRadiusError(const Positions& x, double r) { return (x.rowwise().norm().array() - r).abs().maxCoeff(); }

// The peer: Dziuk's linearly implicit cotan scheme with lumped (barycentric) mass,
// (M^n - dt/2 L^n) x^{n+1} = M^n x^n, for x_t = -H n = (1/2) Laplace-Beltrami x
// (H = (k1 + k2)/2; the literature's H = k1 + k2 has no 1/2).
struct CotanResult {
  Positions x;
  double ms_per_step = 0;
};
CotanResult CotanMcf(const Mesh& mesh, double dt, int steps) {
  const int nv = mesh.NumVertices();
  CotanResult r;
  r.x = mesh.positions;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt;
  const Stopwatch watch;
  Mesh current = mesh;
  for (int s = 0; s < steps; ++s) {
    current.positions = r.x;
    const CotanLaplacian cot = BuildCotanLaplacian(current);
    Eigen::SparseMatrix<double> A = -0.5 * dt * cot.stiffness;
    for (int i = 0; i < nv; ++i) A.coeffRef(i, i) += cot.mass(i);
    if (s == 0) ldlt.analyzePattern(A);
    ldlt.factorize(A);
    const Eigen::MatrixXd rhs = cot.mass.asDiagonal() * Eigen::MatrixXd(r.x);
    r.x = ldlt.solve(rhs);
  }
  r.ms_per_step = watch.Millis() / steps;
  return r;
}

Integrals HighOrder(const Mesh& mesh) {
  FitOptions o;
  o.degree = 4;
  const auto fits = FitSurface(mesh, BuildTopology(mesh).value(), o).value();
  return Integrate(WalfSurface(mesh, fits), IntegrationInput()).value();
}

// Table 5.1's three levels in a mesh family: "cubed" (the project's cubed spheres,
// n = 8 / 16 / 31), "delaunay" (hulls of Fibonacci points with the text's 368 / 1450 /
// 5804 vertices), "jittered" (the same hulls of points jittered by 0.3 x the spacing,
// 400 / 1600 / 6400 vertices: sizes and connectivity the tests never saw).
Mesh TableMesh(const std::string& family, int level) {
  if (family == "delaunay") return GenerateDelaunaySphereMesh((int[]){368, 1450, 5804}[level]);
  if (family == "jittered") return GenerateDelaunaySphereMesh((int[]){400, 1600, 6400}[level], 0.3, 7);
  return Sphere((int[]){8, 16, 31}[level]);
}

void Table(const std::string& family) {
  const double T = 0.05, exact = std::sqrt(1 - 2 * T);
  double floor_r = 1;
  for (int i = 0; i < 50; ++i) floor_r = floor_r * floor_r * floor_r / (floor_r * floor_r + 1e-3);
  const double text[3] = {1.68e-4, 8.76e-5, 8.33e-5};
  std::printf("Table 5.1 (%s meshes): unit sphere, 50 x 1e-3, degree 4, semi-implicit; BE floor %.3e\n",
              family.c_str(), floor_r - exact);
  std::printf("   l  verts  Linf       (text)     spatial    flatA err  flatV err  hoA err    hoV err    ms/step | cotan Linf  ms/step\n");
  std::vector<double> h, sp;
  for (int l = 0; l < 3; ++l) {
    const Mesh mesh = TableMesh(family, l);
    const int n = l;
    FlowOptions o;
    o.dt = 1e-3;
    o.steps = 50;
    FlowResult r;
    const Stopwatch w;
    if (absl::Status s = RunFlow(mesh, o, RunContext(), &r); !s.ok()) {
      std::printf("error: %s\n", s.ToString().c_str());
      return;
    }
    const double ms = w.Millis() / 50;
    const Integrals ho = HighOrder(r.mesh);
    const double A = 4 * M_PI * exact * exact, V = 4 * M_PI / 3 * exact * exact * exact;
    const CotanResult c = CotanMcf(mesh, 1e-3, 50);
    h.push_back(AverageEdgeLength(mesh));
    sp.push_back(MaxRadiusError(r.mesh.positions, floor_r));
    std::printf("  %2d %6d  %.3e  (%.2e)  %.3e  %.3e  %.3e  %.3e  %.3e  %7.1f | %.3e  %6.1f\n", n, mesh.NumVertices(),
                MaxRadiusError(r.mesh.positions, exact), text[l], sp.back(), std::abs(r.steps.back().area - A),
                std::abs(r.steps.back().volume - V), std::abs(ho.area - A), std::abs(ho.volume - V), ms,
                MaxRadiusError(c.x, exact), c.ms_per_step);
  }
  std::printf("spatial order %.2f\n", ConvergenceOrder(h, sp));
  // Semi-implicit at dt = 1e-2 on all three levels.
  for (int n = 0; n < 3; ++n) {
    FlowOptions o;
    o.dt = 1e-2;
    o.steps = 10;
    FlowResult r;
    const absl::Status s = RunFlow(TableMesh(family, n), o, RunContext(), &r);
    double R = 1;
    for (int i = 0; i < 10; ++i) R = R * R * R / (R * R + 1e-2);
    std::printf("semi-implicit dt=1e-2 level %d: %s, spatial error at t=0.1 %.2e\n", n, s.ok() ? "ok" : s.ToString().c_str(),
                MaxRadiusError(r.mesh.positions, R));
  }
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

void Steps(const std::vector<int>& sizes, int threads, const std::string& solver, const std::string& only,
           const std::string& only_scheme) {
  std::printf("step times (ms, median of steps 2..4), threads %d, solver %s\n", threads, solver.c_str());
  std::printf("  flow  scheme          verts     fit4    fit  assemble   solve   total  iters  total/fit4  step1\n");
  for (int target : sizes) {
    const int n = static_cast<int>(std::lround(std::sqrt((target - 2) / 6.0)));
    const Mesh mesh = Sphere(n);
    const Topology topo = BuildTopology(mesh).value();
    FitOptions fo = DefaultFlowFitOptions();
    std::vector<double> fit_times;
    for (int i = 0; i < 3; ++i) {
      const Stopwatch w;
      (void)FitSurface(mesh, topo, fo, nullptr, {}, RunContext(nullptr, threads)).value();
      fit_times.push_back(w.Millis());
    }
    const double fit4 = Median(fit_times);
    for (FlowKind kind : {FlowKind::kMeanCurvature, FlowKind::kSurfaceDiffusion}) {
      if (!only.empty() && only != FlowKindName(kind)) continue;
      for (FlowScheme scheme : {FlowScheme::kSemiImplicit, FlowScheme::kBdf2}) {
        if (!only_scheme.empty() && only_scheme != FlowSchemeName(scheme)) continue;
        FlowOptions o;
        o.kind = kind;
        o.scheme = scheme;
        o.dt = kind == FlowKind::kMeanCurvature ? 1e-3 : 1e-6;
        // "bicgstab-ilut" selects BiCGSTAB with the ILUT preconditioner.
        const bool ilut = solver == "bicgstab-ilut";
        o.solver.kind = ParseSolverKind(ilut ? "bicgstab" : solver).value();
        if (ilut) o.solver.preconditioner = Preconditioner::kIlut;
        if (const char* f = std::getenv("GF_ILUT_FILL")) o.solver.ilut_fill = std::atoi(f);
        if (const char* d = std::getenv("GF_ILUT_DROP")) o.solver.ilut_drop = std::atof(d);
        const RunContext ctx = RunContext().WithThreads(threads);
        auto stepper = FlowStepper::Create(mesh, o, ctx);
        if (!stepper.ok()) {
          std::printf("error: %s\n", stepper.status().ToString().c_str());
          return;
        }
        std::vector<double> f, a, s, tot;
        int iters = 0;
        double first = 0;  // step 1: symbolic analyses, the SD preconditioner's factorization
        for (int i = 0; i < 4; ++i) {
          const Stopwatch w;
          auto st = (*stepper)->Step(ctx);
          if (!st.ok()) {
            std::printf("error: %s\n", st.status().ToString().c_str());
            return;
          }
          if (i == 0) {
            first = w.Millis();
            continue;
          }
          f.push_back(st->fit_ms), a.push_back(st->assemble_ms), s.push_back(st->solve_ms), tot.push_back(w.Millis());
          iters = st->solver_iterations;
        }
        std::printf("  %-4s  %-13s %8d %8.1f %6.1f %8.1f %8.1f %7.1f %5d  %6.2f  %7.1f\n",
                    kind == FlowKind::kMeanCurvature ? "mcf" : "sd", FlowSchemeName(scheme), mesh.NumVertices(), fit4,
                    Median(f), Median(a), Median(s), Median(tot), iters, Median(tot) / fit4, first);
        std::fflush(stdout);
      }
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  const std::string what = argc > 1 ? argv[1] : "table";
  if (what == "table") {
    Table(argc > 2 ? argv[2] : "cubed");
  } else if (what == "steps") {
    std::vector<int> sizes;
    std::stringstream ss(argc > 2 ? argv[2] : "10000,100000");
    for (std::string item; std::getline(ss, item, ',');) sizes.push_back(std::atoi(item.c_str()));
    Steps(sizes, argc > 3 ? std::atoi(argv[3]) : 1, argc > 4 ? argv[4] : "auto", argc > 5 ? argv[5] : "",
          argc > 6 ? argv[6] : "");
  } else {
    std::fprintf(stderr, "usage: flow_study table [cubed|delaunay|jittered] | steps [sizes] [threads] [solver] [mcf|surface_diffusion] [scheme]\n");
    return 2;
  }
}
