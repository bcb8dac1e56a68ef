// Throughput of per-vertex WLS fitting on the n = 168 torus (84,672 vertices, 169,344
// triangles; the dissertation's Table 3.3 uses an 85,208-vertex torus), against CGAL's
// Jet_fitting_3 (CGAL::Monge_via_jet_fitting) fed the very same stencils.
//
//   BM_Pipeline/<degree>/<threads>      BuildNeighborhoods + FitSurface + ComputeDifferentials(all)
//   BM_FitQuantities/<degree>/<threads> FitSurface + ComputeDifferentials(all), stencils precomputed
//   BM_FitQuantitiesScalar/<d>/<t>      the same with the scalar kernel (batched_kernel = false)
//   BM_Degree2Refined/<mode>/<t>        degree 2 as BM_FitQuantities with mode 0: plain, 1 / 3:
//                                       slope_refinement 1 / 2, 2: hermite_hessian (degree-3 pre-fit),
//                                       4: quadratic_hermite
//   BM_Neighborhoods/<degree>/<threads> BuildNeighborhoods alone (for the breakdown)
//   BM_VertexNormals/<threads>          ApproximateVertexNormals alone
//   BM_Topology                         BuildTopology alone (not part of the pipeline above)
//   BM_CgalJet/<degree>/<threads>       CGAL Monge_via_jet_fitting(d_fitting = degree, d_monge = 2)
//                                       on our stencils; threads = 2 runs an OpenMP loop over
//                                       vertices with one fitter per thread (CGAL itself is serial)
//
// Rates: items_per_second and the "tri/s" counter are triangles per second of wall time.
// `--mesh=FILE` runs every line on that mesh instead (e.g. a gmsh torus); `--isa=avx2` (or
// avx512, portable) picks the batched kernel's instruction set; `--qr` keeps the batched
// kernel off the normal equations; `--compare` prints their differences to the QR's
// (CompareNormalEquations) instead of timing. See bench/README.md.
#include <cstdio>
#include <algorithm>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>
#include <omp.h>

#include <CGAL/Monge_via_jet_fitting.h>
#include <CGAL/Simple_cartesian.h>

#include "core/fitting/fit.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/fitting/wls_batch.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"

namespace {

using namespace geomfit;

using Kernel = CGAL::Simple_cartesian<double>;
using CgalPoint = Kernel::Point_3;
using MongeVia = CGAL::Monge_via_jet_fitting<Kernel>;

constexpr int kTorusN = 168;
bool g_compare = false;  // --compare: normal equations vs QR (CompareNormalEquations)
std::string g_mesh_path;  // --mesh=FILE: that mesh instead of the torus (e.g. a gmsh one)

struct Fixture {
  Mesh mesh;
  Topology topo;
  Positions normals;  // approximate vertex normals (CGAL orientation only)
  std::shared_ptr<const Neighborhoods> nb[kMaxDegree + 1];
  double avg_stencil[kMaxDegree + 1] = {};

  Fixture() {
    if (!g_mesh_path.empty()) {
      mesh = ReadMesh(g_mesh_path).value();
    } else {
      GeneratorOptions g;
      g.n = kTorusN;
      mesh = GenerateTorusMesh(g);
    }
    topo = BuildTopology(mesh).value();
    normals = ApproximateVertexNormals(mesh, topo, NormalWeighting::kArea, 0);
    for (int d = 1; d <= kMaxDegree; ++d) {
      FitOptions o;
      o.degree = d;
      nb[d] = std::make_shared<Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(o), 0));
      avg_stencil[d] = double(nb[d]->indices.size()) / mesh.NumVertices();
    }
  }
  int NumTriangles() const { return mesh.NumFaces(); }
};

const Fixture& F() {
  static const Fixture* f = new Fixture();
  return *f;
}

void SetRates(benchmark::State& state, int degree) {
  const Fixture& f = F();
  state.SetItemsProcessed(state.iterations() * f.NumTriangles());
  state.counters["tri/s"] = benchmark::Counter(f.NumTriangles(), benchmark::Counter::kIsIterationInvariantRate);
  state.counters["verts"] = f.mesh.NumVertices();
  state.counters["stencil"] = f.avg_stencil[degree];
}

FitOptions Options(int degree) {
  FitOptions o;
  o.degree = degree;
  return o;
}

