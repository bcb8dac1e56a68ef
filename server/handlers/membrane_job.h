#pragma once
// Membranes (chapter 6) on the Workspace: the proto -> core translation shared by
// ComputeMembrane (membrane.cc) and the pressure-load solve job (membrane_job.cc).
#include <string>

#include "absl/status/statusor.h"
#include "core/fitting/options.h"
#include "core/mechanics/membrane.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/jobs/job_manager.h"

namespace geomfit::server {

class Workspace;

/// E and nu from the request; INVALID_ARGUMENT naming `<prefix>young_modulus` or
/// `<prefix>poisson_ratio` and the valid range.
absl::StatusOr<MembraneOptions> MembraneMaterialFromProto(double young_modulus, double poisson_ratio,
                                                          const std::string& prefix);
/// The reference fit (LHF): degree 4 when `given` is false, else `fit` (degree
/// min_degree..6; errors name `field`).
absl::StatusOr<FitOptions> MembraneFitFromProto(bool given, const v1::FitOptions& fit, int min_degree,
                                                const std::string& field);

/// Checks `spec` (INVALID_ARGUMENT naming membrane.<field>, NOT_FOUND for its mesh or
/// revision) and returns the job's work: the Newton solve, one event per iteration, the
/// deformed surface stored at the end (never after a failure or a cancel).
absl::StatusOr<JobRunFn> MakeMembraneJob(Workspace* ws, v1::MembraneSolveJob spec);

}  // namespace geomfit::server
