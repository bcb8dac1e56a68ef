// In-process chapter-4 commands of the `geomfit` tool: project, refine, nodes, integrate.
#include <cstdio>
#include <map>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/progress.h"
#include "core/integration/integrate.h"
#include "core/mesh/topology.h"
#include "core/reconstruction/features.h"
#include "core/reconstruction/meshing.h"
#include "core/reconstruction/projection.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"

namespace geomfit::cli {
namespace {

// Options every reconstruction command shares.
struct SurfaceArgs {
  std::string mesh, method = "walf", output, feature_edges, server;
  int degree = DefaultReconstructionFit().degree, threads = 0;
  double feature_angle = 0;
  bool no_safeguard = false, verbose = false;
};

void AddSurfaceOptions(ArgParser* p, SurfaceArgs* a) {
  p->Positional("MESH", &a->mesh, "mesh file (.obj .off .ply .stl)")
      .String("method", &a->method, "reconstruction: walf, cmf or linear", "M")
      .Int("degree", &a->degree, "fitting degree 1..6")
      .Flag("no-safeguard", &a->no_safeguard, "turn the oscillation safeguard (4.1.3) off")
      .Double("feature-angle", &a->feature_angle, "keep sharp edges whose dihedral angle exceeds DEG (0 = off)")
      .String("feature-edges", &a->feature_edges, "file of user-marked feature edges 'a b' (vertex ids)", "FILE")
      .Int("threads", &a->threads, "threads (0 = all cores)")
      .String("output", &a->output, "output file", "FILE")
      .Server(&a->server, "compute on a geomfit server (MESH: a file to upload or a mesh id)")
      .Flag("verbose", &a->verbose, "print timings to stderr");
}

#ifdef GEOMFIT_WITH_CLIENT
// The same surface options as the service takes them.
absl::StatusOr<v1::ReconstructionOptions> ToWire(const SurfaceArgs& a) {
  v1::ReconstructionOptions o;
  const std::map<std::string, v1::Reconstruction> methods = {
      {"walf", v1::RECONSTRUCTION_WALF}, {"cmf", v1::RECONSTRUCTION_CMF}, {"linear", v1::RECONSTRUCTION_LINEAR}};
  if (!methods.count(a.method)) return UsageError(absl::StrCat("--method '", a.method, "': expected walf, cmf or linear"));
  o.set_method(methods.at(a.method));
  o.mutable_fit()->set_degree(a.degree);
  o.mutable_fit()->set_oscillation_safeguard(!a.no_safeguard);
  o.set_feature_angle_deg(a.feature_angle);
  if (!a.feature_edges.empty()) return UsageError("--feature-edges is not supported with --server yet");
  return o;
}

struct RemoteSession {
  std::unique_ptr<Client> client;
  std::string id;
  Mesh mesh;  // read when MESH is a file
};

absl::StatusOr<RemoteSession> Connect(const SurfaceArgs& a) {
  RemoteSession r;
  r.client = ConnectTo(a.server);
  GF_ASSIGN_OR_RETURN(r.id, RemoteMeshId(*r.client, a.mesh, a.verbose, &r.mesh));
  ProgressBar::Get().Begin("compute");
  return r;
}
#endif

#ifndef GEOMFIT_WITH_CLIENT
absl::Status NoClient(const SurfaceArgs&) { return UsageError(kNoClientMessage); }
#endif

absl::StatusOr<ReconstructionMethod> ParseMethod(const std::string& m) {
  if (m == "walf") return ReconstructionMethod::kWalf;
  if (m == "cmf") return ReconstructionMethod::kCmf;
  if (m == "linear") return ReconstructionMethod::kLinear;
  return UsageError(absl::StrCat("--method '", m, "': expected walf, cmf or linear"));
}

// A whitespace-separated numeric table with `cols` columns ('#' comments, blank lines).
absl::StatusOr<RowMajorMatrixXd> ReadTable(const std::string& path, int cols) {
  GF_ASSIGN_OR_RETURN(const std::string text, ReadFileToString(path));
  std::vector<double> values;
  int line_no = 0, rows = 0;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    ++line_no;
    if (const size_t hash = line.find('#'); hash != absl::string_view::npos) line = line.substr(0, hash);
    std::vector<absl::string_view> tok = absl::StrSplit(line, absl::ByAnyChar(" \t,\r"), absl::SkipEmpty());
    if (tok.empty()) continue;
    if (static_cast<int>(tok.size()) != cols)
      return absl::InvalidArgumentError(absl::StrFormat("%s:%d: expected %d numbers, found %d", path, line_no, cols, tok.size()));
    for (absl::string_view t : tok) {
      double v;
      if (!absl::SimpleAtod(t, &v))
        return absl::InvalidArgumentError(absl::StrFormat("%s:%d: '%s' is not a number", path, line_no, t));
      values.push_back(v);
    }
    ++rows;
  }
  return RowMajorMatrixXd(Eigen::Map<RowMajorMatrixXd>(values.data(), rows, cols));
}

// A mesh, its topology, fits and reconstructed surface (the mesh outlives the surface).
struct Loaded {
  Mesh mesh;
  Topology topo;
  std::shared_ptr<const Features> features;  // with sharp features: fits are of features->split
  Topology split_topo;
  std::shared_ptr<const SurfaceFits> fits;
  std::unique_ptr<ReconstructedSurface> surface;
};

absl::Status Load(const SurfaceArgs& a, bool stencils, Loaded* out) {
  GF_ASSIGN_OR_RETURN(const ReconstructionMethod method, ParseMethod(a.method));
  FitOptions o;
  o.degree = a.degree;
  o.oscillation_safeguard = !a.no_safeguard;
  if (absl::Status s = ValidateFitOptions(o); !s.ok()) return UsageError(s.message());
  Stopwatch t;
  ProgressBar::Get().Begin("read");
  GF_ASSIGN_OR_RETURN(out->mesh, ReadMesh(a.mesh));
  absl::StatusOr<Topology> topo = ValidateMesh(out->mesh);
  if (!topo.ok()) return absl::InvalidArgumentError(absl::StrCat(a.mesh, ": ", topo.status().message()));
  out->topo = *std::move(topo);
  if (a.feature_angle > 0 || !a.feature_edges.empty()) {  // sharp features (4.1.4)
    FeatureOptions fo;
    if (a.feature_angle > 0) fo.angle_deg = a.feature_angle;
    else fo.angle_deg = 180;  // only the marked edges
    if (!a.feature_edges.empty()) {
      GF_ASSIGN_OR_RETURN(const RowMajorMatrixXd e, ReadTable(a.feature_edges, 2));
      for (int i = 0; i < e.rows(); ++i) fo.marked.emplace_back(static_cast<int32_t>(e(i, 0)), static_cast<int32_t>(e(i, 1)));
    }
    GF_ASSIGN_OR_RETURN(Features f, DetectFeatures(out->mesh, out->topo, fo));
    auto features = std::make_shared<const Features>(std::move(f));
    GF_ASSIGN_OR_RETURN(out->split_topo, BuildTopology(features->split));
    GF_ASSIGN_OR_RETURN(out->fits, FitSurface(features->split, out->split_topo, o, nullptr, FitRequest{.stencils = stencils}, ProgressBar::Get().Context(a.threads)));
    out->features = features;
    out->surface = std::make_unique<FeatureSurface>(out->mesh, features, MakeSurface(method, features->split, out->fits, a.threads), a.degree);
    if (a.verbose)
      std::fprintf(stderr, "geomfit: %zu feature edges in %zu ridge curves\n", features->edges.size(), features->curves.size());
  } else {
    GF_ASSIGN_OR_RETURN(out->fits, FitSurface(out->mesh, out->topo, o, nullptr, FitRequest{.stencils = stencils}, ProgressBar::Get().Context(a.threads)));
    out->surface = MakeSurface(method, out->mesh, out->fits, a.threads);
  }
  if (a.verbose)
    std::fprintf(stderr, "geomfit: read and fitted %s (%d vertices, degree %d) in %.3f s\n", a.mesh.c_str(),
                 out->mesh.NumVertices(), a.degree, t.Seconds());
  return absl::OkStatus();
}

absl::Status WriteText(const std::string& path, const std::string& text) {
  ProgressBar::Get().Begin("write");
  if (path.empty() || path == "-") {
    std::fputs(text.c_str(), stdout);
    return absl::OkStatus();
  }
  return WriteFileAtomically(path, text);
}

// Parses; prints usage and returns true in *help when asked.
absl::Status ParseOrHelp(ArgParser& p, const std::vector<std::string>& argv, bool* help) {
  GF_RETURN_IF_ERROR(p.Parse(argv));
  *help = p.help_requested();
  if (*help) std::fputs(p.Usage().c_str(), stdout);
  return absl::OkStatus();
}

/// `geomfit refine --job`: a refine job on the server, watched to its end.
absl::Status RefineAsJob(const SurfaceArgs& a, int factor, int levels) {
  if (a.server.empty()) return UsageError("--job needs --server HOST:PORT");
  if (levels < 1 || levels > 8) return UsageError(absl::StrCat("--levels ", levels, " is out of range [1, 8]"));
  if (factor != 2 && factor != 3) return UsageError(absl::StrCat("--factor ", factor, ": a job refines by 2 or 3"));
  if (!a.output.empty()) {
    GF_RETURN_IF_ERROR(MeshOutputFormat(a.output).status());
  }
#ifdef GEOMFIT_WITH_CLIENT
  GF_ASSIGN_OR_RETURN(const v1::ReconstructionOptions o, ToWire(a));
  GF_ASSIGN_OR_RETURN(RemoteSession r, Connect(a));
  v1::RefineJob spec;
  spec.set_mesh_id(r.id);
  *spec.mutable_options() = o;
  spec.set_factor(factor);
  spec.set_levels(levels);
  GF_ASSIGN_OR_RETURN(const std::vector<v1::JobResultMesh> results, RunRefineJob(*r.client, spec));
  std::string table = "level\tmesh_id\trevision\tvertices\tfaces\n";
  for (size_t k = 0; k < results.size(); ++k) {
    GF_ASSIGN_OR_RETURN(const RemoteMesh m, r.client->GetMesh(results[k].mesh_id()));
    absl::StrAppendFormat(&table, "%d\t%s\t%d\t%d\t%d\n", k + 1, m.mesh_id, m.revision, m.num_vertices,
                          m.num_faces);
  }
  std::fputs(table.c_str(), stdout);
  if (a.output.empty() || results.empty()) return absl::OkStatus();
  GF_ASSIGN_OR_RETURN(const Mesh finest, r.client->Download(results.back().mesh_id()));
  return WriteMeshOutput(finest, a.output);
#else
  return NoClient(a);
#endif
}

}  // namespace

