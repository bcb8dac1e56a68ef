#include "server/handlers/jobs.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"
#include "server/handlers/flow_job.h"
#include "server/handlers/membrane_job.h"
#include "server/handlers/refine_job.h"

namespace geomfit::server {
namespace {

absl::Status RequireJobId(const std::string& id) {
  return id.empty() ? absl::InvalidArgumentError("job_id: empty") : absl::OkStatus();
}

void AddResults(const std::vector<JobResultMesh>& results,
                google::protobuf::RepeatedPtrField<v1::JobResultMesh>* out) {
  for (const JobResultMesh& m : results) {
    v1::JobResultMesh* r = out->Add();
    r->set_mesh_id(m.mesh_id);
    r->set_revision(m.revision);
  }
}

}  // namespace

v1::JobEvent ToProto(const JobEvent& e, const std::string& job_id) {
  v1::JobEvent p;
  p.set_job_id(job_id);
  p.set_seq(e.seq);
  p.set_state(static_cast<v1::JobState>(e.state));
  p.set_unix_ms(e.unix_ms);
  p.set_step(e.step);
  p.set_time(e.time);
  p.set_phase(e.phase);
  p.set_done(e.done);
  p.set_total(e.total);
  p.mutable_values()->insert(e.values.begin(), e.values.end());
  p.mutable_counts()->insert(e.counts.begin(), e.counts.end());
  p.set_message(e.message);
  for (const JobArray& a : e.arrays) {
    v1::NamedArray* n = p.add_arrays();
    n->set_name(a.name);
    n->mutable_array()->set_data(a.data.data(), sizeof(double) * a.data.size());
    for (int64_t d : a.shape) n->mutable_array()->add_shape(d);
  }
  AddResults(e.results, p.mutable_results());
  p.set_error_code(e.error_code);
  p.set_final(e.final);
  return p;
}

v1::Job ToProto(const JobStatus& s) {
  const JobRecord& r = s.record;
  v1::Job j;
  j.set_job_id(r.job_id);
  j.set_kind(r.kind);
  j.set_state(static_cast<v1::JobState>(r.state));
  j.set_created_unix_ms(r.created_unix_ms);
  j.set_updated_unix_ms(r.updated_unix_ms);
  AddResults(r.results, j.mutable_results());
  j.set_error_code(r.error_code);
  j.set_error(r.error);
  j.set_last_event(s.last_seq);
  if (s.latest.seq > 0) *j.mutable_latest() = ToProto(s.latest, r.job_id);
  j.mutable_request()->ParseFromString(r.options);  // the options blob is the request
  return j;
}

absl::StatusOr<v1::Job> JobHandlers::StartJob(const v1::StartJobRequest& request) {
  JobRunFn run;
  std::string kind;
  switch (request.spec_case()) {
    case v1::StartJobRequest::kRefine: {
      kind = "refine";
      GF_ASSIGN_OR_RETURN(run, MakeRefineJob(&handlers_->workspace(), request.refine(), max_vertices_));
      break;
    }
    case v1::StartJobRequest::kFlow: {
      kind = "flow";
      GF_ASSIGN_OR_RETURN(run, MakeFlowJob(&handlers_->workspace(), request.flow()));
      break;
    }
    case v1::StartJobRequest::kMembrane: {
      kind = "membrane";
      GF_ASSIGN_OR_RETURN(run, MakeMembraneJob(&handlers_->workspace(), request.membrane()));
      break;
    }
    case v1::StartJobRequest::SPEC_NOT_SET:
      return absl::InvalidArgumentError("spec: set one job spec (refine, flow, membrane)");
  }
  GF_ASSIGN_OR_RETURN(JobStatus status, jobs_->Start(kind, request.SerializeAsString(), std::move(run)));
  return ToProto(status);
}

absl::StatusOr<v1::Job> JobHandlers::GetJob(const v1::GetJobRequest& request) {
  GF_RETURN_IF_ERROR(RequireJobId(request.job_id()));
  GF_ASSIGN_OR_RETURN(JobStatus status, jobs_->Get(request.job_id()));
  return ToProto(status);
}

absl::StatusOr<v1::Job> JobHandlers::CancelJob(const v1::CancelJobRequest& request) {
  GF_RETURN_IF_ERROR(RequireJobId(request.job_id()));
  GF_ASSIGN_OR_RETURN(JobStatus status, jobs_->Cancel(request.job_id()));
  return ToProto(status);
}

absl::StatusOr<v1::ListJobsResponse> JobHandlers::ListJobs(const v1::ListJobsRequest& request) {
  if (request.page_size() < 0 || request.page_size() > 1000)
    return absl::InvalidArgumentError(absl::StrCat("page_size ", request.page_size(), " is out of range [0, 1000]"));
  const int size = request.page_size() == 0 ? 100 : request.page_size();
  GF_ASSIGN_OR_RETURN(std::vector<JobStatus> jobs, jobs_->List(request.page_token(), size + 1));
  v1::ListJobsResponse out;
  for (int i = 0; i < static_cast<int>(jobs.size()) && i < size; ++i) *out.add_jobs() = ToProto(jobs[i]);
  if (static_cast<int>(jobs.size()) > size) out.set_next_page_token(jobs[size - 1].record.job_id);
  return out;
}

absl::StatusOr<std::vector<v1::JobEvent>> JobHandlers::ReadEvents(const std::string& job_id, int64_t from, int max,
                                                                  bool* end, std::function<void()> on_more,
                                                                  uint64_t* subscription) {
  GF_RETURN_IF_ERROR(RequireJobId(job_id));
  if (from < 0) return absl::InvalidArgumentError("from_event must not be negative");
  GF_ASSIGN_OR_RETURN(JobEventBatch batch, jobs_->Read(job_id, from, max, std::move(on_more), subscription));
  std::vector<v1::JobEvent> out;
  out.reserve(batch.events.size());
  for (const JobEvent& e : batch.events) out.push_back(ToProto(e, job_id));
  *end = batch.end;
  return out;
}

absl::StatusOr<v1::Job> JobHandlers::StartFlow(const v1::FlowJob& spec) {
  v1::StartJobRequest request;
  *request.mutable_flow() = spec;
  return StartJob(request);
}

}  // namespace geomfit::server

namespace geomfit::server {

absl::StatusOr<v1::Job> JobHandlers::StartMembraneSolve(const v1::MembraneSolveJob& spec) {
  v1::StartJobRequest request;
  *request.mutable_membrane() = spec;
  return StartJob(request);
}

}  // namespace geomfit::server
