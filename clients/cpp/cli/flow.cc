// `geomfit flow MESH` (a geometric flow, §5.2-5.3: on a server as a job, or in-process
// with --local) and `geomfit operator MESH --server` (a GFD operator as Matrix Market).
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/ascii.h"
#include "absl/strings/str_format.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/interrupt.h"
#include "core/flow/flow.h"
#include "core/mesh/io.h"
#include "core/util/status_macros.h"

namespace geomfit::cli {
namespace {

/// A .pvd time series of .vtp snapshots (PREFIX_NNNNN.vtp, PREFIX.pvd): ParaView plays
/// it as an animation. The .pvd is rewritten after every snapshot, so a stopped run
/// leaves a readable series.
class SeriesWriter {
 public:
  SeriesWriter(std::string prefix, Mesh mesh) : prefix_(std::move(prefix)), mesh_(std::move(mesh)) {}

  absl::Status Add(int step, double t, const Positions& positions) {
    if (prefix_.empty()) return absl::OkStatus();
    mesh_.positions = positions;
    const std::string file = absl::StrFormat("%s_%05d.vtp", prefix_, step);
    GF_RETURN_IF_ERROR(WriteVtp(file, mesh_, {}));
    absl::StrAppendFormat(&entries_, "    <DataSet timestep=\"%.17g\" group=\"\" part=\"0\" file=\"%s\"/>\n", t,
                          std::filesystem::path(file).filename().string());
    return WriteFileAtomically(prefix_ + ".pvd",
                               absl::StrCat("<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" "
                                            "byte_order=\"LittleEndian\">\n  <Collection>\n",
                                            entries_, "  </Collection>\n</VTKFile>\n"));
  }