absl::Status RunProject(const std::vector<std::string>& argv) {
  SurfaceArgs a;
  std::string points, face_points;
  ArgParser p("geomfit project", "MESH (--points XYZ.txt | --face-points FXE.txt) [options]",
              "Projects points onto the high-order surface reconstructed from MESH (4.1-4.2).\n"
              "--points: lines 'x y z' near the surface; --face-points: lines 'face xi eta'.\n"
              "Writes TSV: face xi eta x y z nx ny nz distance.");
  AddSurfaceOptions(&p, &a);
  p.String("points", &points, "file of points x y z", "FILE").String("face-points", &face_points, "file of face xi eta", "FILE");
  bool help;
  GF_RETURN_IF_ERROR(ParseOrHelp(p, argv, &help));
  if (help) return absl::OkStatus();
  if (points.empty() == face_points.empty()) return UsageError("give exactly one of --points and --face-points");
  std::vector<ProjectedPoint> out;
  Stopwatch t;
  if (!a.server.empty()) {
#ifdef GEOMFIT_WITH_CLIENT
    GF_ASSIGN_OR_RETURN(const v1::ReconstructionOptions o, ToWire(a));
    GF_ASSIGN_OR_RETURN(RemoteSession r, Connect(a));
    GF_ASSIGN_OR_RETURN(const RowMajorMatrixXd table, ReadTable(points.empty() ? face_points : points, 3));
    if (!points.empty()) {
      GF_ASSIGN_OR_RETURN(out, r.client->ProjectPoints(r.id, Positions(table), o));
    } else {
      std::vector<FacePoint> fp(table.rows());
      for (int i = 0; i < table.rows(); ++i) fp[i] = {static_cast<int32_t>(table(i, 0)), table(i, 1), table(i, 2)};
      GF_ASSIGN_OR_RETURN(out, r.client->EvaluateFacePoints(r.id, fp, o));
    }
#else
    return NoClient(a);
#endif
  } else if (!points.empty()) {
    Loaded l;
    GF_RETURN_IF_ERROR(Load(a, false, &l));
    GF_ASSIGN_OR_RETURN(const RowMajorMatrixXd xyz, ReadTable(points, 3));
    GF_RETURN_IF_ERROR(ProjectPoints(*l.surface, l.topo, Positions(xyz), &out, ProgressBar::Get().Context(a.threads)));
  } else {
    Loaded l;
    GF_RETURN_IF_ERROR(Load(a, false, &l));
    GF_ASSIGN_OR_RETURN(const RowMajorMatrixXd fxe, ReadTable(face_points, 3));
    std::vector<FacePoint> fp(fxe.rows());
    for (int i = 0; i < fxe.rows(); ++i) {
      if (fxe(i, 0) != static_cast<int32_t>(fxe(i, 0)))
        return absl::InvalidArgumentError(absl::StrFormat("%s: point %d: face %g is not an integer", face_points, i, fxe(i, 0)));
      fp[i] = {static_cast<int32_t>(fxe(i, 0)), fxe(i, 1), fxe(i, 2)};
    }
    std::vector<SurfacePoint> sp;
    GF_RETURN_IF_ERROR(EvaluatePoints(*l.surface, fp, &sp, ProgressBar::Get().Context(a.threads)));
    out.resize(sp.size());
    for (size_t i = 0; i < sp.size(); ++i) out[i] = {fp[i], sp[i], 0.0};
  }
  if (a.verbose) std::fprintf(stderr, "geomfit: %zu points in %.3f s\n", out.size(), t.Seconds());
  std::string text = "# face\txi\teta\tx\ty\tz\tnx\tny\tnz\tdistance\n";
  for (const ProjectedPoint& q : out) {
    const Eigen::Vector3d& x = q.point.position;
    const Eigen::Vector3d& n = q.point.normal;
    absl::StrAppendFormat(&text, "%d\t%.17g\t%.17g\t%.17g\t%.17g\t%.17g\t%.17g\t%.17g\t%.17g\t%.17g\n", q.where.face,
                          q.where.xi, q.where.eta, x.x(), x.y(), x.z(), n.x(), n.y(), n.z(), q.distance);
  }
  return WriteText(a.output, text);
}

