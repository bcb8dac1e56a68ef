#include "server/handlers/flow_job.h"

#include <cmath>
#include <optional>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/flow/flow.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {
namespace {

/// A parse error of core ("kind: unknown ...") as flow.<its field>.
absl::Status Invalid(const absl::Status& s) { return absl::InvalidArgumentError(absl::StrCat("flow.", s.message())); }

/// A relative-change limit or a tolerance factor: finite and >= 0 (0: none).
absl::Status CheckLimit(const char* field, double v) {
  if (std::isfinite(v) && v >= 0) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrFormat("flow.%s = %g: expected a finite value >= 0", field, v));
}

absl::StatusOr<FlowOptions> FlowOptionsFromProto(const v1::FlowJob& spec) {
  FlowOptions o;
  if (!spec.kind().empty()) {
    absl::StatusOr<FlowKind> kind = ParseFlowKind(spec.kind());
    if (!kind.ok()) return Invalid(kind.status());
    o.kind = *kind;
  }
  if (!spec.scheme().empty()) {
    absl::StatusOr<FlowScheme> scheme = ParseFlowScheme(spec.scheme());
    if (!scheme.ok()) return Invalid(scheme.status());
    o.scheme = *scheme;
  }
  if (!spec.solver().empty()) {
    absl::StatusOr<SolverKind> solver = ParseSolverKind(spec.solver());
    if (!solver.ok()) return Invalid(solver.status());
    if (!SolverAvailable(*solver))
      return absl::InvalidArgumentError(absl::StrCat("flow.solver: ", spec.solver(), " is not in this build"));
    o.solver.kind = *solver;
  }
  if (!(std::isfinite(spec.dt()) && spec.dt() > 0))
    return absl::InvalidArgumentError(absl::StrFormat("flow.dt = %g: must be > 0", spec.dt()));
  o.dt = spec.dt();
  if (spec.steps() < 0) return absl::InvalidArgumentError(absl::StrCat("flow.steps = ", spec.steps(), ": must be >= 0"));
  if (!(std::isfinite(spec.end_time()) && spec.end_time() >= 0))
    return absl::InvalidArgumentError(absl::StrFormat("flow.end_time = %g: must be >= 0", spec.end_time()));
  if (spec.steps() == 0 && spec.end_time() == 0)
    return absl::InvalidArgumentError("flow.steps: 0 steps and no end_time: nothing to run");
  o.steps = spec.steps();
  o.end_time = spec.end_time();
  if (spec.has_fit()) {
    // The flow's own default (degree 4) only when no fit is given: a given degree 0 is a mistake.
    if (spec.fit().degree() == 0) return absl::InvalidArgumentError("flow.fit.degree = 0: expected 1..6");
    absl::StatusOr<FitOptions> fit = wire::FromProto(spec.fit(), o.fit);
    if (!fit.ok()) return absl::InvalidArgumentError(absl::StrCat("flow.fit: ", fit.status().message()));
    o.fit = *fit;
  }
  if (spec.snapshot_every() < 0)
    return absl::InvalidArgumentError(absl::StrCat("flow.snapshot_every = ", spec.snapshot_every(), ": must be >= 0"));
  GF_RETURN_IF_ERROR(CheckLimit("max_area_change", spec.max_area_change()));
  GF_RETURN_IF_ERROR(CheckLimit("max_volume_change", spec.max_volume_change()));
  if (spec.has_time_tolerance()) {  // unset: the core default
    GF_RETURN_IF_ERROR(CheckLimit("time_tolerance", spec.time_tolerance()));
    o.time_tolerance = spec.time_tolerance();
  }
  if (absl::Status s = ValidateFlowOptions(o); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("flow.", s.message()));
  return o;
}

JobArray PositionsArray(const Positions& p) {
  JobArray a;
  a.name = "positions";
  a.shape = {p.rows(), 3};
  a.data.assign(p.data(), p.data() + p.size());
  return a;
}

}  // namespace

