// `geomfit membrane pressure|solve` (chapter 6): the stress and interface pressure of a
// deformed membrane against its reference, and the pressure-load solve (on a server as
// a job, or in-process with --local).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/progress.h"
#include "core/mechanics/membrane.h"
#include "core/mechanics/pressure_solve.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "core/util/status_macros.h"
#ifdef GEOMFIT_WITH_CLIENT
#include "proto/wire.h"
#endif

namespace geomfit::cli {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Options shared by both subcommands.
struct MembraneArgs {
  std::string mesh, server, output;
  bool local = false, ascii = false;
  double young_modulus = kNaN, poisson_ratio = kNaN;
  int degree = 4, threads = 0;
};

void AddCommon(ArgParser* p, MembraneArgs* a) {
  p->Server(&a->server, "geomfit server")
      .Flag("local", &a->local, "run in this process")
      .Double("young-modulus", &a->young_modulus, "Young's modulus E > 0 (required)")
      .Double("poisson-ratio", &a->poisson_ratio, "Poisson ratio nu in (-1, 0.5) (required)")
      .Int("degree", &a->degree, "fitting degree of the reference (LHF)")
      .Int("threads", &a->threads, "--local: threads (0 = all cores)")
      .Flag("ascii", &a->ascii, ".vtp/.vtu arrays as text");
}

/// Usage checks that need no mesh.
absl::Status CheckCommon(const MembraneArgs& a) {
  if (a.local == !a.server.empty()) return UsageError("give exactly one of --server HOST:PORT and --local");
  MembraneOptions m;
  m.E = a.young_modulus;
  m.nu = a.poisson_ratio;
  if (absl::Status s = ValidateMembraneOptions(m); !s.ok())
    return UsageError(absl::StrCat(absl::StrContains(s.message(), "nu:") ? "--poisson-ratio" : "--young-modulus",
                                   ": ", s.message()));
  if (a.degree < 1 || a.degree > 6) return UsageError("--degree: expected 1..6");
  return absl::OkStatus();
}

MembraneOptions Material(const MembraneArgs& a) {
  MembraneOptions m;
  m.E = a.young_modulus;
  m.nu = a.poisson_ratio;
  return m;
}

/// The fields present as point arrays (Pressure the active scalars).
std::vector<PointField> MembraneFieldsOf(const MembraneFields& f) {
  std::vector<PointField> out;
  auto add = [&](const char* name, const auto& a) {
    if (a.size() > 0) out.push_back({name, Eigen::MatrixXd(a)});
  };
  add("Pressure", f.pressure);
  add("Stretches", f.stretches);
  add("Strain", f.strain);
  add("Stress", f.stress);
  add("VonMises", f.von_mises);
  add("Traction", f.traction);
  return out;
}

/// Point arrays on `mesh`: .vtp / .vtu, or a table (.tsv, .npy; empty or "-": TSV on
/// stdout) with one column per component (NAME or NAME_k; `mesh` unused).
absl::Status WriteFields(const std::string& path, const Mesh& mesh, const std::vector<PointField>& fields,
                         const std::string& scalars, bool ascii) {
  const bool table = path.empty() || path == "-";
  OutputKind kind = OutputKind::kTsv;
  if (!table) {
    GF_ASSIGN_OR_RETURN(kind, OutputKindFromPath(path));
  }
  if (kind == OutputKind::kVtp || kind == OutputKind::kVtu) {
    VtkOptions o;
    if (ascii) o.encoding = VtkEncoding::kAscii;
    for (const PointField& f : fields)
      if (f.name == scalars) o.scalars = scalars;
    return kind == OutputKind::kVtp ? WriteVtp(path, mesh, fields, o) : WriteVtu(path, mesh, fields, o);
  }
  int64_t cols = 0;
  std::string header = "#";
  for (const PointField& f : fields) {
    for (int c = 0; c < f.values.cols(); ++c)
      absl::StrAppend(&header, cols++ == 0 ? " " : "\t", f.name, f.values.cols() > 1 ? absl::StrCat("_", c) : "");
  }
  RowMajorMatrixXd t(fields.empty() ? 0 : fields[0].values.rows(), cols);
  for (int64_t c = 0; const PointField& f : fields) {
    t.middleCols(c, f.values.cols()) = f.values;
    c += f.values.cols();
  }
  if (kind == OutputKind::kNpy) return WriteNpy(path, t);
  std::string text = header + "\n";
  for (int i = 0; i < t.rows(); ++i)
    for (int c = 0; c < t.cols(); ++c) absl::StrAppendFormat(&text, "%.17g%c", t(i, c), c + 1 < t.cols() ? '\t' : '\n');
  if (!table) return WriteFileAtomically(path, text);
  if (std::fwrite(text.data(), 1, text.size(), stdout) != text.size() || std::fflush(stdout) != 0)
    return absl::ErrnoToStatus(errno, "cannot write to standard output");
  return absl::OkStatus();
}

void PrintPressureSummary(const Eigen::VectorXd& p) {
  if (p.size() == 0) return;
  double lo = INFINITY, hi = -INFINITY, sum = 0;
  int n = 0;
  for (double v : p)
    if (std::isfinite(v)) lo = std::min(lo, v), hi = std::max(hi, v), sum += v, ++n;
  std::fprintf(stderr, "geomfit: pressure over %d vertices: min %.9g mean %.9g max %.9g\n", n, lo,
               n > 0 ? sum / n : kNaN, hi);
}

// ---- pressure ------------------------------------------------------------------

struct PressureArgs : MembraneArgs {
  std::string deformed, quantities = "pressure,stretches,von_mises";
  int revision = 0, deformed_revision = 0;
};

/// --quantities as wire values.
absl::StatusOr<std::vector<v1::MembraneQuantity>> ParseQuantities(const std::string& list) {
  std::vector<v1::MembraneQuantity> out;
  for (absl::string_view name : absl::StrSplit(list, ',', absl::SkipEmpty())) {
    v1::MembraneQuantity q;
    if (!v1::MembraneQuantity_Parse(absl::StrCat("MEMBRANE_QUANTITY_", absl::AsciiStrToUpper(name)), &q) ||
        q == v1::MEMBRANE_QUANTITY_UNSPECIFIED)
      return UsageError(absl::StrCat("--quantities: unknown '", name,
                                     "' (pressure, stretches, strain, stress, von_mises, traction)"));
    out.push_back(q);
  }
  if (out.empty()) return UsageError("--quantities: empty");
  return out;
}

/// Drops the arrays not asked for (the local computation makes them all).
void Keep(const std::vector<v1::MembraneQuantity>& qs, MembraneFields* f) {
  auto want = [&](v1::MembraneQuantity q) { return std::find(qs.begin(), qs.end(), q) != qs.end(); };
  if (!want(v1::MEMBRANE_QUANTITY_PRESSURE)) f->pressure.resize(0);
  if (!want(v1::MEMBRANE_QUANTITY_STRETCHES)) f->stretches.resize(0, 2);
  if (!want(v1::MEMBRANE_QUANTITY_STRAIN)) f->strain.resize(0, 9);
  if (!want(v1::MEMBRANE_QUANTITY_STRESS)) f->stress.resize(0, 9);
  if (!want(v1::MEMBRANE_QUANTITY_VON_MISES)) f->von_mises.resize(0);
  if (!want(v1::MEMBRANE_QUANTITY_TRACTION)) f->traction.resize(0);
}

absl::Status PressureLocal(const PressureArgs& a, const std::vector<v1::MembraneQuantity>& qs) {
  if (a.deformed.empty()) return UsageError("--local needs --deformed FILE");
  GF_ASSIGN_OR_RETURN(const Mesh ref, ReadMesh(a.mesh));
  GF_ASSIGN_OR_RETURN(const Mesh def, ReadMesh(a.deformed));
  if (def.NumVertices() != ref.NumVertices() || def.faces != ref.faces)
    return absl::InvalidArgumentError(absl::StrCat(a.deformed, ": another topology than ", a.mesh, " (",
                                                   def.NumVertices(), " vertices, ", def.NumFaces(), " faces against ",
                                                   ref.NumVertices(), " and ", ref.NumFaces(), ", or other faces)"));
  GF_ASSIGN_OR_RETURN(const Topology topo, BuildTopology(ref));
  FitOptions fit;
  fit.degree = a.degree;
  GF_ASSIGN_OR_RETURN(MembraneFields f,
                      ComputeMembrane(ref, topo, def.positions, Material(a), fit, ProgressBar::Get().Context(a.threads)));
  Keep(qs, &f);
  PrintPressureSummary(f.pressure);
  return WriteFields(a.output, def, MembraneFieldsOf(f), "Pressure", a.ascii);
}

#ifdef GEOMFIT_WITH_CLIENT
absl::Status PressureRemote(const PressureArgs& a, const std::vector<v1::MembraneQuantity>& qs) {
  std::unique_ptr<Client> client = ConnectTo(a.server);
  v1::ComputeMembraneRequest r;
  r.set_young_modulus(a.young_modulus);
  r.set_poisson_ratio(a.poisson_ratio);
  r.mutable_options()->set_degree(a.degree);
  for (v1::MembraneQuantity q : qs) r.add_quantities(q);
  Mesh ref;
  GF_ASSIGN_OR_RETURN(const std::string id, RemoteMeshId(*client, a.mesh, false, &ref));
  r.set_mesh_id(id);
  r.set_revision(a.revision);
  // A file's positions go along: its id's latest revision may be a solve's result.
  if (ref.NumVertices() > 0)
    wire::EncodeDoubles(ref.positions.data(), ref.NumVertices(), 3, r.mutable_reference_positions());
  Mesh def;
  if (!a.deformed.empty() && std::filesystem::exists(a.deformed)) {
    GF_ASSIGN_OR_RETURN(def, ReadMesh(a.deformed));
    wire::EncodeDoubles(def.positions.data(), def.NumVertices(), 3, r.mutable_deformed_positions());
  } else {
    if (a.deformed.empty() && a.deformed_revision == 0)
      return UsageError("give --deformed FILE|MESH_ID or --deformed-revision N");
    r.mutable_deformed()->set_mesh_id(a.deformed);  // empty: the reference's mesh
    r.mutable_deformed()->set_revision(a.deformed_revision);
  }
  GF_ASSIGN_OR_RETURN(const RemoteMembrane m, client->ComputeMembrane(r));
  PrintPressureSummary(m.values.pressure);
  const bool vtk = !a.output.empty() && (absl::EndsWithIgnoreCase(a.output, ".vtp") ||
                                         absl::EndsWithIgnoreCase(a.output, ".vtu"));
  if (vtk && def.NumVertices() == 0) {  // the deformed surface from the server
    GF_ASSIGN_OR_RETURN(def, client->Download(a.deformed.empty() ? id : a.deformed));
  }
  return WriteFields(a.output, def, MembraneFieldsOf(m.values), "Pressure", a.ascii);
}
#endif

absl::Status RunPressure(const std::vector<std::string>& argv) {
  PressureArgs a;
  ArgParser p("geomfit membrane pressure", "REFERENCE (--server HOST:PORT | --local) --deformed MESH "
              "--young-modulus E --poisson-ratio NU [options]",
              "Stress, strain, principal stretches, von Mises stress and the interface pressure\n"
              "p = tr(W tau) (6.2.10; inside minus outside) of a deformed membrane against its\n"
              "reference (6.1-6.2). REFERENCE and --deformed: mesh files of the same topology, or\n"
              "with --server stored mesh ids (--deformed-revision: a revision of the reference's\n"
              "mesh or of --deformed). Output by extension on the deformed surface: .vtp/.vtu\n"
              "(point arrays Pressure, Stretches, Strain, Stress, VonMises, Traction), .tsv or\n"
              ".npy (one column per component); default a TSV table on stdout. A summary line\n"
              "goes to stderr.");
  p.Positional("REFERENCE", &a.mesh, "reference (unstressed) mesh file, or a stored mesh id with --server")
      .String("deformed", &a.deformed, "deformed mesh file (same topology) or stored mesh id", "MESH");
  AddCommon(&p, &a);
  p.Int("revision", &a.revision, "--server: revision of a stored REFERENCE (0 = latest)")
      .Int("deformed-revision", &a.deformed_revision, "--server: revision of the deformed mesh (0 = latest)")
      .String("quantities", &a.quantities, "comma-separated: pressure, stretches, strain, stress, von_mises, traction",
              "LIST")
      .String("output", &a.output, "output file (.vtp, .vtu, .tsv, .npy; - = stdout)", "FILE");
  GF_RETURN_IF_ERROR(p.Parse(argv));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  GF_RETURN_IF_ERROR(CheckCommon(a));
  GF_ASSIGN_OR_RETURN(const std::vector<v1::MembraneQuantity> qs, ParseQuantities(a.quantities));
  if (!a.output.empty() && a.output != "-") GF_RETURN_IF_ERROR(OutputKindFromPath(a.output).status());
  if (a.local) return PressureLocal(a, qs);
#ifdef GEOMFIT_WITH_CLIENT
  return PressureRemote(a, qs);
#else
  return UsageError(kNoClientMessage);
#endif
}

// ---- solve ---------------------------------------------------------------------

struct SolveArgs : MembraneArgs {
  std::string boundary, solver, pressure_file, name;
  double pressure = kNaN, tolerance = 1e-10;
  int max_iterations = 12, max_load_cuts = 6;
  bool new_mesh = false;
};

std::string IterationLine(int load_step, double load, int iteration, double residual, double step) {
  return absl::StrFormat("geomfit: load step %d (%.4g of the pressure) iteration %d: residual %.3e step %.3e",
                         load_step, load, iteration, residual, step);
}

/// --pressure or --pressure-file (one number per vertex, whitespace separated, '#' comments).
absl::StatusOr<Eigen::VectorXd> PressureOf(const SolveArgs& a) {
  if (a.pressure_file.empty()) return Eigen::VectorXd::Constant(1, a.pressure);
  GF_ASSIGN_OR_RETURN(const std::string text, ReadFileToString(a.pressure_file));
  std::vector<double> v;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    line = line.substr(0, line.find('#'));
    for (absl::string_view w : absl::StrSplit(line, absl::ByAnyChar(" \t\r,"), absl::SkipEmpty())) {
      double x;
      if (!absl::SimpleAtod(w, &x))
        return absl::InvalidArgumentError(absl::StrCat(a.pressure_file, ": '", w, "' is not a number"));
      v.push_back(x);
    }
  }
  return Eigen::Map<const Eigen::VectorXd>(v.data(), v.size());
}