absl::Status RunRefine(const std::vector<std::string>& argv) {
  SurfaceArgs a;
  int factor = 2, levels = 1;
  bool job = false;
  ArgParser p("geomfit refine", "MESH --output OUT [--factor 2|3] [options]\n"
              "       geomfit refine --server HOST:PORT MESH --job [--levels N] [--output OUT] [options]",
              "Uniform refinement (4.2.2): each face into factor^2 faces, new vertices on the\n"
              "reconstructed surface. OUT: .obj .off .ply .stl or .vtp.\n"
              "--job: a server job refining --levels times, each level stored as a mesh (printed as\n"
              "'level mesh_id revision vertices faces'), progress lines on stderr; OUT gets the finest.");
  AddSurfaceOptions(&p, &a);
  p.Int("factor", &factor, "2: triangles and quads 1 -> 4; 3: 1 -> 9")
      .Int("levels", &levels, "refinement levels (with --job), 1..8")
      .Flag("job", &job, "run as a job on the server (needs --server): watchable, cancellable");
  bool help;
  GF_RETURN_IF_ERROR(ParseOrHelp(p, argv, &help));
  if (help) return absl::OkStatus();
  if (job) return RefineAsJob(a, factor, levels);
  if (levels != 1) return UsageError("--levels needs --job (and --server)");
  if (a.output.empty()) return UsageError("'geomfit refine' needs --output FILE");
  GF_RETURN_IF_ERROR(MeshOutputFormat(a.output).status());
  if (factor < 2 || factor > 8) return UsageError(absl::StrCat("--factor ", factor, " is out of range [2, 8]"));
  if (!a.server.empty()) {
#ifdef GEOMFIT_WITH_CLIENT
    GF_ASSIGN_OR_RETURN(const v1::ReconstructionOptions o, ToWire(a));
    GF_ASSIGN_OR_RETURN(RemoteSession r, Connect(a));
    GF_ASSIGN_OR_RETURN(const RemoteMesh refined, r.client->RefineMesh(r.id, factor, o));
    std::fprintf(stderr, "geomfit: stored the refined mesh as %s\n", refined.mesh_id.c_str());
    GF_ASSIGN_OR_RETURN(const Mesh m, r.client->Download(refined.mesh_id));
    return WriteMeshOutput(m, a.output);
#else
    return NoClient(a);
#endif
  }
  Loaded l;
  GF_RETURN_IF_ERROR(Load(a, false, &l));
  GF_ASSIGN_OR_RETURN(const Mesh refined, RefineMesh(*l.surface, l.topo, factor, ProgressBar::Get().Context(a.threads)));
  ProgressBar::Get().Begin("write");
  return WriteMeshOutput(refined, a.output);
}