 private:
  const std::string prefix_;
  Mesh mesh_;
  std::string entries_;
};

struct FlowArgs {
  std::string mesh, server, kind = "mcf", scheme = "semi_implicit", solver, series;
  bool local = false;
  double dt = 1e-3, end_time = 0, max_area = 0, max_volume = 0;
  double time_tolerance = FlowOptions{}.time_tolerance;
  int steps = 0, degree = 4, every = 1, threads = 0;
};

std::string StepLine(int step, int total, double t, double area, double volume, double speed, int64_t iters) {
  return absl::StrFormat("geomfit: step %d/%d t=%.6g area=%.9g volume=%.9g max_speed=%.4g iterations=%d", step,
                         total, t, area, volume, speed, iters);
}

absl::Status RunLocal(const FlowArgs& a) {
  GF_ASSIGN_OR_RETURN(const Mesh mesh, ReadMesh(a.mesh));
  FlowOptions o;
  GF_ASSIGN_OR_RETURN(o.kind, ParseFlowKind(a.kind));
  GF_ASSIGN_OR_RETURN(o.scheme, ParseFlowScheme(a.scheme));
  if (!a.solver.empty()) {
    GF_ASSIGN_OR_RETURN(o.solver.kind, ParseSolverKind(a.solver));
  }
  o.dt = a.dt;
  o.steps = a.steps;
  o.end_time = a.end_time;
  o.fit.degree = a.degree;
  o.time_tolerance = a.time_tolerance;
  if (absl::Status s = ValidateFlowOptions(o); !s.ok()) return UsageError(s.message());
  const int total = o.steps > 0 ? o.steps : static_cast<int>(std::ceil(o.end_time / o.dt - 1e-9));
  SeriesWriter series(a.series, mesh);
  GF_RETURN_IF_ERROR(series.Add(0, 0, mesh.positions));
  const double area0 = MeshArea(mesh), volume0 = MeshVolume(mesh);
  FlowResult result;
  bool stopped = false;
  CancellationToken cancel;  // Ctrl-C
  const InterruptHandler interrupt([&] { cancel.Cancel(); });
  const absl::Status s = RunFlow(mesh, o, RunContext(&cancel, a.threads), &result,
                                 [&](const StepStats& st, const Mesh& m) -> absl::Status {
                                   std::fprintf(stderr, "%s\n",
                                                StepLine(st.step, total, st.t, st.area, st.volume, st.max_speed,
                                                         st.solver_iterations)
                                                    .c_str());
                                   stopped = (a.max_area > 0 && std::abs(st.area / area0 - 1) > a.max_area) ||
                                             (a.max_volume > 0 && std::abs(st.volume / volume0 - 1) > a.max_volume);
                                   if (st.step % a.every == 0 || st.step == total || stopped)
                                     GF_RETURN_IF_ERROR(series.Add(st.step, st.t, m.positions));
                                   return stopped ? absl::CancelledError("stop condition") : absl::OkStatus();
                                 });
  if (!s.ok() && !stopped) {
    if (cancel.IsCancelled())
      return absl::CancelledError(absl::StrFormat("flow cancelled after %zu steps%s", result.steps.size(),
                                                  a.series.empty() ? "" : absl::StrCat("; ", a.series, ".pvd holds them")));
    return s;
  }
  if (stopped) std::fprintf(stderr, "geomfit: stopped at a stop condition after %zu steps\n", result.steps.size());
  return absl::OkStatus();
}

#ifdef GEOMFIT_WITH_CLIENT
absl::Status RunRemote(const FlowArgs& a) {
  std::unique_ptr<Client> client = ConnectTo(a.server);
  Mesh mesh;
  GF_ASSIGN_OR_RETURN(const std::string id, RemoteMeshId(*client, a.mesh, false, &mesh));
  if (mesh.NumVertices() == 0 && !a.series.empty()) {
    GF_ASSIGN_OR_RETURN(mesh, client->Download(id));
  }
  v1::FlowJob spec;
  spec.set_mesh_id(id);
  spec.set_kind(a.kind);
  spec.set_scheme(a.scheme);
  spec.set_solver(a.solver);
  spec.set_dt(a.dt);
  spec.set_steps(a.steps);
  spec.set_end_time(a.end_time);
  spec.mutable_fit()->set_degree(a.degree);
  spec.set_snapshot_every(a.every);
  spec.set_max_area_change(a.max_area);
  spec.set_max_volume_change(a.max_volume);
  spec.set_send_positions(!a.series.empty());
  spec.set_time_tolerance(a.time_tolerance);
  GF_ASSIGN_OR_RETURN(const v1::Job job, client->StartFlow(spec));
  std::fprintf(stderr, "geomfit: started flow job %s on %s (geomfit jobs cancel --server %s %s)\n",
               job.job_id().c_str(), id.c_str(), a.server.c_str(), job.job_id().c_str());
  SeriesWriter series(a.series, mesh);
  if (!a.series.empty()) GF_RETURN_IF_ERROR(series.Add(0, 0, mesh.positions));
  absl::Status write = absl::OkStatus();
  v1::JobEvent last;
  GF_RETURN_IF_ERROR(WatchJobCancellingOnInterrupt(*client, job.job_id(), 0, [&](const v1::JobEvent& e) {
    if (e.phase() == "step") {
      const auto value = [&](const char* k) { return e.values().count(k) ? e.values().at(k) : 0.0; };
      const int64_t iters = e.counts().count("solver_iterations") ? e.counts().at("solver_iterations") : 0;
      std::fprintf(stderr, "%s\n",
                   StepLine(static_cast<int>(e.step()), static_cast<int>(e.total()), e.time(), value("area"),
                            value("volume"), value("max_speed"), iters)
                       .c_str());
    } else if (e.phase() == "snapshot" && !a.series.empty()) {
      for (const v1::NamedArray& arr : e.arrays()) {
        if (arr.name() != "positions") continue;
        const std::string& bytes = arr.array().data();
        Positions p(mesh.NumVertices(), 3);
        if (bytes.size() != sizeof(double) * p.size()) {
          write = absl::DataLossError(absl::StrCat("snapshot of step ", e.step(), ": ", bytes.size(), " bytes"));
          return false;
        }
        std::memcpy(p.data(), bytes.data(), bytes.size());
        write = series.Add(static_cast<int>(e.step()), e.time(), p);
        if (!write.ok()) return false;
      }
    } else if (e.final()) {
      std::fprintf(stderr, "geomfit: %s\n", FormatJobEvent(e).c_str());
    }
    return true;
  }, &last));
  if (!write.ok()) {
    client->CancelJob(job.job_id()).IgnoreError();
    return write;
  }
  return JobOutcome(last, "flow job");
}
#endif

}  // namespace

absl::Status RunFlowCommand(const std::vector<std::string>& argv) {
  FlowArgs a;
  ArgParser p("geomfit flow", "MESH (--server HOST:PORT | --local) [options] [--output-series PREFIX]",
              "A geometric flow of a closed surface (5.2-5.3): mean-curvature flow or surface\n"
              "diffusion, refitting every step. With --server it runs as a job (MESH: a file,\n"
              "uploaded, or a mesh id; snapshots become revisions of the mesh); --local runs it\n"
              "in-process. Progress lines go to stderr; --output-series writes PREFIX.pvd and\n"
              "PREFIX_NNNNN.vtp (a ParaView animation). Ctrl-C cancels the flow (the server's job,\n"
              "or the local run) and exits (130) once it stopped; the series keeps its steps.");
  p.Positional("MESH", &a.mesh, "mesh file (or a stored mesh id with --server)")
      .String("server", &a.server, "geomfit server", "HOST:PORT")
      .Flag("local", &a.local, "run in this process")
      .String("kind", &a.kind, "mcf or surface_diffusion", "KIND")
      .String("scheme", &a.scheme, "explicit, semi_implicit or bdf2", "SCHEME")
      .Double("dt", &a.dt, "time step")
      .Int("steps", &a.steps, "steps (0: until --end-time)")
      .Double("end-time", &a.end_time, "simulated end time when --steps is 0")
      .Int("degree", &a.degree, "fitting degree (1..6)")
      .String("solver", &a.solver, "auto, sparselu, umfpack, klu or bicgstab", "SOLVER")
      .Int("snapshot-every", &a.every, "store (and write) every k steps")
      .Double("max-area-change", &a.max_area, "stop once |A/A0 - 1| exceeds this (0: no limit)")
      .Double("max-volume-change", &a.max_volume, "stop once |V/V0 - 1| exceeds this (0: no limit)")
      .Double("time-tolerance", &a.time_tolerance,
              "iterative solves stop at this times the step's truncation error (0: always to 1e-12)")
      .Int("threads", &a.threads, "--local: threads (0 = all cores)")
      .String("output-series", &a.series, "write PREFIX.pvd and PREFIX_NNNNN.vtp", "PREFIX");
  GF_RETURN_IF_ERROR(p.Parse(argv));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  if (a.every < 1) return UsageError("--snapshot-every must be >= 1");
  if (a.steps < 0) return UsageError("--steps must not be negative");
  if (a.steps == 0 && !(a.end_time > 0)) return UsageError("give --steps or --end-time");
  if (!(std::isfinite(a.time_tolerance) && a.time_tolerance >= 0))
    return UsageError("--time-tolerance must be a finite value >= 0");
  if (a.local == !a.server.empty()) return UsageError("give exactly one of --server HOST:PORT and --local");
  if (a.local) return RunLocal(a);
#ifdef GEOMFIT_WITH_CLIENT
  return RunRemote(a);
#else
  return UsageError(kNoClientMessage);
#endif
}

absl::Status RunOperatorCommand(const std::vector<std::string>& argv) {
  std::string mesh, server, name = "laplace_beltrami", output;
  int degree = 4;
  ArgParser p("geomfit operator", "MESH --server HOST:PORT [--operator NAME] [--degree D] --output FILE.mtx",
              "A GFD surface operator (5.1) of the mesh's LHF fits as a sparse matrix in Matrix\n"
              "Market format (scipy.io.mmread reads it): gradient (3n x n), divergence\n"
              "(n x 3n), laplace_beltrami (n x n), hessian (9n x n), weingarten (3n x 3n).");
  p.Positional("MESH", &mesh, "mesh file (uploaded) or a stored mesh id")
      .String("server", &server, "geomfit server", "HOST:PORT")
      .String("operator", &name, "gradient, divergence, laplace_beltrami, hessian or weingarten", "NAME")
      .Int("degree", &degree, "fitting degree (1..6)")
      .String("output", &output, "Matrix Market file to write", "FILE");
  GF_RETURN_IF_ERROR(p.Parse(argv));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  if (server.empty()) return UsageError("geomfit operator needs --server HOST:PORT");
  if (output.empty()) return UsageError("geomfit operator needs --output FILE.mtx");
  v1::OperatorKind kind;
  if (!v1::OperatorKind_Parse(absl::StrCat("OPERATOR_", absl::AsciiStrToUpper(name)), &kind) ||
      kind == v1::OPERATOR_UNSPECIFIED)
    return UsageError(absl::StrCat("--operator ", name, ": expected gradient, divergence, laplace_beltrami, hessian "
                                   "or weingarten"));
#ifdef GEOMFIT_WITH_CLIENT
  std::unique_ptr<Client> client = ConnectTo(server);
  Mesh unused;
  GF_ASSIGN_OR_RETURN(const std::string id, RemoteMeshId(*client, mesh, false, &unused));
  v1::FitOptions fit;
  fit.set_degree(degree);
  GF_ASSIGN_OR_RETURN(const SparseMatrix m, client->GetOperator(id, kind, fit));
  std::string text = absl::StrFormat("%%%%MatrixMarket matrix coordinate real general\n%d %d %d\n", m.rows(), m.cols(),
                                     m.nonZeros());
  for (int r = 0; r < m.outerSize(); ++r)
    for (SparseMatrix::InnerIterator it(m, r); it; ++it)
      absl::StrAppendFormat(&text, "%d %d %.17g\n", r + 1, it.col() + 1, it.value());
  return WriteFileAtomically(output, text);
#else
  return UsageError(kNoClientMessage);
#endif
}

}  // namespace geomfit::cli
