#pragma once
// The `refine` job: multi-level uniform refinement on the high-order surface, each
// level stored as a new mesh. Runs on the Workspace: the job holds the snapshot it was
// started on, and progress of each level's fit and refinement becomes job events.
#include "absl/status/statusor.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/jobs/job_manager.h"

namespace geomfit::server {

class Workspace;

/// Checks `spec` (INVALID_ARGUMENT naming refine.<field>, NOT_FOUND for its mesh or
/// revision, RESOURCE_EXHAUSTED beyond --max-vertices) and returns the job's work. A
/// cancelled or failed run deletes the meshes it stored.
absl::StatusOr<JobRunFn> MakeRefineJob(Workspace* ws, v1::RefineJob spec, int64_t max_vertices);

}  // namespace geomfit::server
