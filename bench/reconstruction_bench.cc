// Chapter-4 costs on a ~170k-triangle torus (n = 168: 84,672 vertices, 169,344
// triangles): points per second for linear interpolation, WALF and CMF with cached
// vertex fits (1 and 6 points per face; compare Tables 4.2-4.3), and integration time.
#include <benchmark/benchmark.h>

#include "core/integration/integrate.h"
#include "core/reconstruction/surface.h"
#include "core/surfaces/analytic.h"

namespace geomfit {
namespace {

struct Torus {
  Mesh mesh;
  Topology topo;
  std::shared_ptr<const SurfaceFits> fits[7];
};

const Torus& GetTorus(int degree) {
  static Torus t = [] {
    Torus x;
    GeneratorOptions g;
    g.n = 168;
    x.mesh = GenerateTorusMesh(g);
    x.topo = BuildTopology(x.mesh).value();
    return x;
  }();
  if (!t.fits[degree]) {  // cached fits, as the server keeps them
    FitOptions o;
    o.degree = degree;
    t.fits[degree] = FitSurface(t.mesh, t.topo, o, nullptr, FitRequest{.stencils = true}, RunContext(nullptr, 1)).value();
  }
  return t;
}

void Evaluate(benchmark::State& state, ReconstructionMethod method) {
  const int per_face = static_cast<int>(state.range(0)), degree = static_cast<int>(state.range(1));
  const Torus& t = GetTorus(degree);
  auto surface = MakeSurface(method, t.mesh, t.fits[degree]);
  const std::vector<FacePoint> points = RandomFacePoints(t.mesh, per_face, 1);
  std::vector<SurfacePoint> out;
  for (auto _ : state) {
    benchmark::DoNotOptimize(EvaluatePoints(*surface, points, &out, RunContext(nullptr, 1)));
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(points.size()));
  state.counters["points/s"] = benchmark::Counter(static_cast<double>(points.size()), benchmark::Counter::kIsIterationInvariantRate);
}

void BM_Linear(benchmark::State& s) { Evaluate(s, ReconstructionMethod::kLinear); }
void BM_Walf(benchmark::State& s) { Evaluate(s, ReconstructionMethod::kWalf); }
void BM_Cmf(benchmark::State& s) { Evaluate(s, ReconstructionMethod::kCmf); }

BENCHMARK(BM_Linear)->ArgsProduct({{1, 6}, {2}})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Walf)->ArgsProduct({{1, 6}, {2, 4}})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_Cmf)->ArgsProduct({{1, 6}, {2, 4}})->Unit(benchmark::kMillisecond)->Iterations(1);

// Area, volume, one scalar field and one flux over WALF, quadrature degree d + 2.
void BM_Integrate(benchmark::State& state) {
  const int degree = static_cast<int>(state.range(0));
  const Torus& t = GetTorus(degree);
  WalfSurface walf(t.mesh, t.fits[degree]);
  IntegrationInput in;
  in.scalars = t.mesh.positions.col(0).array().sin().matrix();
  in.vectors = t.mesh.positions;
  for (auto _ : state) benchmark::DoNotOptimize(Integrate(walf, in, RunContext(nullptr, 1)));
  state.counters["triangles/s"] = benchmark::Counter(t.mesh.NumFaces(), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Integrate)->Arg(2)->Arg(4)->Arg(6)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace geomfit

BENCHMARK_MAIN();