absl::StatusOr<BoundaryCondition> BoundaryOf(const std::string& s) {
  if (s.empty()) return BoundaryCondition::kUnset;
  if (s == "clamped") return BoundaryCondition::kClamped;
  if (s == "free") return BoundaryCondition::kFree;
  return UsageError(absl::StrCat("--boundary ", s, ": expected clamped or free"));
}

absl::Status WriteDeformed(const SolveArgs& a, const Mesh& deformed, const Positions& displacement) {
  if (a.output.empty()) return absl::OkStatus();
  const bool vtk = absl::EndsWithIgnoreCase(a.output, ".vtp") || absl::EndsWithIgnoreCase(a.output, ".vtu");
  if (!vtk) return WriteMeshOutput(deformed, a.output);
  std::vector<PointField> fields;
  if (displacement.rows() == deformed.NumVertices()) fields.push_back({"Displacement", Eigen::MatrixXd(displacement)});
  return WriteFields(a.output, deformed, fields, "", a.ascii);
}

absl::Status SolveLocal(const SolveArgs& a) {
  GF_ASSIGN_OR_RETURN(const Mesh mesh, ReadMesh(a.mesh));
  GF_ASSIGN_OR_RETURN(const Topology topo, BuildTopology(mesh));
  PressureSolveOptions o;
  o.material = Material(a);
  o.fit.degree = a.degree;
  GF_ASSIGN_OR_RETURN(o.boundary, BoundaryOf(a.boundary));
  if (!a.solver.empty()) {
    if (absl::Status s = SetPressureSolver(a.solver, &o); !s.ok()) return UsageError(absl::StrCat("--", s.message()));
  }
  o.tolerance = a.tolerance;
  o.max_iterations = a.max_iterations;
  o.max_load_cuts = a.max_load_cuts;
  if (absl::Status s = ValidatePressureSolveOptions(o); !s.ok()) return UsageError(s.message());
  GF_ASSIGN_OR_RETURN(const Eigen::VectorXd pressure, PressureOf(a));
  GF_ASSIGN_OR_RETURN(const PressureSolution sol,
                      SolvePressureLoad(mesh, topo, pressure, o, RunContext(nullptr, a.threads),
                                        [](const NewtonIteration& it) {
                                          std::fprintf(stderr, "%s\n",
                                                       IterationLine(it.load_step, it.load, it.iteration,
                                                                     it.residual, it.step)
                                                           .c_str());
                                        }));
  std::fprintf(stderr, "geomfit: converged: residual %.3e after %zu iterations (%d factorizations), max displacement %.9g\n",
               sol.residual, sol.history.size(), sol.factorizations, sol.displacement.rowwise().norm().maxCoeff());
  Mesh deformed = mesh;
  deformed.positions = sol.deformed;
  return WriteDeformed(a, deformed, sol.displacement);
}

