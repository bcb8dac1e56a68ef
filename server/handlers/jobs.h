#pragma once
// Jobs RPCs: proto <-> JobManager. No gRPC types (service.cc adapts them).
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/jobs/job_manager.h"

namespace geomfit::server {

class Handlers;

class JobHandlers {
 public:
  /// `handlers` runs the jobs' work; `max_vertices` bounds what a job may create.
  JobHandlers(JobManager* jobs, Handlers* handlers, int64_t max_vertices)
      : jobs_(jobs), handlers_(handlers), max_vertices_(max_vertices) {}

  absl::StatusOr<v1::Job> StartJob(const v1::StartJobRequest& request);
  absl::StatusOr<v1::Job> GetJob(const v1::GetJobRequest& request);
  absl::StatusOr<v1::Job> CancelJob(const v1::CancelJobRequest& request);
  absl::StatusOr<v1::ListJobsResponse> ListJobs(const v1::ListJobsRequest& request);
  /// WatchJob's reads: up to `max` events with seq >= from (see JobManager::Read for
  /// `on_more` and `subscription`); *end once the final event is among them.
  absl::StatusOr<std::vector<v1::JobEvent>> ReadEvents(const std::string& job_id, int64_t from, int max, bool* end,
                                                       std::function<void()> on_more = nullptr,
                                                       uint64_t* subscription = nullptr);
  JobManager* manager() { return jobs_; }
  /// StartJob with a flow spec.
  absl::StatusOr<v1::Job> StartFlow(const v1::FlowJob& spec);
  /// StartJob with a membrane (pressure-load solve) spec.
  absl::StatusOr<v1::Job> StartMembraneSolve(const v1::MembraneSolveJob& spec);

 private:
  JobManager* jobs_;
  Handlers* handlers_;
  const int64_t max_vertices_;
};

/// Conversions (also for tests).
v1::JobEvent ToProto(const JobEvent& event, const std::string& job_id);
v1::Job ToProto(const JobStatus& status);

}  // namespace geomfit::server
