#include "server/handlers/refine_job.h"

#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/reconstruction/meshing.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {
namespace {

constexpr int kMaxLevels = 8;

/// Deletes the meshes a job created (not ones that existed before it).
void Rollback(Workspace* ws, const std::vector<std::string>& created) {
  for (const std::string& id : created) ws->Delete(id).IgnoreError();
}

JobEvent LevelEvent(int level, int levels, const char* phase, std::string message) {
  JobEvent e;
  e.step = level;
  e.phase = phase;
  e.done = level - 1;
  e.total = levels;
  e.message = std::move(message);
  return e;
}

}  // namespace

absl::StatusOr<JobRunFn> MakeRefineJob(Workspace* ws, v1::RefineJob spec, int64_t max_vertices) {
  if (spec.mesh_id().empty()) return absl::InvalidArgumentError("refine.mesh_id: empty");
  GF_RETURN_IF_ERROR(CheckRange("refine.levels", spec.levels(), 1, kMaxLevels));
  const int factor = spec.factor() == 0 ? kMinRefineFactor : spec.factor();
  if (factor != 2 && factor != 3)
    return absl::InvalidArgumentError(absl::StrCat("refine.factor = ", factor, ": expected 2 or 3"));
  if (spec.revision() < 0) return absl::InvalidArgumentError("refine.revision must not be negative");
  absl::StatusOr<ReconstructionOptions> options = wire::FromProto(spec.options());
  if (!options.ok()) return absl::InvalidArgumentError(absl::StrCat("refine.options.", options.status().message()));
  // The job holds the revision current now to its end (later updates do not affect it).
  GF_ASSIGN_OR_RETURN(Snapshot input, ws->Acquire(spec.mesh_id(), spec.revision()));
  GF_ASSIGN_OR_RETURN(const MeshRecord info, ws->Info(spec.mesh_id()));
  double faces = static_cast<double>(input.mesh->NumFaces());
  for (int k = 0; k < spec.levels(); ++k) faces *= factor * factor;
  if (faces > static_cast<double>(max_vertices))
    return absl::ResourceExhaustedError(absl::StrCat("refine: ", spec.levels(), " levels of factor ", factor, " make ",
                                                     faces, " faces, above --max-vertices (", max_vertices, ")"));
  const std::string base = spec.name().empty() ? absl::StrCat(info.name, " refined x", factor) : spec.name();
  const int levels = spec.levels();

  return [ws, input = std::move(input), ro = *std::move(options), factor, levels, base](
             const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
    JobResult result;
    std::vector<std::string> created;
    auto fail = [&](absl::Status s) {
      Rollback(ws, created);
      return ctx.cancelled() ? ctx.Check() : s;
    };
    Snapshot current = input;
    for (int level = 1; level <= levels; ++level) {
      if (absl::Status s = ctx.Check(); !s.ok()) return fail(s);
      events->Emit(LevelEvent(level, levels, "refine", absl::StrCat("level ", level, ": refining ", current.mesh_id)));
      const Stopwatch watch;
      absl::StatusOr<std::unique_ptr<Reconstructed>> surface = ws->Reconstruct(current, ro, false, ctx);
      if (!surface.ok()) return fail(surface.status());
      absl::StatusOr<Mesh> refined = RefineMesh(*(*surface)->surface, *current.topology, factor, ctx);
      if (!refined.ok()) return fail(refined.status());
      if (absl::Status s = ctx.Check(); !s.ok()) return fail(s);  // a cancelled level stores nothing
      MeshMeta meta;
      meta.name = absl::StrCat(base, " L", level);
      meta.tenant = TenantOfId(current.mesh_id);  // a derived mesh is its source's tenant's
      meta.labels["refined_from"] = current.mesh_id.substr(TenantPrefix(meta.tenant).size());
      const int64_t started = NowUnixMs();
      absl::StatusOr<MeshRecord> stored = ws->AddMesh(*std::move(refined), meta);
      if (!stored.ok()) return fail(stored.status());
      if (stored->created_unix_ms >= started) created.push_back(stored->mesh_id);
      result.results.push_back({stored->mesh_id, stored->revision});
      JobEvent done = LevelEvent(level, levels, "stored", absl::StrCat("level ", level, ": stored ", stored->mesh_id));
      done.done = level;
      done.counts["vertices"] = stored->num_vertices;
      done.counts["faces"] = stored->num_faces;
      done.values["seconds"] = watch.Seconds();
      done.results.push_back(result.results.back());
      events->Emit(std::move(done));
      result.counts["vertices"] = stored->num_vertices;
      result.counts["faces"] = stored->num_faces;
      absl::StatusOr<Snapshot> next = ws->Acquire(stored->mesh_id, stored->revision);
      if (!next.ok()) return fail(next.status());
      current = *std::move(next);
    }
    result.message = absl::StrCat("refined ", levels, " levels; finest ", current.mesh_id);
    return result;
  };
}

}  // namespace geomfit::server
