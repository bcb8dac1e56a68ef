// RPC time vs in-process compute at 1k, 10k and 100k vertices, and an FSI-style loop
// (UpdatePositions + ComputeDifferentials per step), against an in-process server on
// a loopback port through geomfit::Client. Store: --store via GEOMFIT_BENCH_STORE
// (memory | sqlite; default memory). Numeric threads: GEOMFIT_BENCH_THREADS (0 = all).
// Rows per response chunk: GEOMFIT_BENCH_CHUNK_ROWS (server default otherwise).
// GEOMFIT_BENCH_TARGET: see Service. GEOMFIT_BENCH_PREFETCH=0 turns the in-process
// server's --prefetch off.
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <memory>

#include <benchmark/benchmark.h>
#include <spdlog/spdlog.h>

#include "clients/cpp/client/client.h"
#include "core/fitting/fit.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"
#include "server/server.h"

namespace geomfit {
namespace {

constexpr uint32_t kQuantities = kNormals | kMeanCurvature | kGaussianCurvature | kPrincipalCurvatures;

int Threads() {
  const char* t = std::getenv("GEOMFIT_BENCH_THREADS");
  return t ? std::atoi(t) : 0;
}

/// Torus with about `vertices` vertices (3 n^2).
const Mesh& TorusWith(int vertices) {
  static std::map<int, Mesh> meshes;
  auto it = meshes.find(vertices);
  if (it == meshes.end()) {
    GeneratorOptions o;
    o.n = std::max(4, static_cast<int>(std::lround(std::sqrt(vertices / 3.0))));
    it = meshes.emplace(vertices, GenerateTorusMesh(o)).first;
  }
  return it->second;
}

/// One server + client for the whole run. GEOMFIT_BENCH_TARGET=HOST:PORT uses a running
/// geomfit-server instead of an in-process one (to compare with the Python client
/// against the same server process).
struct Service {
  Service() {
    spdlog::set_level(spdlog::level::warn);
    ClientOptions c;
    if (const char* target = std::getenv("GEOMFIT_BENCH_TARGET")) {
      c.target = target;
      client = Client::Connect(c);
      return;
    }
    server::ServerOptions o;
    o.host = "127.0.0.1";
    o.port = 0;
    const char* store = std::getenv("GEOMFIT_BENCH_STORE");
    o.store = store ? store : "memory";
    data_dir = std::filesystem::temp_directory_path() / ("geomfit_bench_" + std::to_string(getpid()));
    o.data_dir = data_dir.string();
    o.threads = Threads();
    if (const char* rows = std::getenv("GEOMFIT_BENCH_CHUNK_ROWS")) o.chunk_rows = std::atoll(rows);
    if (const char* prefetch = std::getenv("GEOMFIT_BENCH_PREFETCH")) o.prefetch = std::atoi(prefetch);
    o.cache_bytes = int64_t{4} << 30;
    server = std::move(server::Server::Start(o)).value();
    c.target = "127.0.0.1:" + std::to_string(server->port());
    client = Client::Connect(c);
  }
  ~Service() {
    if (!server) return;
    server->Shutdown(1);
    std::filesystem::remove_all(data_dir);
  }
  std::filesystem::path data_dir;
  std::unique_ptr<server::Server> server;
  std::unique_ptr<Client> client;
};

Service& TheService() {
  static auto* s = new Service();
  return *s;
}

/// The median of per-call milliseconds (robust to this VM's multi-millisecond stalls,
/// which the mean real_time takes in): reported as `p50_ms` counters.
double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

FitOptions Options() { return FitOptions(); }

void BM_InProcessEvaluateCachedFits(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  const Topology topo = ValidateMesh(mesh).value();
  const auto fits = FitSurface(mesh, topo, Options(), nullptr, {}, RunContext(nullptr, Threads())).value();
  for (auto _ : state) benchmark::DoNotOptimize(ComputeDifferentials(*fits, kQuantities, Threads()));
  state.counters["vertices"] = mesh.NumVertices();
}

void BM_RpcCurvatureCachedFits(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  Client& client = *TheService().client;
  const std::string id = client.Upload(mesh, "bench").value().mesh_id;
  (void)client.ComputeDifferentials(id, Options(), kQuantities).value();  // fill the cache
  std::vector<double> ms;
  for (auto _ : state) {
    const Stopwatch watch;
    auto d = client.ComputeDifferentials(id, Options(), kQuantities);
    ms.push_back(watch.Millis());
    if (!d.ok() || !d->summary.fit_cache_hit) state.SkipWithError("expected a cached fit");
    benchmark::DoNotOptimize(d);
  }
  state.counters["vertices"] = mesh.NumVertices();
  state.counters["p50_ms"] = Median(std::move(ms));
}

void BM_InProcessFitAndEvaluate(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  const Topology topo = ValidateMesh(mesh).value();
  for (auto _ : state) {
    const auto fits = FitSurface(mesh, topo, Options(), nullptr, {}, RunContext(nullptr, Threads())).value();
    benchmark::DoNotOptimize(ComputeDifferentials(*fits, kQuantities, Threads()));
  }
  state.counters["vertices"] = mesh.NumVertices();
}

/// What the server computes per FSI step: the fit with cached neighbourhoods, then
/// the quantities (the "compute" an FSI step's overhead is measured against).
void BM_InProcessFsiCompute(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  const Topology topo = ValidateMesh(mesh).value();
  const FitOptions options = Options();
  auto nbhd = std::make_shared<const Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(options), Threads()));
  for (auto _ : state) {
    const auto fits = FitSurface(mesh, topo, options, nbhd, {}, RunContext(nullptr, Threads())).value();
    benchmark::DoNotOptimize(ComputeDifferentials(*fits, kQuantities, Threads()));
  }
  state.counters["vertices"] = mesh.NumVertices();
}

