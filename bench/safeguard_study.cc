// The oscillation safeguard (§4.1.3) on meshes from outside the project (issue 16 item 2):
// for every mesh, method and degree, WALF/CMF max distance to the exact surface and max
// normal error at random face points, with the safeguard off and on, the number of
// vertex fits whose degree it lowered (Table 4.1-style), and WALF's area error.
// bench/external_meshes.py --families a,b1 makes the gmsh / marching-cubes tori;
// bench/safeguard_external.py runs this program on them and writes the tables.
//
// Usage: safeguard_study [--surface torus] [--methods walf,cmf] [--degrees 2,3,4,5,6]
//                        [--per-face 3] [--threads 0] LABEL=MESH ...
// Prints one tab-separated row per mesh, method and degree.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "bench/bench_args.h"
#include "core/fitting/fit.h"
#include "core/integration/integrate.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/reconstruction/surface.h"
#include "core/surfaces/analytic.h"
#include "core/util/run_context.h"

using namespace geomfit;

namespace {

struct Run {
  double distance = 0, normal = 0, area_error = -1;
  int downgraded = 0;
};

Run Measure(const Mesh& mesh, const Topology& topo, const AnalyticSurface& exact, double exact_area,
            ReconstructionMethod method, int degree, bool safeguard, int per_face, int threads) {
  FitOptions o;
  o.degree = degree;
  o.oscillation_safeguard = safeguard;
  const RunContext ctx(nullptr, threads);
  auto fits = FitSurface(mesh, topo, o, nullptr, FitRequest{.stencils = method == ReconstructionMethod::kWalf}, ctx);
  if (!fits.ok()) {
    std::fprintf(stderr, "fit failed: %s\n", std::string(fits.status().message()).c_str());
    std::exit(1);
  }
  Run r;
  for (const VertexDiagnostics& dg : (*fits)->diagnostics()) r.downgraded += (dg.flags & kFlagOscillation) != 0;
  auto surface = MakeSurface(method, mesh, *fits, threads);
  std::vector<SurfacePoint> out;
  if (absl::Status s = EvaluatePoints(*surface, RandomFacePoints(mesh, per_face, 42), &out, ctx); !s.ok()) {
    std::fprintf(stderr, "evaluate failed: %s\n", std::string(s.message()).c_str());
    std::exit(1);
  }
  for (const SurfacePoint& s : out) {
    const Eigen::Vector3d p = exact.Project(s.position);
    r.distance = std::max(r.distance, (p - s.position).norm());
    r.normal = std::max(r.normal, (exact.At(p).normal - s.normal).norm());
  }
  if (method == ReconstructionMethod::kWalf && exact_area > 0) {
    IntegrationInput in;
    in.volume = false;
    auto integrals = Integrate(*surface, in, ctx);
    if (integrals.ok()) r.area_error = std::abs(integrals->area - exact_area) / exact_area;
  }
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  std::string surface_name = "torus";
  std::vector<std::string> methods = {"walf", "cmf"}, meshes;
  std::vector<std::string> degrees = {"2", "3", "4", "5", "6"};
  int per_face = 3, threads = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const char* next = i + 1 < argc ? argv[i + 1] : nullptr;
    if (a == "--surface" && next) surface_name = argv[++i];
    else if (a == "--methods" && next) methods = SplitList(argv[++i], "");
    else if (a == "--degrees" && next) degrees = SplitList(argv[++i], "");
    else if (a == "--per-face" && next) per_face = std::atoi(argv[++i]);
    else if (a == "--threads" && next) threads = std::atoi(argv[++i]);
    else meshes.push_back(a);
  }
  auto exact = NamedSurface(surface_name);
  if (!exact.ok()) return std::fprintf(stderr, "unknown surface %s\n", surface_name.c_str()), 1;
  // Exact areas of the named surfaces the study uses (torus R = 1, r = 0.3; unit sphere).
  const double exact_area = surface_name == "torus" ? 4 * M_PI * M_PI * 0.3 : surface_name == "sphere" ? 4 * M_PI : 0;
  std::printf("mesh\tvertices\th\tmethod\tdegree\tdist_off\tdist_on\tdist_ratio\tnormal_off\tnormal_on\tnormal_ratio\t"
              "downgraded\tarea_err_off\tarea_err_on\n");
  for (const std::string& spec : meshes) {
    const size_t eq = spec.find('=');
    const std::string label = eq == std::string::npos ? spec : spec.substr(0, eq);
    const std::string path = eq == std::string::npos ? spec : spec.substr(eq + 1);
    // gen,NAME,N is the project's generated mesh NAME at resolution N (its own surface);
    // delaunay,V,JITTER the unstructured Delaunay sphere of V vertices.
    std::unique_ptr<AnalyticSurface> own;
    absl::StatusOr<Mesh> mesh;
    if (path.rfind("gen,", 0) == 0 || path.rfind("delaunay,", 0) == 0) {
      const std::vector<std::string> f = SplitList(path.c_str(), "");
      if (f.size() < 3) return std::fprintf(stderr, "bad spec %s\n", path.c_str()), 1;
      if (f[0] == "gen") {
        GeneratorOptions g;
        g.n = std::atoi(f[2].c_str());
        mesh = GenerateNamedMesh(f[1], g);
        own = *NamedSurface(f[1]);
      } else {
        mesh = GenerateDelaunaySphereMesh(std::atoi(f[1].c_str()), std::atof(f[2].c_str()));
        own = *NamedSurface("sphere");
      }
    } else {
      mesh = ReadMesh(path);
    }
    if (!mesh.ok()) return std::fprintf(stderr, "%s: %s\n", path.c_str(), std::string(mesh.status().message()).c_str()), 1;
    const AnalyticSurface& surface = own ? *own : **exact;
    const double area = own ? (path.find("torus") != std::string::npos ? 4 * M_PI * M_PI * 0.3 : 4 * M_PI) : exact_area;
    auto topo = BuildTopology(*mesh);
    if (!topo.ok()) return std::fprintf(stderr, "%s: %s\n", path.c_str(), std::string(topo.status().message()).c_str()), 1;
    const double h = AverageEdgeLength(*mesh);
    for (const std::string& m : methods) {
      const ReconstructionMethod method = m == "cmf" ? ReconstructionMethod::kCmf : ReconstructionMethod::kWalf;
      for (const std::string& ds : degrees) {
        const int d = std::atoi(ds.c_str());
        const Run off = Measure(*mesh, *topo, surface, area, method, d, false, per_face, threads);
        const Run on = Measure(*mesh, *topo, surface, area, method, d, true, per_face, threads);
        std::printf("%s\t%d\t%.5f\t%s\t%d\t%.3e\t%.3e\t%.2f\t%.3e\t%.3e\t%.2f\t%d\t%.3e\t%.3e\n", label.c_str(),
                    mesh->NumVertices(), h, m.c_str(), d, off.distance, on.distance, on.distance / off.distance,
                    off.normal, on.normal, on.normal / off.normal, on.downgraded, off.area_error, on.area_error);
        std::fflush(stdout);
      }
    }
  }
  return 0;
}
