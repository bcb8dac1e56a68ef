// The cold path of a run on a fresh mesh: reading the file, BuildTopology and
// BuildNeighborhoods, on the n = 168 torus (84,672 vertices, 169,344 triangles) as
// generated (neighbours have near indices) and with its vertices shuffled (an external
// mesher's order: neighbours anywhere in memory). One thread unless stated.
//
//   BM_Topology/shuffled:<0|1>              BuildTopology
//   BM_MeshChecks/shuffled:<0|1>            HasLocalNumbering(mesh) + ValidateGeometry
//   BM_Neighborhoods/shuffled:<0|1>/deg:<d>/threads:<t>  BuildNeighborhoods(RingSpecFor(degree d))
//   BM_RelabelledNormals/shuffled:<1|2>/spokes:<0|1>  (--mesh) vertex normals, relabelled
//   BM_Parse/shuffled:<0|1>/fmt:<f>         ParseMesh of bytes in memory; f = 0 OBJ, 1 OFF,
//                                           2 ascii PLY (%.17g coordinates, as FormatObj)
//   BM_ReadObj/shuffled:<0|1>               ReadMesh of the OBJ file (file read + parse)
//   BM_ReadFile                             ReadMesh of FILE (with --mesh=FILE)
//
// Counters: MB/s of file text (parse and read), verts. See bench/README.md.
//
// `--mesh=FILE` adds two variants to BM_Topology and BM_Neighborhoods: shuffled:2, read
// from FILE (e.g. the gmsh torus of bench/external_meshes.py), and shuffled:3, the same
// mesh renumbered in its Topology::locality_order; BM_Neighborhoods also gets shuffled:5,
// FILE relabelled by RelabelForLocality with its rows in source order (what the CLI
// fits on), and shuffled:6, the same relabelled mesh with its rows sorted by the new
// labels (plain BuildTopology); shuffled:7 and 8 are the same two for the generated
// torus, shuffled:4 the generated torus renumbered like shuffled:3, and shuffled:9 is
// shuffled:6 with every row sorted by angle around its vertex from one direction field
// (the stencils' points in another order); shuffled:10 and 11 are FILE and the generated
// torus relabelled with RowOrder::kRotational (what the CLI fits on since the sixth
// round; shuffled:5 and 7 use RowOrder::kSource), shuffled:12 FILE with kRotational's
// topology rows over face rows in their source rotation. BM_RelabelledTopology/
// shuffled:<1|2>/order:<0|1> times RelabelForLocality + BuildTopology of the shuffled
// torus or FILE, RowOrder::kSource or kRotational. `--stats` prints each
// variant's mean stencil size and ring per degree instead of timing.
//
// `cold_path_bench --dump=FILE` writes every output (topologies, neighbourhoods at
// degrees 1-6, parsed meshes; then, for 20,000 mutations of each reader fuzz seed file
// read as every format, the reader's status or mesh and BuildTopology's status) to
// FILE instead of timing: `cmp` of two builds' dumps
// shows a rewrite changed nothing. `--write=DIR` writes DIR/torus.obj and
// DIR/torus_shuffled.obj (for whole runs of `geomfit curvature --local`).
#include <unistd.h>

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>
#include <cstdio>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include <benchmark/benchmark.h>

#include "absl/strings/str_format.h"
#include "core/fitting/frames.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/surfaces/analytic.h"
#include "tests/mesh/make_mesh.h"
#include "tests/mesh/reader_fuzz.h"