/// BM_InProcessFsiCompute on a new copy of the mesh every step, as the server sees a
/// new revision (positions and faces in memory the fit has not touched yet).
void BM_InProcessFsiComputeFreshCopy(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  const Topology topo = ValidateMesh(mesh).value();
  const FitOptions options = Options();
  auto nbhd = std::make_shared<const Neighborhoods>(BuildNeighborhoods(topo, mesh, RingSpecFor(options), Threads()));
  int step = 0;
  for (auto _ : state) {
    state.PauseTiming();
    auto moved = std::make_shared<Mesh>(mesh);
    moved->positions.col(0).array() += 1e-4 * (++step % 2);
    state.ResumeTiming();
    const auto fits = FitSurface(*moved, topo, options, nbhd, {}, RunContext(nullptr, Threads())).value();
    benchmark::DoNotOptimize(ComputeDifferentials(*fits, kQuantities, Threads()));
  }
  state.counters["vertices"] = mesh.NumVertices();
}

/// FSI step: new positions (a small rigid shift per step), then curvature. Besides the
/// step's time: `overhead_ms`, the step minus the compute it used on the server (its
/// own fit, or the prefetch's it joined: joined_compute_ms), per step, so that the
/// machine's drift between this and BM_InProcessFsiCompute does not enter it.
void BM_FsiStep(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  Client& client = *TheService().client;
  const std::string id = client.Upload(mesh, "fsi").value().mesh_id;
  Positions p = mesh.positions;
  int step = 0;
  std::vector<double> update_ms, step_ms, compute_ms, overhead_ms;
  int64_t prefetched = 0;
  for (auto _ : state) {
    p.col(0).array() += 1e-4 * (++step % 2 ? 1 : -1);
    const Stopwatch watch;
    auto info = client.UpdatePositions(id, p);
    update_ms.push_back(watch.Millis());
    auto d = client.ComputeDifferentials(id, Options(), kQuantities, info.ok() ? info->revision : 0);
    step_ms.push_back(watch.Millis());
    if (!info.ok() || !d.ok()) {
      state.SkipWithError("FSI step failed");
      break;
    }
    const FitSummary& s = d->summary;
    compute_ms.push_back(s.fit_ms + s.evaluate_ms + s.joined_compute_ms);
    overhead_ms.push_back(step_ms.back() - compute_ms.back());
    prefetched += s.joined_compute_ms > 0;
  }
  state.counters["vertices"] = mesh.NumVertices();
  // Steps whose fit the server had begun before the request came (--prefetch).
  state.counters["prefetched"] = static_cast<double>(prefetched) / std::max<int64_t>(1, state.iterations());
  auto mean = [](const std::vector<double>& v) {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? 0.0 : s / v.size();
  };
  state.counters["server_compute_ms"] = Median(compute_ms);
  state.counters["overhead_ms"] = mean(overhead_ms);
  state.counters["overhead_p50_ms"] = Median(overhead_ms);
  state.counters["update_p50_ms"] = Median(update_ms);
  state.counters["p50_ms"] = Median(step_ms);
}