absl::Status RunNodes(const std::vector<std::string>& argv) {
  SurfaceArgs a;
  int order = 2;
  ArgParser p("geomfit nodes", "MESH --output PREFIX [--order 2|3] [options]",
              "High-order (quadratic or cubic) elements on the reconstructed surface (4.2.1).\n"
              "Writes PREFIX.nodes.tsv (x y z per node; mesh vertices first) and\n"
              "PREFIX.elements.tsv (node ids per face: corners, edge nodes, interior),\n"
              "PREFIX.vtu (the elements as VTK Lagrange cells) and, in-process, PREFIX.vtp\n"
              "(every element split along its nodes).");
  AddSurfaceOptions(&p, &a);
  p.Int("order", &order, "element order: 2 or 3");
  bool help;
  GF_RETURN_IF_ERROR(ParseOrHelp(p, argv, &help));
  if (help) return absl::OkStatus();
  if (a.output.empty()) return UsageError("'geomfit nodes' needs --output PREFIX");
  if (order != 2 && order != 3) return UsageError(absl::StrCat("--order ", order, ": expected 2 or 3"));
  HighOrderMesh ho;
  if (!a.server.empty()) {
#ifdef GEOMFIT_WITH_CLIENT
    GF_ASSIGN_OR_RETURN(const v1::ReconstructionOptions o, ToWire(a));
    GF_ASSIGN_OR_RETURN(RemoteSession r, Connect(a));
    GF_ASSIGN_OR_RETURN(ho, r.client->HighOrderNodes(r.id, order, o));
#else
    return NoClient(a);
#endif
  } else {
    Loaded l;
    GF_RETURN_IF_ERROR(Load(a, false, &l));
    GF_ASSIGN_OR_RETURN(ho, MakeHighOrderMesh(*l.surface, l.topo, order, ProgressBar::Get().Context(a.threads)));
    // For viewing: each element split along its nodes (the same lattice) as PREFIX.vtp.
    GF_ASSIGN_OR_RETURN(const Mesh split, RefineMesh(*l.surface, l.topo, order, ProgressBar::Get().Context(a.threads)));
    GF_RETURN_IF_ERROR(WriteVtp(a.output + ".vtp", split, {}, VtkOptions{}));
  }
  ProgressBar::Get().Begin("write");
  std::string nodes = "# x\ty\tz\n", elements;
  for (int i = 0; i < ho.nodes.rows(); ++i)
    absl::StrAppendFormat(&nodes, "%.17g\t%.17g\t%.17g\n", ho.nodes(i, 0), ho.nodes(i, 1), ho.nodes(i, 2));
  for (size_t f = 0; f + 1 < ho.offsets.size(); ++f) {
    for (int q = ho.offsets[f]; q < ho.offsets[f + 1]; ++q)
      absl::StrAppend(&elements, q > ho.offsets[f] ? "\t" : "", ho.elements[q]);
    elements += "\n";
  }
  GF_RETURN_IF_ERROR(WriteLagrangeVtu(a.output + ".vtu", ho));
  GF_RETURN_IF_ERROR(WriteFileAtomically(a.output + ".nodes.tsv", nodes));
  return WriteFileAtomically(a.output + ".elements.tsv", elements);
}

