#pragma once
// The `flow` job: a geometric flow (core/flow) of a stored mesh, each step a job event
// and every k-th step's positions a new revision of the mesh. Runs on the Workspace
// like the refine job (it holds the snapshot it was started on) but fits with core
// directly: per-step fits through the shared cache would evict users' entries.
#include "absl/status/statusor.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/jobs/job_manager.h"

namespace geomfit::server {

class Workspace;

/// Checks `spec` (INVALID_ARGUMENT naming flow.<field>, NOT_FOUND for its mesh or
/// revision) and returns the job's work.
absl::StatusOr<JobRunFn> MakeFlowJob(Workspace* ws, v1::FlowJob spec);

}  // namespace geomfit::server