/// The transport + store part of an FSI step alone.
void BM_FsiUpdatePositionsOnly(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  Client& client = *TheService().client;
  const std::string id = client.Upload(mesh, "fsi-update").value().mesh_id;
  Positions p = mesh.positions;
  int step = 0;
  std::vector<double> ms;
  for (auto _ : state) {
    p.col(0).array() += 1e-4 * (++step % 2 ? 1 : -1);
    const Stopwatch watch;
    if (!client.UpdatePositions(id, p).ok()) state.SkipWithError("update failed");
    ms.push_back(watch.Millis());
  }
  state.counters["vertices"] = mesh.NumVertices();
  state.counters["p50_ms"] = Median(std::move(ms));
}

/// The server side of UpdatePositions without a network: assemble the chunks the
/// client sends, then the handler (validate, store, cache). Memory store.
void BM_HandlerUpdatePositions(benchmark::State& state) {
  const Mesh& mesh = TorusWith(static_cast<int>(state.range(0)));
  auto store = server::NewMemoryStore();
  server::Cache cache(int64_t{1} << 30);
  server::RequestStats stats;
  server::Workspace ws(store.get(), &cache, server::WorkspaceOptions{.threads = Threads()});
  server::Handlers handlers(&ws, &stats, server::HandlerOptions());
  server::UploadAssembler upload(int64_t{1} << 30);
  for (const auto& r : wire::UploadChunks(mesh, v1::MeshHeader(), ClientOptions().chunk_rows)) (void)upload.Add(r);
  const std::string id = handlers.UploadMesh(upload).value().mesh_id();
  Positions p = mesh.positions;
  v1::UpdateHeader header;
  header.set_mesh_id(id);
  int step = 0;
  for (auto _ : state) {
    p.col(0).array() += 1e-4 * (++step % 2 ? 1 : -1);
    server::PositionsAssembler a(int64_t{1} << 30);
    for (const auto& r : wire::UpdateChunks(p, header, ClientOptions().chunk_rows)) (void)a.Add(r);
    if (!handlers.UpdatePositions(a).ok()) state.SkipWithError("update failed");
  }
  state.counters["vertices"] = mesh.NumVertices();
}

#define SIZES Arg(1000)->Arg(10000)->Arg(100000)->Unit(benchmark::kMillisecond)->UseRealTime()
BENCHMARK(BM_InProcessEvaluateCachedFits)->SIZES;
BENCHMARK(BM_RpcCurvatureCachedFits)->SIZES;
BENCHMARK(BM_InProcessFitAndEvaluate)->SIZES;
BENCHMARK(BM_InProcessFsiCompute)->Arg(1000)->Arg(10000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_InProcessFsiComputeFreshCopy)->Arg(1000)->Arg(10000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_FsiStep)->Arg(1000)->Arg(10000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_HandlerUpdatePositions)->Arg(1000)->Arg(10000)->Arg(100000)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_FsiUpdatePositionsOnly)->Arg(1000)->Arg(10000)->Arg(100000)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace geomfit

BENCHMARK_MAIN();