absl::Status RunIntegrate(const std::vector<std::string>& argv) {
  SurfaceArgs a;
  a.method = "walf";
  int quadrature = 0;
  std::string scalar, vector;
  ArgParser p("geomfit integrate", "MESH [--scalar FILE] [--vector FILE] [options]",
              "High-order surface integrals (4.3): area, enclosed volume, and optionally the\n"
              "integral of a nodal scalar field (one value per vertex per line) and the flux\n"
              "of a nodal vector field (three values per line). --method linear gives the\n"
              "flat-triangle baseline; --feature-angle / --feature-edges integrate over the surface\n"
              "split along sharp edges, faces following the ridge curves (4.1.4). Prints 'name value'\n"
              "lines.");
  AddSurfaceOptions(&p, &a);
  p.Int("quadrature", &quadrature, "quadrature degree (0 = degree + 2, at least 4; up to 30)")
      .String("scalar", &scalar, "nodal scalar field file", "FILE")
      .String("vector", &vector, "nodal vector field file", "FILE");
  bool help;
  GF_RETURN_IF_ERROR(ParseOrHelp(p, argv, &help));
  if (help) return absl::OkStatus();
  if (a.method == "cmf") return UsageError("--method cmf is not supported for integration (walf or linear)");
  if (quadrature < 0 || quadrature > 30) return UsageError(absl::StrCat("--quadrature ", quadrature, " is out of range [0, 30]"));
  IntegrationInput in;
  in.quadrature_degree = quadrature;
  if (!scalar.empty()) {
    GF_ASSIGN_OR_RETURN(in.scalars, ReadTable(scalar, 1));
  }
  if (!vector.empty()) {
    GF_ASSIGN_OR_RETURN(in.vectors, ReadTable(vector, 3));
  }
  Integrals r;
  if (!a.server.empty()) {
#ifdef GEOMFIT_WITH_CLIENT
    GF_ASSIGN_OR_RETURN(const v1::ReconstructionOptions o, ToWire(a));
    GF_ASSIGN_OR_RETURN(RemoteSession s, Connect(a));
    GF_ASSIGN_OR_RETURN(r, s.client->Integrate(s.id, in, o));
#else
    return NoClient(a);
#endif
  } else {
    Loaded l;
    GF_RETURN_IF_ERROR(Load(a, !scalar.empty() || !vector.empty(), &l));
    GF_ASSIGN_OR_RETURN(r, Integrate(*l.surface, in, ProgressBar::Get().Context(a.threads)));
  }
  std::string text = absl::StrFormat("area\t%.17g\nvolume\t%.17g\n", r.area, r.volume);
  if (!scalar.empty()) absl::StrAppendFormat(&text, "scalar\t%.17g\n", r.scalars[0]);
  if (!vector.empty()) absl::StrAppendFormat(&text, "flux\t%.17g\n", r.flux);
  return WriteText(a.output, text);
}

}  // namespace geomfit::cli