absl::StatusOr<JobRunFn> MakeFlowJob(Workspace* ws, v1::FlowJob spec) {
  if (spec.mesh_id().empty()) return absl::InvalidArgumentError("flow.mesh_id: empty");
  if (spec.revision() < 0) return absl::InvalidArgumentError("flow.revision must not be negative");
  GF_ASSIGN_OR_RETURN(const FlowOptions options, FlowOptionsFromProto(spec));
  GF_ASSIGN_OR_RETURN(Snapshot input, ws->Acquire(spec.mesh_id(), spec.revision()));
  if (input.topology->num_boundary_edges > 0)
    return absl::InvalidArgumentError(absl::StrCat("flow.mesh_id: ", spec.mesh_id(), " is an open surface (",
                                                   input.topology->num_boundary_edges,
                                                   " boundary edges); flows need a closed surface"));
  const int total = options.steps > 0 ? options.steps
                                      : static_cast<int>(std::ceil(options.end_time / options.dt - 1e-9));

  return [ws, input = std::move(input), options, total, every = spec.snapshot_every(),
          max_area = spec.max_area_change(), max_volume = spec.max_volume_change(),
          send_positions = spec.send_positions()](const RunContext& ctx,
                                                  JobEvents* events) -> absl::StatusOr<JobResult> {
    const double area0 = MeshArea(*input.mesh), volume0 = MeshVolume(*input.mesh);
    JobResult result;
    int64_t revision = input.revision;  // the latest revision this job stored (or started on)
    int stored_step = 0;
    std::string stop_reason;
    // Stores `mesh` as the next revision; expected_revision chains the job's own
    // revisions, so a concurrent update by someone else fails the job (ABORTED).
    auto store = [&](const StepStats& st, const Mesh& mesh) -> absl::Status {
      absl::StatusOr<MeshRecord> rec = ws->UpdatePositions(input.mesh_id, revision, mesh.positions);
      if (!rec.ok())
        return absl::Status(rec.status().code(), absl::StrCat("step ", st.step, ": storing the snapshot: ",
                                                              rec.status().message()));
      revision = rec->revision;
      stored_step = st.step;
      JobEvent e;
      e.step = st.step;
      e.time = st.t;
      e.phase = "snapshot";
      e.done = st.step;
      e.total = total;
      e.message = absl::StrCat("step ", st.step, ": stored revision ", revision, " of ", input.mesh_id);
      e.results.push_back({input.mesh_id, revision});
      if (send_positions) e.arrays.push_back(PositionsArray(mesh.positions));
      events->Emit(std::move(e));
      result.results = {{input.mesh_id, revision}};
      return absl::OkStatus();
    };
    Stopwatch step_watch;
    auto on_step = [&](const StepStats& st, const Mesh& mesh) -> absl::Status {
      JobEvent e;
      e.step = st.step;
      e.time = st.t;
      e.phase = "step";
      e.done = st.step;
      e.total = total;
      e.values = {{"t", st.t},
                  {"area", st.area},
                  {"volume", st.volume},
                  {"max_speed", st.max_speed},
                  {"fit_ms", st.fit_ms},
                  {"assemble_ms", st.assemble_ms},
                  {"solve_ms", st.solve_ms},
                  {"step_ms", step_watch.Millis()}};
      e.counts = {{"solver_iterations", st.solver_iterations}};
      events->Emit(std::move(e));
      step_watch = Stopwatch();
      const double da = std::abs(st.area / area0 - 1), dv = std::abs(st.volume / volume0 - 1);
      if (max_area > 0 && da > max_area)
        stop_reason = absl::StrFormat("relative area change %.3g above max_area_change %g", da, max_area);
      else if (max_volume > 0 && dv > max_volume)
        stop_reason = absl::StrFormat("relative volume change %.3g above max_volume_change %g", dv, max_volume);
      const bool last = st.step == total || !stop_reason.empty();
      if ((every > 0 && st.step % every == 0) || last) GF_RETURN_IF_ERROR(store(st, mesh));
      // A stop condition ends the run here (RunFlow stops on a non-OK status).
      return stop_reason.empty() ? absl::OkStatus() : absl::CancelledError("stop condition");
    };
    FlowResult run;
    const absl::Status s = RunFlow(*input.mesh, options, ctx, &run, on_step);
    if (!s.ok() && stop_reason.empty()) {
      if (ctx.cancelled()) return ctx.Check();
      return absl::Status(s.code(), absl::StrCat(s.message(), "; last good snapshot: revision ", revision, " of ",
                                                 input.mesh_id, " (step ", stored_step, ")"));
    }
    const StepStats last = run.steps.empty() ? StepStats() : run.steps.back();
    result.values = {{"t", last.t}, {"area", last.area}, {"volume", last.volume}};
    result.counts = {{"steps", static_cast<int64_t>(run.steps.size())}, {"revision", revision}};
    result.message = stop_reason.empty()
                         ? absl::StrCat(FlowKindName(options.kind), " flow: ", run.steps.size(),
                                        " steps; final revision ", revision)
                         : absl::StrCat("stopped at step ", last.step, ": ", stop_reason, "; final revision ",
                                        revision);
    return result;
  };
}

}  // namespace geomfit::server