namespace {

using namespace geomfit;

constexpr int kTorusN = 168;

std::string AsciiPly(const Mesh& m) {
  std::string out = absl::StrFormat(
      "ply\nformat ascii 1.0\nelement vertex %d\nproperty double x\nproperty double y\n"
      "property double z\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n",
      m.NumVertices(), m.NumFaces());
  for (int v = 0; v < m.NumVertices(); ++v)
    absl::StrAppendFormat(&out, "%.17g %.17g %.17g\n", m.positions(v, 0), m.positions(v, 1),
                          m.positions(v, 2));
  for (int f = 0; f < m.NumFaces(); ++f) {
    absl::StrAppend(&out, m.FaceSize(f));
    for (int c = 0; c < m.FaceSize(f); ++c) absl::StrAppend(&out, " ", m.faces(f, c));
    out += '\n';
  }
  return out;
}

struct Variant {
  Mesh mesh;
  Topology topo;
  std::string text[3];  // OBJ, OFF, ascii PLY
  std::string obj_path;
};

std::string g_mesh_path;  // --mesh

struct Fixture {
  Variant v[13];
  int count = 2;  // variants in --dump and --stats (v[5]-v[12], with --mesh, timed only)
  Fixture() {
    GeneratorOptions g;
    g.n = kTorusN;
    v[0].mesh = GenerateTorusMesh(g);
    v[1].mesh = testing_util::ShuffleVertices(v[0].mesh, 12345);
    for (int s = 0; s < 2; ++s) {
      Variant& x = v[s];
      x.topo = BuildTopology(x.mesh).value();
      x.text[0] = FormatMesh(x.mesh, MeshFormat::kObj).value();
      x.text[1] = FormatMesh(x.mesh, MeshFormat::kOff).value();
      x.text[2] = AsciiPly(x.mesh);
      x.obj_path = absl::StrFormat("/tmp/geomfit_cold_path_bench_%d_%d.obj", getpid(), s);
      if (!WriteMesh(x.mesh, x.obj_path).ok()) std::abort();
    }
    if (!g_mesh_path.empty()) {
      Variant& x = v[count++];
      x.mesh = ReadMesh(g_mesh_path).value();
      x.topo = BuildTopology(x.mesh).value();
      // shuffled:3, the same mesh renumbered in its locality order.
      Renumber(x, v[count++]);
      Renumber(v[0], v[count++]);
      // shuffled:5, FILE relabelled as `geomfit curvature --local` does (rows in source order).
      LocalityRelabelling r = RelabelForLocality(x.mesh, RowOrder::kSource).value();
      v[5].topo = BuildTopology(r).value();
      v[5].mesh = r.mesh;
      // shuffled:10, FILE relabelled as the CLI does since the sixth round (kRotational);
      // shuffled:12, fan-ordered rows over face rows in their source rotation.
      LocalityRelabelling rot = RelabelForLocality(x.mesh, RowOrder::kRotational).value();
      v[10].topo = BuildTopology(rot).value();
      v[10].mesh = std::move(rot.mesh);
      r.order = RowOrder::kRotational;
      v[12].topo = BuildTopology(r).value();
      v[12].mesh = std::move(r.mesh);
      // shuffled:6, the same relabelled mesh with plain BuildTopology (rows sorted by the
      // new labels): the same memory layout as shuffled:5, other row order.
      v[6].mesh = v[5].mesh;
      v[6].topo = BuildTopology(v[6].mesh).value();
      // shuffled:7 and 8, the same two for the generated torus.
      LocalityRelabelling r2 = RelabelForLocality(v[0].mesh, RowOrder::kSource).value();
      v[7].topo = BuildTopology(r2).value();
      v[7].mesh = std::move(r2.mesh);
      LocalityRelabelling rot2 = RelabelForLocality(v[0].mesh, RowOrder::kRotational).value();
      v[11].topo = BuildTopology(rot2).value();
      v[11].mesh = std::move(rot2.mesh);
      v[8].mesh = v[7].mesh;
      v[8].topo = BuildTopology(v[8].mesh).value();
      // shuffled:9, shuffled:6 with rows in the same geometric pattern at every vertex.
      v[9] = v[6];
      RotationalRows(v[9]);
    }
  }
  // Each vertex's neighbours and faces sorted by angle around it, from the direction of
  // (-y, x, 0) (around a torus's axis): the same geometric pattern at every vertex.
  static void RotationalRows(Variant& x) {
    const Mesh& m = x.mesh;
    Topology& t = x.topo;
    auto p = [&](int u) { return Eigen::Vector3d(m.positions(u, 0), m.positions(u, 1), m.positions(u, 2)); };
    for (int v = 0; v < t.num_vertices; ++v) {
      const Eigen::Vector3d c = p(v);
      Eigen::Vector3d n = Eigen::Vector3d::Zero();
      for (int j = 0; j < t.NumVertexFaces(v); ++j) {
        const int f = t.VertexFaces(v)[j];
        n += (p(m.faces(f, 1)) - p(m.faces(f, 0))).cross(p(m.faces(f, 2)) - p(m.faces(f, 0)));
      }
      n.normalize();
      Eigen::Vector3d e1(-c.y(), c.x(), 0.0);
      e1 = (e1 - e1.dot(n) * n).normalized();
      const Eigen::Vector3d e2 = n.cross(e1);
      auto angle = [&](const Eigen::Vector3d& q) { return std::atan2((q - c).dot(e2), (q - c).dot(e1)); };
      int32_t* nb = t.vv.data() + t.vv_offsets[v];
      std::sort(nb, nb + t.NumNeighbors(v), [&](int a, int b) { return angle(p(a)) < angle(p(b)); });
      int32_t* fs = t.vf_faces.data() + t.vf_offsets[v];
      auto centroid = [&](int f) {
        Eigen::Vector3d s = Eigen::Vector3d::Zero();
        for (int k = 0; k < m.FaceSize(f); ++k) s += p(m.faces(f, k));
        return Eigen::Vector3d(s / m.FaceSize(f));
      };
      std::sort(fs, fs + t.NumVertexFaces(v), [&](int a, int b) { return angle(centroid(a)) < angle(centroid(b)); });
    }
  }
  static void Renumber(const Variant& x, Variant& y) {
      const int nv = x.mesh.NumVertices();
      std::vector<int32_t> position(nv);
      for (int i = 0; i < nv; ++i) position[x.topo.locality_order[i]] = i;
      y.mesh.positions.resize(nv, 3);
      for (int u = 0; u < nv; ++u) y.mesh.positions.row(position[u]) = x.mesh.positions.row(u);
      y.mesh.faces = x.mesh.faces;
      for (int f = 0; f < x.mesh.NumFaces(); ++f)
        for (int c = 0; c < x.mesh.FaceSize(f); ++c) y.mesh.faces.Mutable()(f, c) = position[x.mesh.faces(f, c)];
      y.topo = BuildTopology(y.mesh).value();
  }
  ~Fixture() {
    for (int s = 0; s < 2; ++s) std::remove(v[s].obj_path.c_str());
  }
};

Fixture& F() {
  static Fixture f;
  return f;
}

void BM_Topology(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  for (auto _ : state) {
    Topology t = BuildTopology(x.mesh).value();
    benchmark::DoNotOptimize(t.vv.data());
    benchmark::ClobberMemory();
  }
  state.counters["verts"] = x.mesh.NumVertices();
}

// RelabelForLocality(mesh, order) + BuildTopology of it: the CLI's topology of a
// scattered numbering (order 0 kSource, 1 kRotational).
void BM_RelabelledTopology(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  const RowOrder order = state.range(1) ? RowOrder::kRotational : RowOrder::kSource;
  for (auto _ : state) {
    LocalityRelabelling r = RelabelForLocality(x.mesh, order).value();
    Topology t = BuildTopology(r).value();
    benchmark::DoNotOptimize(t.vv.data());
    benchmark::ClobberMemory();
  }
  state.counters["verts"] = x.mesh.NumVertices();
}

// ApproximateVertexNormals (area weights, one thread) on the CLI's relabelled mesh
// (kRotational): spokes:1 reads each corner's spokes from the fan-ordered neighbour rows
// (Topology::fan_rows, the CLI's path), spokes:0 walks the face rows (fan_rows cleared).
void BM_RelabelledNormals(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  const LocalityRelabelling r = RelabelForLocality(x.mesh, RowOrder::kRotational).value();
  Topology t = BuildTopology(r).value();
  t.fan_rows = state.range(1) != 0;
  for (auto _ : state) {
    Positions n = ApproximateVertexNormals(r.mesh, t, NormalWeighting::kArea, 1);
    benchmark::DoNotOptimize(n.data());
    benchmark::ClobberMemory();
  }
  state.counters["verts"] = x.mesh.NumVertices();
}

// The CLI's per-mesh checks before it relabels: HasLocalNumbering of the face rows and
// ValidateGeometry (finite coordinates, no zero-area face), one thread.
void BM_MeshChecks(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  for (auto _ : state) {
    benchmark::DoNotOptimize(HasLocalNumbering(x.mesh));
    benchmark::DoNotOptimize(ValidateGeometry(x.mesh, 1).ok());
  }
  state.counters["verts"] = x.mesh.NumVertices();
}

void BM_Neighborhoods(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  FitOptions o;
  o.degree = static_cast<int>(state.range(1));
  for (auto _ : state) {
    Neighborhoods nb = BuildNeighborhoods(x.topo, x.mesh, RingSpecFor(o), static_cast<int>(state.range(2)));
    benchmark::DoNotOptimize(nb.indices.data());
    benchmark::ClobberMemory();
  }
  state.counters["verts"] = x.mesh.NumVertices();
}

void BM_Parse(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  const int fmt = static_cast<int>(state.range(1));
  const MeshFormat format[] = {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly};
  const std::string& text = x.text[fmt];
  for (auto _ : state) {
    Mesh m = ParseMesh(text, format[fmt]).value();
    benchmark::DoNotOptimize(m.positions.data());
    benchmark::ClobberMemory();
  }
  state.counters["MB/s"] = benchmark::Counter(text.size() * 1e-6, benchmark::Counter::kIsIterationInvariantRate);
  state.counters["MB"] = text.size() * 1e-6;
}

void BM_ReadObj(benchmark::State& state) {
  const Variant& x = F().v[state.range(0)];
  for (auto _ : state) {
    Mesh m = ReadMesh(x.obj_path).value();
    benchmark::DoNotOptimize(m.positions.data());
    benchmark::ClobberMemory();
  }
  state.counters["MB/s"] =
      benchmark::Counter(x.text[0].size() * 1e-6, benchmark::Counter::kIsIterationInvariantRate);
}

/// ReadMesh of FILE (--mesh), e.g. the gmsh torus: an external mesher's text.
void BM_ReadFile(benchmark::State& state) {
  size_t bytes = 0;
  for (auto _ : state) {
    Mesh m = ReadMesh(g_mesh_path).value();
    benchmark::DoNotOptimize(m.positions.data());
    benchmark::ClobberMemory();
  }
  FILE* f = std::fopen(g_mesh_path.c_str(), "rb");
  if (f != nullptr && std::fseek(f, 0, SEEK_END) == 0) bytes = static_cast<size_t>(std::ftell(f));
  if (f != nullptr) std::fclose(f);
  state.counters["MB/s"] = benchmark::Counter(bytes * 1e-6, benchmark::Counter::kIsIterationInvariantRate);
}

BENCHMARK(BM_Topology)->ArgName("shuffled")->DenseRange(0, 1)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_MeshChecks)->ArgName("shuffled")->DenseRange(0, 1)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_Neighborhoods)
    ->ArgNames({"shuffled", "deg", "threads"})
    ->ArgsProduct({{0, 1}, {2, 4}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_Parse)
    ->ArgNames({"shuffled", "fmt"})
    ->ArgsProduct({{0, 1}, {0, 1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_ReadObj)->ArgName("shuffled")->DenseRange(0, 1)->Unit(benchmark::kMillisecond)->UseRealTime();

template <typename T>
void Put(FILE* out, const std::vector<T>& v) {
  const uint64_t n = v.size();
  std::fwrite(&n, sizeof(n), 1, out);
  std::fwrite(v.data(), sizeof(T), v.size(), out);
}

void PutMesh(FILE* out, const Mesh& m) {
  Put(out, std::vector<double>(m.positions.data(), m.positions.data() + m.positions.size()));
  Put(out, std::vector<int32_t>(m.faces.data(), m.faces.data() + m.faces.size()));
}

void Dump(const char* path) {
  FILE* out = std::fopen(path, "wb");
  if (!out) std::abort();
  for (int s = 0; s < F().count; ++s) {
    const Variant& x = F().v[s];
    const Topology& t = x.topo;
    Put(out, t.vf_offsets), Put(out, t.vf_faces), Put(out, t.vv_offsets), Put(out, t.vv);
    Put(out, t.is_boundary), Put(out, t.is_isolated);
    Put(out, std::vector<int>{t.num_boundary_edges, t.num_isolated, t.has_quads});
    for (int d = 1; d <= kMaxDegree; ++d) {
      FitOptions o;
      o.degree = d;
      for (int threads : {1, 2}) {
        const Neighborhoods nb = BuildNeighborhoods(t, x.mesh, RingSpecFor(o), threads);
        Put(out, nb.offsets), Put(out, nb.indices), Put(out, nb.rings);
      }
    }
    if (s >= 2) continue;  // --mesh: no texts
    const MeshFormat format[] = {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly};
    for (int fmt = 0; fmt < 3; ++fmt) PutMesh(out, ParseMesh(x.text[fmt], format[fmt]).value());
    PutMesh(out, ReadMesh(x.obj_path).value());
  }
  // Error messages: the reader fuzz corpus (tests/mesh/reader_fuzz.h).
  std::mt19937_64 rng(1);
  const auto put_status = [out](const absl::Status& st) {
    const std::string text = st.ToString();
    Put(out, std::vector<char>(text.begin(), text.end()));
  };
  for (int i = 0; i < 20000; ++i)
    for (const reader_fuzz::SeedFile& s : reader_fuzz::SeedFiles()) {
      const std::string bytes = reader_fuzz::Mutate(s.bytes, rng);
      for (MeshFormat f : {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly, MeshFormat::kStl}) {
        const absl::StatusOr<Mesh> m = ParseMesh(bytes, f);
        put_status(m.status());
        if (!m.ok()) continue;
        PutMesh(out, *m);
        put_status(BuildTopology(*m).status());
      }
    }
  std::fclose(out);
}

// Mean stencil size and ring per variant and degree (what BM_Neighborhoods grows).
void Stats() {
  for (int s = 0; s < F().count; ++s) {
    const Variant& x = F().v[s];
    const Topology& t = x.topo;
    std::vector<int32_t> position(t.num_vertices);
    for (int i = 0; i < t.num_vertices; ++i)  // a relabelling's topology: vertex order
      position[t.locality_order.empty() ? i : t.locality_order[i]] = i;
    double gap = 0, gap_order = 0;
    for (int v = 0; v < t.num_vertices; ++v)
      for (int j = 0; j < t.NumNeighbors(v); ++j) {
        gap += std::abs(v - t.Neighbors(v)[j]);
        gap_order += std::abs(position[v] - position[t.Neighbors(v)[j]]);
      }
    std::printf("variant %d: mean index gap over edges %.1f (in locality order %.1f)\n", s,
                gap / t.vv.size(), gap_order / t.vv.size());
    for (int d = 1; d <= kMaxDegree; ++d) {
      FitOptions o;
      o.degree = d;
      const Neighborhoods nb = BuildNeighborhoods(x.topo, x.mesh, RingSpecFor(o), 1);
      double rings = 0;
      for (float r : nb.rings) rings += r;
      const int nv = x.mesh.NumVertices();
      std::printf("variant %d (%d vertices) degree %d: mean points %.3f, mean ring %.3f\n", s, nv, d,
                  static_cast<double>(nb.indices.size()) / nv, rings / nv);
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  for (int i = 1; i < argc; ++i)
    if (std::strncmp(argv[i], "--mesh=", 7) == 0) g_mesh_path = argv[i] + 7;
  if (!g_mesh_path.empty()) {
    benchmark::RegisterBenchmark("BM_Topology", BM_Topology)
        ->ArgName("shuffled")
        ->DenseRange(2, 3)
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    benchmark::RegisterBenchmark("BM_ReadFile", BM_ReadFile)->Unit(benchmark::kMillisecond)->UseRealTime();
    benchmark::RegisterBenchmark("BM_RelabelledTopology", BM_RelabelledTopology)
        ->ArgNames({"shuffled", "order"})
        ->ArgsProduct({{1, 2}, {0, 1}})
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    benchmark::RegisterBenchmark("BM_RelabelledNormals", BM_RelabelledNormals)
        ->ArgNames({"shuffled", "spokes"})
        ->ArgsProduct({{1, 2}, {0, 1}})
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
    benchmark::RegisterBenchmark("BM_Neighborhoods", BM_Neighborhoods)
        ->ArgNames({"shuffled", "deg", "threads"})
        ->ArgsProduct({{2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12}, {2, 4, 6}, {1, 2}})
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
  }
  for (int i = 1; i < argc; ++i)
    if (std::strcmp(argv[i], "--stats") == 0) {
      Stats();
      return 0;
    } else if (std::strncmp(argv[i], "--dump=", 7) == 0) {
      Dump(argv[i] + 7);
      return 0;
    } else if (std::strncmp(argv[i], "--write=", 8) == 0) {
      const std::string dir = argv[i] + 8;
      const bool ok = WriteMesh(F().v[0].mesh, dir + "/torus.obj").ok() &&
                      WriteMesh(F().v[1].mesh, dir + "/torus_shuffled.obj").ok();
      return ok ? 0 : 1;
    }
  // Drop --mesh before Google Benchmark parses the rest.
  int kept = 1;
  for (int i = 1; i < argc; ++i)
    if (std::strncmp(argv[i], "--mesh=", 7) != 0) argv[kept++] = argv[i];
  argc = kept;
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  const Fixture& f = F();  // build meshes and files before any timing
  std::fprintf(stderr, "torus n=%d: %d vertices, %d triangles; OBJ %.1f MB\n", kTorusN,
               f.v[0].mesh.NumVertices(), f.v[0].mesh.NumFaces(), f.v[0].text[0].size() * 1e-6);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