#ifdef GEOMFIT_WITH_CLIENT
absl::Status SolveRemote(const SolveArgs& a) {
  std::unique_ptr<Client> client = ConnectTo(a.server);
  Mesh unused;
  GF_ASSIGN_OR_RETURN(const std::string id, RemoteMeshId(*client, a.mesh, false, &unused));
  v1::MembraneSolveJob spec;
  spec.set_mesh_id(id);
  spec.set_young_modulus(a.young_modulus);
  spec.set_poisson_ratio(a.poisson_ratio);
  GF_ASSIGN_OR_RETURN(const Eigen::VectorXd pressure, PressureOf(a));
  if (a.pressure_file.empty()) {
    spec.set_pressure(a.pressure);
  } else {
    wire::EncodeDoubles(pressure.data(), pressure.size(), 0, spec.mutable_pressure_field());
  }
  if (a.boundary == "clamped") spec.set_boundary(v1::MEMBRANE_BOUNDARY_CLAMPED);
  if (a.boundary == "free") spec.set_boundary(v1::MEMBRANE_BOUNDARY_FREE);
  spec.mutable_fit()->set_degree(a.degree);
  spec.set_solver(a.solver);
  spec.set_tolerance(a.tolerance);
  spec.set_max_iterations(a.max_iterations);
  spec.set_max_load_cuts(a.max_load_cuts);
  spec.set_new_mesh(a.new_mesh);
  spec.set_name(a.name);
  spec.set_send_displacement(!a.output.empty());
  GF_ASSIGN_OR_RETURN(const v1::Job job, client->StartMembraneSolve(spec));
  std::fprintf(stderr, "geomfit: started membrane job %s on %s (geomfit jobs cancel --server %s %s)\n",
               job.job_id().c_str(), id.c_str(), a.server.c_str(), job.job_id().c_str());
  v1::JobEvent last;
  Positions displacement;
  GF_RETURN_IF_ERROR(client->WatchJob(job.job_id(), 0, [&](const v1::JobEvent& e) {
    last = e;
    const auto value = [&](const char* k) { return e.values().count(k) ? e.values().at(k) : 0.0; };
    const auto count = [&](const char* k) { return e.counts().count(k) ? e.counts().at(k) : int64_t{0}; };
    if (e.phase() == "newton") {
      std::fprintf(stderr, "%s\n",
                   IterationLine(static_cast<int>(count("load_step")), value("load"),
                                 static_cast<int>(count("iteration")), value("residual"), value("step"))
                       .c_str());
    } else if (e.phase() == "stored") {
      for (const v1::NamedArray& arr : e.arrays()) {
        if (arr.name() != "displacement") continue;
        absl::StatusOr<wire::RowsXd> d = wire::DecodeDoubles(arr.array(), "displacement", {3});
        if (d.ok()) displacement = *d;
      }
    } else if (e.final()) {
      std::fprintf(stderr, "geomfit: %s\n", FormatJobEvent(e).c_str());
    }
    return true;
  }));
  if (!last.final()) return absl::UnavailableError(absl::StrCat("job ", job.job_id(), ": the watch ended early"));
  if (last.state() != v1::JOB_STATE_SUCCEEDED)
    return absl::AbortedError(absl::StrCat("membrane job ", job.job_id(), ": ", last.message()));
  if (last.results_size() == 0) return absl::DataLossError("the job stored no result");
  if (a.output.empty()) return absl::OkStatus();
  GF_ASSIGN_OR_RETURN(const Mesh deformed, client->Download(last.results(0).mesh_id()));
  return WriteDeformed(a, deformed, displacement);
}
#endif

