// Chapter 5 studies (bench/README.md, "Flows").
//   flow_study table [cubed|delaunay|jittered]
//                      Table 5.1 protocol (unit sphere, 50 x 1e-3, degree 4) on the three
//                      levels, beside the cotan (Dziuk) implicit MCF with lumped mass.
//   flow_study steps [sizes] [threads] [solver] [mcf|surface_diffusion] [scheme]
//                      semi-implicit MCF and SD step times split into fit / assemble /
//                      solve (median of steps 2..4; GF_STEPS=k: of steps k-2..k), and a
//                      degree-4 fit of the same mesh;
//                      solver: auto (default), auto-jacobi, auto-amg, sparselu, ...;
//                      environment GF_TOLERANCE (BiCGSTAB's relative residual),
//                      GF_JACOBI_LIMIT (SolverOptions::jacobi_limit)
//   flow_study amg [sizes] [dt_mcf] [dt_sd]
//                      AMG on the flows' systems outside the stepper: hierarchy, V-cycle
//                      convergence factor and cost, BiCGSTAB iterations against Jacobi.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/SparseCholesky>

#include "core/flow/flow.h"
#include "core/linalg/amg.h"
#include "core/operators/operators.h"
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
  const int last = std::max(4, std::getenv("GF_STEPS") ? std::atoi(std::getenv("GF_STEPS")) : 4);
  std::printf("step times (ms, median of steps %d..%d), threads %d, solver %s\n", last - 2, last, threads,
              solver.c_str());
  std::printf("  flow  scheme          verts     fit4    fit  assemble   solve   total  iters  total/fit4  step1  step-cpu  cpu/fit4-cpu\n");
  for (int target : sizes) {
    const int n = static_cast<int>(std::lround(std::sqrt((target - 2) / 6.0)));
    const Mesh mesh = Sphere(n);
    const Topology topo = BuildTopology(mesh).value();
    FitOptions fo = DefaultFlowFitOptions();
    std::vector<double> fit_times, fit_cpu;
    for (int i = 0; i < 3; ++i) {
      const Stopwatch w;
      const std::clock_t c0 = std::clock();
      (void)FitSurface(mesh, topo, fo, nullptr, {}, RunContext(nullptr, threads)).value();
      fit_times.push_back(w.Millis());
      fit_cpu.push_back(1e3 * static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC);
    }
    const double fit4 = Median(fit_times), fit4_cpu = Median(fit_cpu);
    for (FlowKind kind : {FlowKind::kMeanCurvature, FlowKind::kSurfaceDiffusion}) {
      if (!only.empty() && only != FlowKindName(kind)) continue;
      for (FlowScheme scheme : {FlowScheme::kSemiImplicit, FlowScheme::kBdf2}) {
        if (!only_scheme.empty() && only_scheme != FlowSchemeName(scheme)) continue;
        FlowOptions o;
        o.kind = kind;
        o.scheme = scheme;
        o.dt = kind == FlowKind::kMeanCurvature ? 1e-3 : 1e-6;
        // "bicgstab-ilut" selects BiCGSTAB with the ILUT preconditioner; "auto-jacobi" and
        // "auto-amg" the flows' default solver (MCF's system, SD's reduced one) with Jacobi
        // or AMG from the start instead of the adaptive choice.
        const bool ilut = solver == "bicgstab-ilut", jacobi = solver == "auto-jacobi", amg = solver == "auto-amg";
        o.solver.kind = ParseSolverKind(ilut ? "bicgstab" : jacobi || amg ? "auto" : solver).value();
        if (ilut) o.solver.preconditioner = Preconditioner::kIlut;
        if (jacobi) o.solver.preconditioner = Preconditioner::kDiagonal;
        if (amg) o.solver.preconditioner = Preconditioner::kAmg;
        if (const char* f = std::getenv("GF_ILUT_FILL")) o.solver.ilut_fill = std::atoi(f);
        if (std::getenv("GF_AMG_PLAIN")) o.solver.amg.smooth_prolongator = false;
        if (const char* v = std::getenv("GF_AMG_THETA")) o.solver.amg.strength = std::atof(v);
        if (const char* d = std::getenv("GF_ILUT_DROP")) o.solver.ilut_drop = std::atof(d);
        if (const char* v = std::getenv("GF_TOLERANCE")) o.solver.tolerance = std::atof(v);
        if (const char* v = std::getenv("GF_JACOBI_LIMIT")) o.solver.jacobi_limit = std::atoi(v);
        const RunContext ctx = RunContext().WithThreads(threads);
        auto stepper = FlowStepper::Create(mesh, o, ctx);
        if (!stepper.ok()) {
          std::printf("error: %s\n", stepper.status().ToString().c_str());
          return;
        }
        std::vector<double> f, a, s, tot, cpu;
        int iters = 0;
        double first = 0;  // step 1: symbolic analyses, the SD preconditioner's factorization
        // GF_STEPS (default 4): steps taken; the medians are over the last three.
        const int steps = std::max(4, std::getenv("GF_STEPS") ? std::atoi(std::getenv("GF_STEPS")) : 4);
        for (int i = 0; i < steps; ++i) {
          const Stopwatch w;
          const std::clock_t c0 = std::clock();
          auto st = (*stepper)->Step(ctx);
          const double cpu_ms = 1e3 * static_cast<double>(std::clock() - c0) / CLOCKS_PER_SEC;
          if (!st.ok()) {
            std::printf("error: %s\n", st.status().ToString().c_str());
            return;
          }
          if (i == 0) first = w.Millis();
          if (i < steps - 3) continue;
          f.push_back(st->fit_ms), a.push_back(st->assemble_ms), s.push_back(st->solve_ms), tot.push_back(w.Millis());
          cpu.push_back(cpu_ms);
          iters = st->solver_iterations;
        }
        std::printf("  %-4s  %-13s %8d %8.1f %6.1f %8.1f %8.1f %7.1f %5d  %6.2f  %7.1f  %8.1f  %.2f\n",
                    kind == FlowKind::kMeanCurvature ? "mcf" : "sd", FlowSchemeName(scheme), mesh.NumVertices(), fit4,
                    Median(f), Median(a), Median(s), Median(tot), iters, Median(tot) / fit4, first, Median(cpu),
                    Median(cpu) / fit4_cpu);
        std::fflush(stdout);
      }
    }
  }
}


