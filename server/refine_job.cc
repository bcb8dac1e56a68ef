#include "server/refine_job.h"

#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/handlers.h"

namespace geomfit::server {
namespace {

constexpr int kMaxLevels = 8;

/// Deletes the meshes a job created (not ones that existed before it).
void Rollback(Handlers* handlers, const std::vector<std::string>& created) {
  for (const std::string& id : created) {
    v1::DeleteMeshRequest request;
    request.set_mesh_id(id);
    handlers->DeleteMesh(request).status().IgnoreError();
  }
}

}  // namespace

absl::StatusOr<JobRunFn> MakeRefineJob(Handlers* handlers, v1::RefineJob spec, int64_t max_vertices) {
  if (spec.mesh_id().empty()) return absl::InvalidArgumentError("refine.mesh_id: empty");
  if (spec.levels() < 1 || spec.levels() > kMaxLevels)
    return absl::InvalidArgumentError(
        absl::StrCat("refine.levels = ", spec.levels(), " is out of range [1, ", kMaxLevels, "]"));
  if (spec.factor() == 0) spec.set_factor(2);
  if (spec.factor() != 2 && spec.factor() != 3)
    return absl::InvalidArgumentError(absl::StrCat("refine.factor = ", spec.factor(), ": expected 2 or 3"));
  if (spec.revision() < 0) return absl::InvalidArgumentError("refine.revision must not be negative");
  if (absl::StatusOr<FitOptions> fit = wire::FromProto(spec.options().fit()); !fit.ok())
    return absl::InvalidArgumentError(absl::StrCat("refine.options.fit: ", fit.status().message()));
  v1::GetMeshRequest get;
  get.set_mesh_id(spec.mesh_id());
  GF_ASSIGN_OR_RETURN(const v1::MeshInfo info, handlers->GetMesh(get));
  if (spec.revision() != 0 && spec.revision() != info.revision())
    return absl::NotFoundError(absl::StrCat("refine.revision ", spec.revision(), ": mesh '", spec.mesh_id(),
                                            "' is at revision ", info.revision(), " (only the latest is kept)"));
  spec.set_revision(info.revision());  // the job refines what is current now
  double faces = static_cast<double>(info.num_faces());
  for (int k = 0; k < spec.levels(); ++k) faces *= spec.factor() * spec.factor();
  if (faces > static_cast<double>(max_vertices))
    return absl::ResourceExhaustedError(absl::StrCat("refine: ", spec.levels(), " levels of factor ", spec.factor(),
                                                     " make ", faces, " faces, above --max-vertices (",
                                                     max_vertices, ")"));
  const std::string base = spec.name().empty() ? absl::StrCat(info.name(), " refined x", spec.factor()) : spec.name();

  return [handlers, spec, base](const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
    static const CancellationToken kNever;
    const CancellationToken& cancel = ctx.token() ? *ctx.token() : kNever;
    JobResult result;
    std::vector<std::string> created;
    auto fail = [&](absl::Status s) {
      Rollback(handlers, created);
      return ctx.cancelled() ? ctx.Check() : s;
    };
    v1::RefineMeshRequest request;
    request.set_mesh_id(spec.mesh_id());
    request.set_revision(spec.revision());
    *request.mutable_options() = spec.options();
    request.set_factor(spec.factor());
    for (int level = 1; level <= spec.levels(); ++level) {
      if (absl::Status s = ctx.Check(); !s.ok()) return fail(s);
      JobEvent begin;
      begin.step = level;
      begin.phase = "refine";
      begin.done = level - 1;
      begin.total = spec.levels();
      begin.message = absl::StrCat("level ", level, ": refining ", request.mesh_id());
      events->Emit(std::move(begin));
      request.set_name(absl::StrCat(base, " L", level));
      const Stopwatch watch;
      const int64_t started = NowUnixMs();
      absl::StatusOr<v1::MeshInfo> refined = handlers->RefineMesh(request, cancel);
      if (!refined.ok()) return fail(refined.status());
      if (refined->created_unix_ms() >= started) created.push_back(refined->mesh_id());
      result.results.push_back({refined->mesh_id(), refined->revision()});
      JobEvent stored;
      stored.step = level;
      stored.phase = "stored";
      stored.done = level;
      stored.total = spec.levels();
      stored.counts["vertices"] = refined->num_vertices();
      stored.counts["faces"] = refined->num_faces();
      stored.values["seconds"] = watch.Seconds();
      stored.results.push_back(result.results.back());
      stored.message = absl::StrCat("level ", level, ": stored ", refined->mesh_id());
      events->Emit(std::move(stored));
      result.counts["vertices"] = refined->num_vertices();
      result.counts["faces"] = refined->num_faces();
      request.set_mesh_id(refined->mesh_id());
      request.set_revision(refined->revision());
    }
    if (absl::Status s = ctx.Check(); !s.ok()) return fail(s);
    result.message = absl::StrCat("refined ", spec.levels(), " levels; finest ", request.mesh_id());
    return result;
  };
}

}  // namespace geomfit::server
