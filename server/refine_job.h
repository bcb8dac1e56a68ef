#pragma once
// The `refine` job: multi-level uniform refinement on the high-order surface, each
// level stored as a new mesh. An adapter over Handlers::RefineMesh, kept in this one
// place so it can move onto the Workspace later.
#include "absl/status/statusor.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/jobs/job_manager.h"

namespace geomfit::server {

class Handlers;

/// Checks `spec` (INVALID_ARGUMENT naming refine.<field>, NOT_FOUND for its mesh or
/// revision, RESOURCE_EXHAUSTED beyond --max-vertices) and returns the job's work. A
/// cancelled or failed run deletes the meshes it stored.
absl::StatusOr<JobRunFn> MakeRefineJob(Handlers* handlers, v1::RefineJob spec, int64_t max_vertices);

}  // namespace geomfit::server