void BM_Pipeline(benchmark::State& state) {
  const Fixture& f = F();
  const FitOptions o = Options(static_cast<int>(state.range(0)));
  const RunContext ctx(nullptr, static_cast<int>(state.range(1)));
  for (auto _ : state) {
    auto nb = std::make_shared<Neighborhoods>(BuildNeighborhoods(f.topo, f.mesh, RingSpecFor(o), ctx.threads()));
    auto fits = FitSurface(f.mesh, f.topo, o, std::move(nb), {}, ctx).value();
    Differentials d = ComputeDifferentials(*fits, kAllQuantities, ctx.threads());
    benchmark::DoNotOptimize(d.mean.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, o.degree);
}

void BM_FitQuantities(benchmark::State& state) {
  const Fixture& f = F();
  const FitOptions o = Options(static_cast<int>(state.range(0)));
  const RunContext ctx(nullptr, static_cast<int>(state.range(1)));
  for (auto _ : state) {
    auto fits = FitSurface(f.mesh, f.topo, o, f.nb[o.degree], {}, ctx).value();
    Differentials d = ComputeDifferentials(*fits, kAllQuantities, ctx.threads());
    benchmark::DoNotOptimize(d.mean.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, o.degree);
}

// The same with the scalar SolveWls for every vertex (FitRequest::batched_kernel = false).
void BM_FitQuantitiesScalar(benchmark::State& state) {
  const Fixture& f = F();
  const FitOptions o = Options(static_cast<int>(state.range(0)));
  const RunContext ctx(nullptr, static_cast<int>(state.range(1)));
  FitRequest req;
  req.batched_kernel = false;
  for (auto _ : state) {
    auto fits = FitSurface(f.mesh, f.topo, o, f.nb[o.degree], req, ctx).value();
    Differentials d = ComputeDifferentials(*fits, kAllQuantities, ctx.threads());
    benchmark::DoNotOptimize(d.mean.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, o.degree);
}

// Degree 2 with its refinements (FitOptions::slope_refinement, hermite_hessian), on the
// degree-2 stencils (the pre-fit of hermite_hessian builds its own).
void BM_Degree2Refined(benchmark::State& state) {
  const Fixture& f = F();
  FitOptions o = Options(2);
  o.slope_refinement = state.range(0) == 1 ? 1 : state.range(0) == 3 ? 2 : 0;
  o.hermite_hessian = state.range(0) == 2;
  o.quadratic_hermite = state.range(0) == 4;
  const RunContext ctx(nullptr, static_cast<int>(state.range(1)));
  for (auto _ : state) {
    auto fits = FitSurface(f.mesh, f.topo, o, f.nb[2], {}, ctx).value();
    Differentials d = ComputeDifferentials(*fits, kAllQuantities, ctx.threads());
    benchmark::DoNotOptimize(d.mean.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, 2);
}

void BM_Neighborhoods(benchmark::State& state) {
  const Fixture& f = F();
  const FitOptions o = Options(static_cast<int>(state.range(0)));
  const RunContext ctx(nullptr, static_cast<int>(state.range(1)));
  for (auto _ : state) {
    Neighborhoods nb = BuildNeighborhoods(f.topo, f.mesh, RingSpecFor(o), ctx.threads());
    benchmark::DoNotOptimize(nb.indices.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, o.degree);
}

// ApproximateVertexNormals alone (frames and safeguard weights of every fit), 1 or 2 threads.
void BM_VertexNormals(benchmark::State& state) {
  const Fixture& f = F();
  for (auto _ : state) {
    Positions n = ApproximateVertexNormals(f.mesh, f.topo, NormalWeighting::kArea, static_cast<int>(state.range(0)));
    benchmark::DoNotOptimize(n.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, 2);
}

void BM_Topology(benchmark::State& state) {
  const Fixture& f = F();
  for (auto _ : state) {
    Topology t = BuildTopology(f.mesh).value();
    benchmark::DoNotOptimize(t.vv.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, 2);
}

// CGAL on our stencils: gather the stencil's points (vertex first, as CGAL's Monge origin
// is the fit above the first point), fit, orient the Monge normal like our vertex normal,
// store normal and principal curvatures.
void BM_CgalJet(benchmark::State& state) {
  const Fixture& f = F();
  const int degree = static_cast<int>(state.range(0));
  const int threads = static_cast<int>(state.range(1));
  const Neighborhoods& nb = *f.nb[degree];
  const int nv = f.mesh.NumVertices();
  std::vector<double> k1(nv), k2(nv);
  Positions normal(nv, 3);
  for (auto _ : state) {
#pragma omp parallel num_threads(threads)
    {
      MongeVia fitter;
      std::vector<CgalPoint> pts;
      pts.reserve(kMaxStencil);
#pragma omp for schedule(dynamic, 256)
      for (int v = 0; v < nv; ++v) {
        pts.clear();
        const int32_t* idx = nb.Points(v);
        for (int i = 0; i < nb.Size(v); ++i) {
          const auto p = f.mesh.positions.row(idx[i]);
          pts.emplace_back(p(0), p(1), p(2));
        }
        MongeVia::Monge_form m = fitter(pts.begin(), pts.end(), degree, 2);
        m.comply_wrt_given_normal(Kernel::Vector_3(f.normals(v, 0), f.normals(v, 1), f.normals(v, 2)));
        const auto n = m.normal_direction();
        normal.row(v) << n.x(), n.y(), n.z();
        k1[v] = m.principal_curvatures(0);
        k2[v] = m.principal_curvatures(1);
      }
    }
    benchmark::DoNotOptimize(k1.data());
    benchmark::DoNotOptimize(k2.data());
    benchmark::DoNotOptimize(normal.data());
    benchmark::ClobberMemory();
  }
  SetRates(state, degree);
}

// --compare: the batched kernel with and without the normal equations (QR only), degrees
// 1-6, one thread: largest difference of normals, H, K, k1, k2 relative to the larger of
// the value and the column's largest magnitude (normals: 1), and how many vertices the
// normal equations solved (those whose condition differs from the QR run's by any bit
// count as such; the rest are bit-equal).
void CompareNormalEquations() {
  const Fixture& f = F();
  for (int degree = 1; degree <= kMaxDegree; ++degree) {
    const FitOptions o = Options(degree);
    const RunContext ctx(nullptr, 1);
    SetWlsBatchNormalEquations(false);
    const auto qr = FitSurface(f.mesh, f.topo, o, f.nb[degree], {}, ctx).value();
    SetWlsBatchNormalEquations(true);
    const auto ne = FitSurface(f.mesh, f.topo, o, f.nb[degree], {}, ctx).value();
    const Differentials a = ComputeDifferentials(*qr, kAllQuantities, 1);
    const Differentials b = ComputeDifferentials(*ne, kAllQuantities, 1);
    auto worst = [](const Eigen::VectorXd& x, const Eigen::VectorXd& y, double scale) {
      double e = 0;
      for (int v = 0; v < x.size(); ++v) e = std::max(e, std::abs(x(v) - y(v)) / std::max(std::abs(x(v)), scale));
      return e;
    };
    const double ks = std::max(a.k1.cwiseAbs().maxCoeff(), a.k2.cwiseAbs().maxCoeff());
    double en = 0, cond_max = 0;
    int differ = 0;
    for (int v = 0; v < f.mesh.NumVertices(); ++v) {
      for (int k = 0; k < 3; ++k) en = std::max(en, std::abs(a.normals(v, k) - b.normals(v, k)));
      const bool d = qr->coefficients(v)[qr->num_coefficients() - 1] != ne->coefficients(v)[ne->num_coefficients() - 1];
      differ += d;
      if (d) cond_max = std::max(cond_max, double(qr->diagnostics(v).condition));
    }
    std::printf("degree %d: normal equations on %d of %d vertices (condition up to %.3g); largest relative "
                "difference normals %.2e H %.2e K %.2e k1 %.2e k2 %.2e\n",
                degree, differ, f.mesh.NumVertices(), cond_max, en, worst(a.mean, b.mean, ks),
                worst(a.gaussian, b.gaussian, ks * ks), worst(a.k1, b.k1, ks), worst(a.k2, b.k2, ks));
  }
}

// With --benchmark_repetitions: the fastest repetition, the figure least disturbed by
// other processes on a shared machine (two threads need both cores free).
double Min(const std::vector<double>& v) { return *std::min_element(v.begin(), v.end()); }

void Args(benchmark::internal::Benchmark* b) {
  for (int threads : {1, 2})
    for (int d : {2, 4, 6}) b->Args({d, threads});
  b->ArgNames({"deg", "threads"})->Unit(benchmark::kMillisecond)->UseRealTime()->ComputeStatistics("min", Min);
}

BENCHMARK(BM_Pipeline)->Apply(Args);
BENCHMARK(BM_FitQuantities)->Apply(Args);
BENCHMARK(BM_FitQuantitiesScalar)->Apply(Args);
BENCHMARK(BM_Degree2Refined)
    ->ArgsProduct({{0, 1, 3, 2, 4}, {1, 2}})
    ->ArgNames({"mode", "threads"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_Neighborhoods)->Apply(Args);
BENCHMARK(BM_VertexNormals)
    ->Arg(1)
    ->Arg(2)
    ->ArgName("threads")
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->ComputeStatistics("min", Min);
BENCHMARK(BM_Topology)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_CgalJet)->Apply(Args);

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc;) {
    if (std::strncmp(argv[i], "--mesh=", 7) == 0) {
      g_mesh_path = argv[i] + 7;
    } else if (std::strncmp(argv[i], "--isa=", 6) == 0) {
      if (!SetWlsBatchIsa(argv[i] + 6)) {
        std::fprintf(stderr, "--isa=%s: not supported here\n", argv[i] + 6);
        return 1;
      }
    } else if (std::strcmp(argv[i], "--qr") == 0) {
      SetWlsBatchNormalEquations(false);
    } else if (std::strcmp(argv[i], "--compare") == 0) {
      g_compare = true;
    } else {
      ++i;
      continue;
    }
    for (int j = i; j + 1 < argc; ++j) argv[j] = argv[j + 1];
    --argc;
  }
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  const Fixture& f = F();  // build the torus and stencils before any timing
  std::fprintf(stderr, "batched kernel: %s\n", WlsBatchIsa());
  std::fprintf(stderr, "%s: %d vertices, %d triangles; mean stencil size d2 %.1f d4 %.1f d6 %.1f\n",
               g_mesh_path.empty() ? "torus n=168" : g_mesh_path.c_str(), f.mesh.NumVertices(), f.NumTriangles(), f.avg_stencil[2], f.avg_stencil[4],
               f.avg_stencil[6]);
  if (g_compare) {
    CompareNormalEquations();
    return 0;
  }
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