absl::Status RunSolve(const std::vector<std::string>& argv) {
  SolveArgs a;
  ArgParser p("geomfit membrane solve", "MESH (--server HOST:PORT | --local) --young-modulus E --poisson-ratio NU "
              "(--pressure P | --pressure-file F) [options] [--output deformed.vtp]",
              "The pressure-load problem (6.4.1): the equilibrium of the membrane MESH (its\n"
              "unstressed reference) under a pressure jump [p] (inside minus outside), by Newton\n"
              "with a sparse direct solve, the six rigid motions of a closed surface removed.\n"
              "Open surfaces need --boundary: clamped (boundary vertices fixed) or free\n"
              "(traction-free edges). With --server it runs as a job (MESH: a file, uploaded, or\n"
              "a mesh id) and stores the deformed surface as a new revision (--new-mesh: a new\n"
              "mesh); --local runs it in-process. One line per Newton iteration on stderr.\n"
              "--output: the deformed mesh (.vtp/.vtu with the point array Displacement, or any\n"
              "mesh format).");
  p.Positional("MESH", &a.mesh, "reference mesh file (or a stored mesh id with --server)");
  AddCommon(&p, &a);
  p.Double("pressure", &a.pressure, "constant pressure jump [p] (inside minus outside)")
      .String("pressure-file", &a.pressure_file, "one pressure value per vertex (text, numpy.savetxt)", "FILE")
      .String("boundary", &a.boundary, "open surfaces: clamped or free", "BC")
      .String("solver", &a.solver, "auto (UMFPACK), umfpack, sparselu, klu, bicgstab or gmres", "SOLVER")
      .Double("tolerance", &a.tolerance, "relative residual |F| / |[p] n| to reach")
      .Int("max-iterations", &a.max_iterations, "Newton iterations per load step")
      .Int("max-load-cuts", &a.max_load_cuts, "halvings of the load step before giving up")
      .Flag("new-mesh", &a.new_mesh, "--server: store the result as a new mesh, not a revision")
      .String("name", &a.name, "--server --new-mesh: name of the new mesh", "NAME")
      .String("output", &a.output, "write the deformed mesh here", "FILE");
  GF_RETURN_IF_ERROR(p.Parse(argv));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  GF_RETURN_IF_ERROR(CheckCommon(a));
  if (a.degree < 2) return UsageError("--degree: the solve needs second derivatives (2..6)");
  if (std::isnan(a.pressure) == a.pressure_file.empty())
    return UsageError("give exactly one of --pressure P and --pressure-file FILE");
  if (a.pressure_file.empty() && !std::isfinite(a.pressure)) return UsageError("--pressure must be finite");
  GF_RETURN_IF_ERROR(BoundaryOf(a.boundary).status());
  if (!a.output.empty() && a.output != "-" && !absl::EndsWithIgnoreCase(a.output, ".vtp") &&
      !absl::EndsWithIgnoreCase(a.output, ".vtu"))
    GF_RETURN_IF_ERROR(MeshOutputFormat(a.output).status());
  if (a.local) return SolveLocal(a);
#ifdef GEOMFIT_WITH_CLIENT
  return SolveRemote(a);
#else
  return UsageError(kNoClientMessage);
#endif
}

}  // namespace

absl::Status RunMembraneCommand(const std::vector<std::string>& argv) {
  const std::string usage =
      "usage: geomfit membrane pressure REFERENCE --deformed MESH (--server HOST:PORT | --local) ...\n"
      "       geomfit membrane solve MESH (--server HOST:PORT | --local) --pressure P ...\n"
      "Elastic membranes (chapter 6): `pressure` evaluates stress and interface pressure of a\n"
      "deformed membrane; `solve` finds the deformed shape under a pressure load.\n"
      "geomfit membrane pressure --help, geomfit membrane solve --help: every option.\n";
  if (argv.empty() || argv[0] == "--help" || argv[0] == "-h") {
    if (argv.empty()) return UsageError("geomfit membrane: give a subcommand (pressure or solve)");
    std::fputs(usage.c_str(), stdout);
    return absl::OkStatus();
  }
  const std::vector<std::string> rest(argv.begin() + 1, argv.end());
  if (argv[0] == "pressure") return RunPressure(rest);
  if (argv[0] == "solve") return RunSolve(rest);
  return UsageError(absl::StrCat("geomfit membrane: unknown subcommand '", argv[0], "' (pressure or solve)"));
}

}  // namespace geomfit::cli
