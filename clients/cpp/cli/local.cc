// In-process commands of the `geomfit` tool: curvature --local, generate, convert.
#include <cstdio>
#include <functional>
#include <mutex>
#include <vector>

#include <sys/stat.h>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/progress.h"
#include "clients/cpp/cli/run_heap.h"
#include "core/fitting/fit.h"
#include "core/mesh/topology.h"
#include "core/surfaces/analytic.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"

namespace geomfit::cli {
namespace {

/// The same status with "<prefix>: " in front of its message.
absl::Status WithPrefix(const absl::Status& s, const std::string& prefix) {
  if (s.ok()) return s;
  return absl::Status(s.code(), absl::StrCat(prefix, ": ", s.message()));
}

/// Checks an output path's mesh extension before any work is done (a usage error).
absl::Status CheckMeshOutput(const std::string& path) { return MeshOutputFormat(path).status(); }

void Verbose(bool on, const std::string& line) {
  if (on) std::fprintf(stderr, "geomfit: %s\n", line.c_str());
}

/// Heap bytes a run needs for reading a mesh file of `file_bytes` (an OBJ: the text,
/// the parser's growing arrays, the mesh): what RunHeap commits before reading.
size_t ReadHeapBytes(int64_t file_bytes) { return static_cast<size_t>(2.3 * static_cast<double>(file_bytes)); }

/// Heap bytes the rest of a `curvature --local` run spans for `vertices` at `degree`
/// (the fit's: stencils and their spans, point records, mesh and topology, freed as the
/// fit goes, its blocks' frames and coefficients evaluated and dropped: FitAndEvaluate;
/// the quantities and the output's table), as measured on the gmsh torus (87k vertices,
/// one thread: the resident heap, reading included, of runs that back nothing ahead,
/// 4 KB pages). An estimate: what it leaves out faults in on use.
size_t FitHeapBytes(int vertices, int degree) {
  constexpr int kBytesPerVertex[] = {320, 320, 295, 370, 415, 440, 510};  // degrees 0-6
  const int d = std::max(degree, 0);
  return static_cast<size_t>(vertices) * (d <= 6 ? kBytesPerVertex[d] : kBytesPerVertex[6] + 150 * (d - 6));
}

/// Whether to fit on the mesh relabelled for locality: when its numbering is scattered
/// (a generator's local numbering gains nothing), and only if the fit's results depend
/// on the numbering through the topology's row orders alone, which
/// BuildTopology(LocalityRelabelling) sets in fan order (RowOrder::kRotational: the
/// source's stencils in another order, results equal to round-off; the parametric
/// comparison methods read face rows themselves). `--noise auto` relabels too: its noise
/// estimate samples by source index (Topology::vertex_source), the same vertices, so a
/// clean mesh gets the `--noise off` fit; `--noise on` keeps the source numbering.
bool RelabelForFit(const Mesh& mesh, const FitOptions& o) {
  return (o.method == FitMethod::kLHF || o.method == FitMethod::kLOP) && o.noise != NoiseMode::kOn &&
         !HasLocalNumbering(mesh);
}

/// `quantities` of every vertex of a mesh nobody else needs: each block of fits is
/// evaluated as soon as it is fitted and then dropped (FitSurfaceOnceInBlocks), so the
/// whole mesh's frames and coefficients are never held; the values of
/// ComputeDifferentials(FitSurface(...)).
absl::StatusOr<Differentials> FitAndEvaluate(Mesh mesh, Topology topo, const FitOptions& o, uint32_t quantities,
                                             const RunContext& ctx) {
  // Allocated at the first block, once the stencils and point records are built and
  // the mesh freed (its memory, not fresh pages).
  const int64_t nv = mesh.NumVertices();
  Differentials d;
  std::once_flag allocated;
  GF_RETURN_IF_ERROR(FitSurfaceOnceInBlocks(
      std::move(mesh), std::move(topo), o,
      [&](const SurfaceFits& fits, int64_t begin, int64_t end) {
        std::call_once(allocated, [&] { d = AllocateDifferentials(nv, quantities); });
        EvaluateDifferentials(fits, quantities, begin, end, &d);
      },
      ctx));
  if (nv == 0) d = AllocateDifferentials(0, quantities);
  // Evaluated with the fit's blocks (inside its "fit" phase): the phase still reported.
  ctx.Report("evaluate", nv, nv);
  return d;
}

/// Quantities of every vertex and their order (LocalFit::source).
struct LocalFit {
  Differentials d;
  std::vector<int32_t> source;  ///< row i of d is vertex source[i]'s; empty: vertex i's
};

/// Fit and `quantities` of every vertex, computed on the mesh relabelled for locality
/// when that pays and gives the same numbers to round-off (RelabelForFit): an external mesher's
/// scattered numbering then costs no cache misses. The rows stay in the relabelled
/// order (LocalFit::source maps them back: WriteRelabelledDifferentials).
/// `validated` is set once the mesh has passed validation (the "read" phase's end).
/// Unless `keep_mesh`, *mesh is emptied once it is validated (relabelled: at once; else
/// the fit takes it): its memory is then reused by the fit's arrays instead of new pages.
/// The fit (FitSurfaceOnce) frees the fitted mesh and topology as it goes.
absl::StatusOr<LocalFit> FitLocal(Mesh* source_mesh, bool keep_mesh, const std::string& path,
                                  const FitOptions& o, uint32_t quantities, const RunContext& ctx,
                                  const std::function<void()>& validated) {
  const Mesh& mesh = *source_mesh;
  if (RelabelForFit(mesh, o)) {
    absl::StatusOr<LocalityRelabelling> r = RelabelForLocality(mesh);
    absl::StatusOr<Topology> topo = r.ok() ? BuildTopology(*r) : r.status();
    // Any failure: the source's validation below reports it with the user's indices.
    if (topo.ok() && ValidateGeometry(r->mesh, ctx.threads()).ok()) {
      validated();
      if (!keep_mesh) *source_mesh = Mesh();
      std::vector<int32_t>().swap(r->face_source);  // BuildTopology's alone
      if (o.noise == NoiseMode::kAuto) topo->vertex_source = r->vertex_source;  // the noise test's sample
      // The fit frees the mesh and topology as it goes, and its blocks' fits once evaluated.
      GF_ASSIGN_OR_RETURN(Differentials d, FitAndEvaluate(std::move(r->mesh), std::move(*topo), o, quantities, ctx));
      return LocalFit{std::move(d), std::move(r->vertex_source)};
    }
  }
  absl::StatusOr<Topology> topo = ValidateMesh(mesh, ctx.threads());
  GF_RETURN_IF_ERROR(WithPrefix(topo.status(), path));
  validated();
  // Unless the output needs the mesh, the fit frees it and the topology as it goes.
  if (!keep_mesh) {
    GF_ASSIGN_OR_RETURN(Differentials d, FitAndEvaluate(std::move(*source_mesh), std::move(*topo), o, quantities, ctx));
    return LocalFit{std::move(d), {}};
  }
  FitRequest request;
  request.keep_neighborhoods = false;  // the quantities need no stencils
  GF_ASSIGN_OR_RETURN(const auto fits, FitSurface(mesh, *topo, o, nullptr, request, ctx));
  *topo = Topology();
  GF_ASSIGN_OR_RETURN(Differentials d, ComputeDifferentials(*fits, quantities, ctx));
  return LocalFit{std::move(d), {}};
}

}  // namespace

absl::Status RunCurvature(const std::vector<std::string>& argv) {
  CurvatureArgs a;
  bool help = false;
  GF_RETURN_IF_ERROR(ParseCurvatureArgs(argv, &a, &help));
  if (help) return absl::OkStatus();
  if (!a.server.empty()) {
#if defined(GEOMFIT_CLI_FRONT)
    return RunInFullCli();
#elif defined(GEOMFIT_WITH_CLIENT)
    return RunCurvatureRemote(a);
#else
    return UsageError(kNoClientMessage);
#endif
  }

  ProgressBar& bar = ProgressBar::Get();
  Stopwatch read_timer;
  bar.Begin("read");
  // Address space (free until used) for 32x the file, at least 64 MB: a degree-6 run
  // peaks at ~9x an OBJ and ~24x a binary PLY. Backed ahead of use: for reading, then
  // for the fit once the vertices are known.
  RunHeap heap;
  struct stat st;
  if (stat(a.mesh.c_str(), &st) == 0 && st.st_size > 0) {
    heap.Reserve(std::max<size_t>(32 * static_cast<size_t>(st.st_size), size_t{64} << 20));
    heap.Commit(ReadHeapBytes(st.st_size));
  }
  GF_ASSIGN_OR_RETURN(Mesh mesh, ReadMesh(a.mesh));
  heap.Commit(FitHeapBytes(mesh.NumVertices(), std::max(a.fit.degree, a.fit.NormalDegree())));
  Stopwatch fit_timer;
  const RunContext ctx = bar.Context(a.threads);
  // Only the VTK outputs need the mesh once it is fitted.
  const bool keep_mesh = OutputNeedsMesh(a.output);
  GF_ASSIGN_OR_RETURN(LocalFit fit, FitLocal(&mesh, keep_mesh, a.mesh, a.fit, OutputQuantities(a.output), ctx, [&] {
                        Verbose(a.verbose, absl::StrFormat("read %s: %d vertices, %d faces in %.3f s", a.mesh,
                                                           mesh.NumVertices(), mesh.NumFaces(), read_timer.Seconds()));
                        fit_timer = Stopwatch();
                      }));
  Verbose(a.verbose, absl::StrFormat("fit + quantities (degree %d, %s): %.3f s", a.fit.degree,
                                     FitMethodName(a.fit.method), fit_timer.Seconds()));

  Stopwatch write_timer;
  bar.Begin("write");
  GF_ASSIGN_OR_RETURN(const VtkEncoding encoding, VtkEncodingFromFlags(a.ascii, a.zlib));
  GF_RETURN_IF_ERROR(WriteRelabelledDifferentials(a.output, mesh, std::move(fit.d), fit.source, encoding));
  bar.Finish();
  Verbose(a.verbose, absl::StrFormat("wrote %s in %.3f s", a.output.empty() ? "stdout" : a.output,
                                     write_timer.Seconds()));
  const RunHeapStats& h = heap.stats();
  Verbose(a.verbose && h.reserved > 0,
          absl::StrFormat("heap: %d MB backed ahead (%d MB in 2 MB pages%s) in %.1f ms CPU", h.committed >> 20,
                          h.huge_bytes >> 20, h.small_pages ? ", then 4 KB pages" : "", h.commit_ms));
  return absl::OkStatus();
}

absl::Status RunGenerate(const std::vector<std::string>& argv) {
  std::string name, output;
  GeneratorOptions g;
  bool verbose = false;
  ArgParser p("geomfit generate", "NAME [--level N] [--jitter J] [--seed S] --output FILE",
              "Generates a mesh on an analytic surface (vertices exactly on it, irregular\n"
              "connectivity), in any mesh format or .vtp.");
  p.Positional("NAME", &name, "sphere, torus, ellipsoid, bump or quadtorus")
      .Int("level", &g.n, "resolution n (edge length ~ 1/n), 2..4096")
      .Double("jitter", &g.jitter, "vertex jitter along the surface, x local spacing, 0..0.3")
      .UInt64("seed", &g.seed, "random seed of the jitter and diagonals")
      .String("output", &output, "output file (.obj .off .ply .stl .vtp .vtu)", "FILE")
      .Flag("verbose", &verbose, "print timings to stderr");
  GF_RETURN_IF_ERROR(p.Parse(argv));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  if (output.empty()) return UsageError("'geomfit generate' needs --output FILE");
  GF_RETURN_IF_ERROR(CheckMeshOutput(output));

  Stopwatch timer;
  absl::StatusOr<Mesh> mesh = GenerateNamedMesh(name, g);
  // Its only failures are bad arguments (name, level, jitter).
  if (!mesh.ok()) return UsageError(mesh.status().message());
  Verbose(verbose, absl::StrFormat("generated %s: %d vertices, %d faces in %.3f s", name,
                                   mesh->NumVertices(), mesh->NumFaces(), timer.Seconds()));
  Stopwatch write_timer;
  GF_RETURN_IF_ERROR(WriteMeshOutput(*mesh, output));
  Verbose(verbose, absl::StrFormat("wrote %s in %.3f s", output, write_timer.Seconds()));
  return absl::OkStatus();
}

absl::Status RunConvert(const std::vector<std::string>& argv) {
  std::string in, out;
  bool verbose = false, ascii = false, zlib = false;
  ArgParser p("geomfit convert", "IN OUT [--ascii | --zlib]",
              "Converts a mesh between formats, chosen by extension. Reads .obj .off .ply\n"
              ".stl; writes those (PLY binary, STL binary), .vtp and .vtu.");
  p.Positional("IN", &in, "input mesh file")
      .Positional("OUT", &out, "output mesh file")
      .Flag("ascii", &ascii, ".vtp/.vtu as text (default: binary, appended raw)")
      .Flag("zlib", &zlib, ".vtp/.vtu appended arrays zlib-compressed")
      .Flag("verbose", &verbose, "print timings to stderr");
  GF_RETURN_IF_ERROR(p.Parse(argv));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  GF_RETURN_IF_ERROR(CheckMeshOutput(out));
  VtkOptions vtk;
  GF_ASSIGN_OR_RETURN(vtk.encoding, VtkEncodingFromFlags(ascii, zlib));
  if (IsOutputOnly(FormatFromPath(in).value_or(MeshFormat::kVtp)))
    return UsageError(absl::StrCat("input '", in, "': expected .obj, .off, .ply or .stl"));

  Stopwatch timer;
  GF_ASSIGN_OR_RETURN(const Mesh mesh, ReadMesh(in));
  Verbose(verbose, absl::StrFormat("read %s: %d vertices, %d faces in %.3f s", in,
                                   mesh.NumVertices(), mesh.NumFaces(), timer.Seconds()));
  Stopwatch write_timer;
  GF_RETURN_IF_ERROR(WriteMeshOutput(mesh, out, vtk));
  Verbose(verbose, absl::StrFormat("wrote %s in %.3f s", out, write_timer.Seconds()));
  return absl::OkStatus();
}

}  // namespace geomfit::cli
