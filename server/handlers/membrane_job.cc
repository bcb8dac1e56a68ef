#include "server/handlers/membrane_job.h"

#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mechanics/pressure_solve.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {

absl::StatusOr<MembraneOptions> MembraneMaterialFromProto(double young_modulus, double poisson_ratio,
                                                          const std::string& prefix) {
  MembraneOptions m;
  m.E = young_modulus;
  m.nu = poisson_ratio;
  if (!(std::isfinite(m.E) && m.E > 0))
    return absl::InvalidArgumentError(
        absl::StrFormat("%syoung_modulus = %g: Young's modulus E must be finite and > 0 (required)", prefix, m.E));
  if (!(m.nu > -1 && m.nu < 0.5))
    return absl::InvalidArgumentError(
        absl::StrFormat("%spoisson_ratio = %g: the Poisson ratio nu must lie in (-1, 0.5) (required)", prefix, m.nu));
  return m;
}

absl::StatusOr<FitOptions> MembraneFitFromProto(bool given, const v1::FitOptions& fit, int min_degree,
                                                const std::string& field) {
  FitOptions o;
  o.degree = 4;
  if (!given) return o;
  if (fit.degree() < min_degree || fit.degree() > 6)
    return absl::InvalidArgumentError(
        absl::StrCat(field, ".degree = ", fit.degree(), ": expected ", min_degree, "..6 (unset options: 4)"));
  absl::StatusOr<FitOptions> parsed = wire::FromProto(fit, o);
  if (!parsed.ok()) return absl::InvalidArgumentError(absl::StrCat(field, ": ", parsed.status().message()));
  if (parsed->method != FitMethod::kLHF)
    return absl::InvalidArgumentError(absl::StrCat(field, ".method: membranes need LHF fits (height functions)"));
  return *parsed;
}

namespace {

absl::StatusOr<BoundaryCondition> BoundaryFromProto(v1::MembraneBoundary b) {
  switch (b) {
    case v1::MEMBRANE_BOUNDARY_UNSPECIFIED: return BoundaryCondition::kUnset;
    case v1::MEMBRANE_BOUNDARY_CLAMPED: return BoundaryCondition::kClamped;
    case v1::MEMBRANE_BOUNDARY_FREE: return BoundaryCondition::kFree;
    default: return absl::InvalidArgumentError(absl::StrCat("membrane.boundary: unknown value ", b, " (clamped, free)"));
  }
}

absl::StatusOr<PressureSolveOptions> SolveOptionsFromProto(const v1::MembraneSolveJob& spec) {
  PressureSolveOptions o;
  GF_ASSIGN_OR_RETURN(o.material, MembraneMaterialFromProto(spec.young_modulus(), spec.poisson_ratio(), "membrane."));
  GF_ASSIGN_OR_RETURN(o.fit, MembraneFitFromProto(spec.has_fit(), spec.fit(), 2, "membrane.fit"));
  GF_ASSIGN_OR_RETURN(o.boundary, BoundaryFromProto(spec.boundary()));
  if (!spec.solver().empty()) {
    if (absl::Status s = SetPressureSolver(spec.solver(), &o); !s.ok())
      return absl::InvalidArgumentError(absl::StrCat("membrane.", s.message()));
  }
  if (spec.tolerance() != 0) {
    if (!(spec.tolerance() > 0 && spec.tolerance() < 1))
      return absl::InvalidArgumentError(
          absl::StrFormat("membrane.tolerance = %g: expected a value in (0, 1) (0: 1e-10)", spec.tolerance()));
    o.tolerance = spec.tolerance();
  }
  if (spec.max_iterations() < 0)
    return absl::InvalidArgumentError(
        absl::StrCat("membrane.max_iterations = ", spec.max_iterations(), ": must be >= 0 (0: 12)"));
  if (spec.max_iterations() > 0) o.max_iterations = spec.max_iterations();
  if (spec.has_max_load_cuts()) {
    if (spec.max_load_cuts() < 0 || spec.max_load_cuts() > 30)
      return absl::InvalidArgumentError(
          absl::StrCat("membrane.max_load_cuts = ", spec.max_load_cuts(), ": expected 0..30"));
    o.max_load_cuts = spec.max_load_cuts();
  }
  if (absl::Status s = ValidatePressureSolveOptions(o); !s.ok())
    return absl::InvalidArgumentError(absl::StrCat("membrane.", s.message()));
  return o;
}

/// The pressure: one constant or one value per vertex, finite.
absl::StatusOr<Eigen::VectorXd> PressureFromProto(const v1::MembraneSolveJob& spec, int num_vertices) {
  const bool field = spec.pressure_field().shape_size() > 0 || !spec.pressure_field().data().empty();
  if (spec.has_pressure() == field)
    return absl::InvalidArgumentError("membrane.pressure: give exactly one of pressure and pressure_field");
  Eigen::VectorXd p;
  if (spec.has_pressure()) {
    p = Eigen::VectorXd::Constant(1, spec.pressure());
  } else {
    GF_ASSIGN_OR_RETURN(const wire::RowsXd f, wire::DecodeDoubles(spec.pressure_field(), "membrane.pressure_field", {0}));
    if (f.size() != num_vertices)
      return absl::InvalidArgumentError(absl::StrCat("membrane.pressure_field: ", f.size(), " values for ",
                                                     num_vertices, " vertices"));
    p = Eigen::Map<const Eigen::VectorXd>(f.data(), f.size());
  }
  for (Eigen::Index i = 0; i < p.size(); ++i)
    if (!std::isfinite(p(i)))
      return absl::InvalidArgumentError(
          spec.has_pressure() ? absl::StrFormat("membrane.pressure = %g: must be finite", p(i))
                              : absl::StrCat("membrane.pressure_field: value ", i, " is not finite"));
  return p;
}

}  // namespace