// AMG on the flows' systems, outside the stepper: MCF's I - dt K and surface diffusion's
// I + dt B K (matrix-free) with its factored preconditioners, against Jacobi. Environment:
// GF_AMG_THETA, GF_AMG_JACOBI (weight: Jacobi smoother), GF_AMG_PLAIN, GF_AMG_SWEEPS (AMG
// options); GF_NO_JACOBI; GF_COTAN (the cotan matrix M - dt/2 S instead of I - dt K);
// GF_EXACT (SD with exact inner solves); GF_DELAUNAY (Fibonacci hulls, not cubed spheres);
// GF_AMG_COARSE, GF_AMG_LEVELS (coarse_size, max_levels); GF_AMG_DEBUG (the rows where the
// residual of 30 stationary cycles concentrates).
void AmgProbe(const std::vector<int>& sizes, double dt_mcf, double dt_sd, const AmgOptions& ao) {
  for (int target : sizes) {
    const int n = static_cast<int>(std::lround(std::sqrt((target - 2) / 6.0)));
    const Mesh mesh = std::getenv("GF_DELAUNAY") ? GenerateDelaunaySphereMesh(target) : Sphere(n);
    const int nv = mesh.NumVertices();
    FlowOptions fo;
    auto stepper = FlowStepper::Create(mesh, fo).value();
    const SparseMatrix K = stepper->CurvatureJacobian().value();
    const Topology topo = BuildTopology(mesh).value();
    const auto fits = FitForOperators(mesh, topo, DefaultFlowFitOptions(), nullptr, RunContext()).value();
    const SparseMatrix B = LaplaceBeltramiMatrix(*fits).value();
    SparseMatrix I(nv, nv);
    I.setIdentity();
    Eigen::VectorXd rhs(nv);
    for (int i = 0; i < nv; ++i) rhs(i) = std::sin(3 * mesh.positions(i, 0)) + mesh.positions(i, 2);
    auto report = [&](const char* what, const LinearMap& A, const LinearMap& P, double setup_ms) {
      Eigen::VectorXd x;
      const Stopwatch w;
      auto it = SolveBicgstab(A, P, rhs, &x, 1e-12, 3000);
      std::printf("  %-28s n %8d  setup %8.1f ms  solve %9.1f ms  iterations %s\n", what, nv, setup_ms, w.Millis(),
                  it.ok() ? std::to_string(*it).c_str() : it.status().ToString().c_str());
      std::fflush(stdout);
    };
    auto jacobi_of = [](const SparseMatrix& A) {
      Eigen::VectorXd d = A.diagonal().cwiseInverse();
      return LinearMap([d](const Eigen::VectorXd& x, Eigen::VectorXd* y) { *y = d.cwiseProduct(x); });
    };
    {  // MCF
      SparseMatrix A = I - dt_mcf * K;
      if (std::getenv("GF_COTAN")) {
        const CotanLaplacian cot = BuildCotanLaplacian(mesh);
        Eigen::SparseMatrix<double> C = -0.5 * dt_mcf * cot.stiffness;
        for (int i = 0; i < nv; ++i) C.coeffRef(i, i) += cot.mass(i);
        A = C;
      }
      const LinearMap op = [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) { MultiplySerial(A, x, y); };
      if (!std::getenv("GF_NO_JACOBI")) report("mcf jacobi", op, jacobi_of(A), 0);
      Amg amg;
      const Stopwatch w;
      if (absl::Status s = amg.Build(A, ao); !s.ok()) std::printf("amg: %s\n", s.ToString().c_str());
      const double setup = w.Millis();
      std::printf("  levels %d:", amg.num_levels());
      for (int l = 0; l < amg.num_levels(); ++l) std::printf(" %d", amg.rows(l));
      std::printf("  complexity %.2f\n", amg.operator_complexity());
      {
        Eigen::VectorXd x = Eigen::VectorXd::Zero(nv), r = rhs, e, ax;
        // The mean factor over the first 12 cycles hides a slowly amplified local mode:
        // the asymptotic one is the mean over cycles 25..30.
        double r0 = r.norm(), factor = 0, r24 = 0, asymptotic = 0;
        for (int it = 0; it < 30; ++it) {
          amg.Apply(r, &e);
          x += e;
          MultiplySerial(A, x, &ax);
          r = rhs - ax;
          if (it == 11) factor = std::pow(r.norm() / r0, 1.0 / 12);
          if (it == 23) r24 = r.norm();
          if (it == 29) asymptotic = std::pow(r.norm() / r24, 1.0 / 6);
        }
        if (std::getenv("GF_AMG_DEBUG")) {
          std::vector<int> idx(nv);
          for (int i = 0; i < nv; ++i) idx[i] = i;
          std::partial_sort(idx.begin(), idx.begin() + 15, idx.end(), [&](int a, int b) { return std::abs(r(a)) > std::abs(r(b)); });
          std::printf("  |r| %.3g, max %.3g\n", r.norm(), r.cwiseAbs().maxCoeff());
          for (int q = 0; q < 15; ++q) {
            const int i = idx[q];
            double d = 0, off = 0;
            for (SparseMatrix::InnerIterator it(A, i); it; ++it) {
              if (it.col() == i) {
                d = it.value();
              } else {
                off += std::abs(it.value());
              }
            }
            std::printf("   row %d r %.3g a_ii %.4g sum |a_ij| %.4g at (%.4f, %.4f, %.4f)\n", i, r(i), d, off,
                        mesh.positions(i, 0), mesh.positions(i, 1), mesh.positions(i, 2));
          }
        }
        const std::clock_t c0 = std::clock();
        for (int it = 0; it < 10; ++it) amg.Apply(rhs, &e);
        const std::clock_t c1 = std::clock();
        for (int it = 0; it < 10; ++it) MultiplySerial(A, rhs, &e);
        const std::clock_t c2 = std::clock();
        std::printf("  stationary V-cycle factor %.3f (12 cycles), %.3f (cycles 25-30); V-cycle %.2f ms, product %.2f ms (CPU)\n", factor, asymptotic,
                    100.0 * (c1 - c0) / CLOCKS_PER_SEC, 100.0 * (c2 - c1) / CLOCKS_PER_SEC);
      }
      report("mcf amg", op, [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) { amg.Apply(x, y); }, setup);
    }
    if (dt_sd > 0) {  // SD: (I + a B K), preconditioned by (I - c B)(I - 2 c K~), c = sqrt(a/2)
      Eigen::VectorXd tmp;
      const LinearMap op = [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
        MultiplySerial(K, x, &tmp);
        MultiplySerial(B, tmp, y);
        *y = x + dt_sd * *y;
      };
      const double c = std::sqrt(dt_sd / 2);
      SparseMatrix Kt = K;
      const Eigen::VectorXd row_sums = K * Eigen::VectorXd::Ones(nv);
      for (int i = 0; i < nv; ++i) Kt.coeffRef(i, i) -= row_sums(i);
      const SparseMatrix PB = I - c * B, PK = I - 2 * c * Kt, PB2 = I - c * B;
      Amg ab, ak;
      const Stopwatch w;
      (void)ab.Build(PB, ao);
      (void)ak.Build(PK, ao);
      const double setup = w.Millis();
      Eigen::VectorXd half;
      report("sd amg (I-cB)(I-2cK~)", op, [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
        ab.Apply(x, &half);
        ak.Apply(half, y);
      }, setup);
      report("sd amg (I-cB)^2", op, [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
        ab.Apply(x, &half);
        ab.Apply(half, y);
      }, setup / 2);
      if (std::getenv("GF_EXACT")) {
        auto inner = [&](const SparseMatrix& M, const Amg& amg, const Eigen::VectorXd& b, Eigen::VectorXd* x) {
          x->resize(0);
          (void)SolveBicgstab([&](const Eigen::VectorXd& u, Eigen::VectorXd* v) { MultiplySerial(M, u, v); },
                              [&](const Eigen::VectorXd& u, Eigen::VectorXd* v) { amg.Apply(u, v); }, b, x, 1e-11, 500);
        };
        report("sd exact (I-cB)(I-2cK~)", op, [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
          inner(PB, ab, x, &half);
          inner(PK, ak, half, y);
        }, setup);
        report("sd exact (I-cB)^2", op, [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) {
          inner(PB, ab, x, &half);
          inner(PB, ab, half, y);
        }, setup);
      }
      Eigen::VectorXd d(nv);
      const SparseMatrix Ktr = K.transpose();
      for (int i = 0; i < nv; ++i) d(i) = 1 / (1 + dt_sd * B.row(i).dot(Ktr.row(i)));
      report("sd jacobi", op, [&](const Eigen::VectorXd& x, Eigen::VectorXd* y) { *y = d.cwiseProduct(x); }, 0);
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
  } else if (what == "amg") {
    std::vector<int> sizes;
    std::stringstream ss(argc > 2 ? argv[2] : "10000,40000");
    for (std::string item; std::getline(ss, item, ',');) sizes.push_back(std::atoi(item.c_str()));
    AmgOptions ao;
    if (const char* v = std::getenv("GF_AMG_THETA")) ao.strength = std::atof(v);
    if (const char* v = std::getenv("GF_AMG_JACOBI")) ao.smoother = AmgSmoother::kJacobi, ao.jacobi_weight = std::atof(v);
    if (std::getenv("GF_AMG_PLAIN")) ao.smooth_prolongator = false;
    if (const char* v = std::getenv("GF_AMG_SWEEPS")) ao.sweeps = std::atoi(v);
    if (const char* v = std::getenv("GF_AMG_COARSE")) ao.coarse_size = std::atoi(v);
    if (const char* v = std::getenv("GF_AMG_LEVELS")) ao.max_levels = std::atoi(v);
    AmgProbe(sizes, argc > 3 ? std::atof(argv[3]) : 1e-3, argc > 4 ? std::atof(argv[4]) : 1e-6, ao);
  } else {
    std::fprintf(stderr, "usage: flow_study table [cubed|delaunay|jittered] | steps [sizes] [threads] [solver] [mcf|surface_diffusion] [scheme]\n");
    return 2;
  }
}