absl::StatusOr<JobRunFn> MakeMembraneJob(Workspace* ws, v1::MembraneSolveJob spec) {
  if (spec.mesh_id().empty()) return absl::InvalidArgumentError("membrane.mesh_id: empty");
  if (spec.revision() < 0) return absl::InvalidArgumentError("membrane.revision must not be negative");
  GF_ASSIGN_OR_RETURN(const PressureSolveOptions options, SolveOptionsFromProto(spec));
  if (spec.has_pressure() && !std::isfinite(spec.pressure()))  // before the mesh is read
    return absl::InvalidArgumentError(absl::StrFormat("membrane.pressure = %g: must be finite", spec.pressure()));
  GF_ASSIGN_OR_RETURN(Snapshot input, ws->Acquire(spec.mesh_id(), spec.revision()));
  GF_ASSIGN_OR_RETURN(Eigen::VectorXd pressure, PressureFromProto(spec, input.mesh->NumVertices()));
  if (input.topology->num_boundary_edges > 0 && options.boundary == BoundaryCondition::kUnset)
    return absl::InvalidArgumentError(absl::StrCat("membrane.boundary: ", spec.mesh_id(), " is an open surface (",
                                                   input.topology->num_boundary_edges,
                                                   " boundary edges); set clamped or free"));
  std::string name;
  if (spec.new_mesh()) {
    GF_ASSIGN_OR_RETURN(const MeshRecord info, ws->Info(spec.mesh_id()));
    name = spec.name().empty() ? absl::StrCat(info.name, " deformed") : spec.name();
  }

  return [ws, input = std::move(input), options, pressure = std::move(pressure), name,
          new_mesh = spec.new_mesh(), send = spec.send_displacement()](
             const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
    int64_t seq = 0;
    auto on_iteration = [&](const NewtonIteration& it) {
      JobEvent e;
      e.step = ++seq;
      e.phase = "newton";
      e.values = {{"residual", it.residual}, {"step", it.step}, {"load", it.load}};
      e.counts = {{"load_step", it.load_step}, {"iteration", it.iteration}, {"krylov_iterations", it.krylov_iterations}};
      e.message = absl::StrFormat("load %.4g, iteration %d: residual %.3e, step %.3e", it.load, it.iteration,
                                  it.residual, it.step);
      events->Emit(std::move(e));
    };
    const Stopwatch watch;
    absl::StatusOr<PressureSolution> solved =
        SolvePressureLoad(*input.mesh, *input.topology, pressure, options, ctx, on_iteration);
    if (!solved.ok()) return ctx.cancelled() ? ctx.Check() : solved.status();
    GF_RETURN_IF_ERROR(ctx.Check());  // a cancel after the last iteration stores nothing
    absl::StatusOr<MeshRecord> stored;
    if (new_mesh) {
      Mesh deformed;
      deformed.positions = solved->deformed;
      deformed.faces = input.mesh->faces;
      MeshMeta meta;
      meta.name = name;
      meta.tenant = TenantOfId(input.mesh_id);  // a derived mesh is its source's tenant's
      meta.labels["deformed_from"] = input.mesh_id.substr(TenantPrefix(meta.tenant).size());
      stored = ws->AddMesh(std::move(deformed), meta);
    } else {
      stored = ws->UpdatePositions(input.mesh_id, input.revision, solved->deformed);
    }
    if (!stored.ok())
      return absl::Status(stored.status().code(),
                          absl::StrCat("storing the deformed surface: ", stored.status().message()));
    const JobResultMesh mesh{stored->mesh_id, stored->revision};
    JobEvent e;
    e.step = seq;
    e.phase = "stored";
    e.message = absl::StrCat("stored revision ", stored->revision, " of ", stored->mesh_id);
    e.results.push_back(mesh);
    if (send) {
      JobArray a;
      a.name = "displacement";
      a.shape = {solved->displacement.rows(), 3};
      a.data.assign(solved->displacement.data(), solved->displacement.data() + solved->displacement.size());
      e.arrays.push_back(std::move(a));
    }
    events->Emit(std::move(e));
    JobResult result;
    result.results = {mesh};
    result.values = {{"residual", solved->residual},
                     {"max_displacement", solved->displacement.rowwise().norm().maxCoeff()},
                     {"fit_ms", solved->fit_ms},
                     {"assemble_ms", solved->assemble_ms},
                     {"factorize_ms", solved->factorize_ms},
                     {"solve_ms", solved->solve_ms},
                     {"seconds", watch.Seconds()}};
    result.counts = {{"iterations", static_cast<int64_t>(solved->history.size())},
                     {"factorizations", solved->factorizations},
                     {"krylov_iterations", solved->krylov_iterations},
                     {"load_steps", solved->load_steps},
                     {"revision", stored->revision}};
    result.message = absl::StrFormat("converged in %d Newton iterations (residual %.2e); stored revision %d of %s",
                                     static_cast<int>(solved->history.size()), solved->residual, stored->revision,
                                     stored->mesh_id);
    return result;
  };
}

}  // namespace geomfit::server
