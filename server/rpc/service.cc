#include "server/rpc/service.h"

#include <deque>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "server/mesh_store.h"
#include "server/handlers/progress.h"
#include "server/rpc/grpc_status.h"
#include "server/rpc/reactors.h"
#include "server/rpc/watch_job_reactor.h"

namespace geomfit::server {
absl::StatusOr<CallContext> Service::Admit(const grpc::CallbackServerContext* ctx) const {
  if (draining()) return absl::UnavailableError("server is shutting down; retry on another replica or later");
  CallContext call;
  if (tokens_ == nullptr) return call;
  const auto& metadata = ctx->client_metadata();
  const auto it = metadata.find("authorization");
  const absl::string_view value = it == metadata.end() ? "" : absl::string_view(it->second.data(), it->second.size());
  GF_ASSIGN_OR_RETURN(call.tenant, Authenticate(*tokens_, value));
  return call;
}

absl::Status Service::TakeComputeSlot(const std::string& tenant, Call* call) {
  if (inflight_quota_ <= 0) return absl::OkStatus();
  std::lock_guard<std::mutex> lock(slots_mu_);
  int& taken = slots_[tenant];
  if (taken >= inflight_quota_) {
    if (taken == 0) slots_.erase(tenant);
    return absl::ResourceExhaustedError(absl::StrCat("tenant quota --quota-inflight=", inflight_quota_,
                                                     " reached: retry once one of your requests is answered"));
  }
  ++taken;
  call->compute_slot = tenant;
  return absl::OkStatus();
}

grpc::Status Service::Finish(const Call& call, const absl::Status& status) {
  if (call.compute_slot) {  // given back before the answer leaves: a client's next call finds it free
    std::lock_guard<std::mutex> lock(slots_mu_);
    const auto it = slots_.find(*call.compute_slot);
    if (--it->second == 0) slots_.erase(it);
  }
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - call.start).count();
  const std::string code = absl::StatusCodeToString(status.code());
  stats_->Record(call.method, code, status.ok(), ms);
  in_flight_.fetch_sub(1);
  if (status.ok()) {
    spdlog::info("{} mesh={} in={}B out={}B {:.3f}ms OK", call.method, call.mesh_id, call.bytes_in,
                 call.bytes_out, ms);
  } else {
    spdlog::warn("{} mesh={} in={}B out={}B {:.3f}ms {}: {}", call.method, call.mesh_id, call.bytes_in,
                 call.bytes_out, ms, code, std::string(status.message()));
  }
  return ToGrpcStatus(status);
}

template <typename Response>
grpc::ServerUnaryReactor* Service::Unary(grpc::CallbackServerContext* ctx, Call call, ThreadPool* pool,
                                         const google::protobuf::Message* request, Response* response,
                                         std::function<absl::StatusOr<Response>(const CallContext&)> work,
                                         std::function<void(const Response&)> after) {
  grpc::ServerUnaryReactor* reactor = ctx->DefaultReactor();
  Begin();
  absl::StatusOr<CallContext> who = Admit(ctx);
  // gRPC hands the request over for the call's lifetime: scoping it in place spares a
  // copy of large requests (SetPositions).
  if (who.ok() && request != nullptr) ScopeIds(who->tenant, const_cast<google::protobuf::Message*>(request));
  if (who.ok() && pool == compute_) {
    if (absl::Status slot = TakeComputeSlot(who->tenant, &call); !slot.ok()) who = slot;
  }
  auto run = [this, reactor, response, work = std::move(work), after = std::move(after), call,
              who = who.ok() ? *who : CallContext()]() mutable {
    absl::StatusOr<Response> r = work(who);
    if (r.ok()) UnscopeIds(who.tenant, &*r);
    if (r.ok()) {
      call.bytes_out = static_cast<int64_t>(r->ByteSizeLong());
      if (after) {
        *response = *r;  // `response` is gone once Finish is called; `r` stays for `after`
      } else {
        *response = std::move(*r);
      }
    }
    reactor->Finish(Finish(call, r.status()));
    if (after && r.ok()) after(*r);
  };
  if (!who.ok()) {
    reactor->Finish(Finish(call, who.status()));
  } else if (pool == nullptr) {
    run();
  } else if (absl::Status queued = pool->Submit(who->tenant, std::move(run)); !queued.ok()) {
    reactor->Finish(Finish(call, queued));
  }
  return reactor;
}

grpc::ServerReadReactor<grpc::ByteBuffer>* Service::UploadMesh(grpc::CallbackServerContext* ctx,
                                                               grpc::ByteBuffer* response) {
  return new ReadReactor<v1::UploadMeshRequest, UploadAssembler>(
      this, ctx, response, "UploadMesh", [this](const UploadAssembler& a, const CallContext& who) { return handlers_->UploadMesh(a, who.tenant); });
}

grpc::ServerReadReactor<grpc::ByteBuffer>* Service::UpdatePositions(grpc::CallbackServerContext* ctx,
                                                                    grpc::ByteBuffer* response) {
  auto next = std::make_shared<std::unique_ptr<Workspace::PendingPrefetch>>();
  return new ReadReactor<v1::UpdatePositionsRequest, PositionsAssembler>(
      this, ctx, response, "UpdatePositions",
      [this, next](const PositionsAssembler& a, const CallContext&) {
        return Updated(handlers_->UpdatePositions(a), next.get());
      },
      [this, next](const v1::MeshInfo&) { RunPrefetch(next.get()); },
      [this](PositionsAssembler* a) { return handlers_->ExpectPositions(a); });
}

grpc::ServerUnaryReactor* Service::SetPositions(grpc::CallbackServerContext* ctx,
                                                const v1::SetPositionsRequest* request, v1::MeshInfo* response) {
  Call call{"SetPositions", request->header().mesh_id()};
  call.bytes_in = static_cast<int64_t>(request->ByteSizeLong());
  auto next = std::make_shared<std::unique_ptr<Workspace::PendingPrefetch>>();
  return Unary<v1::MeshInfo>(
      ctx, std::move(call), compute_, request, response,
      [this, request, next](const CallContext&) { return Updated(handlers_->SetPositions(*request), next.get()); },
      [this, next](const v1::MeshInfo&) { RunPrefetch(next.get()); });
}

absl::StatusOr<v1::MeshInfo> Service::Updated(absl::StatusOr<v1::MeshInfo> info,
                                              std::unique_ptr<Workspace::PendingPrefetch>* next) {
  if (info.ok()) *next = handlers_->PlanPrefetch(info->mesh_id(), info->revision());
  return info;
}

void Service::RunPrefetch(std::unique_ptr<Workspace::PendingPrefetch>* next) {
  if (*next == nullptr) return;
  CancellationToken cancel;
  cancel.SetPoll([this] { return draining(); });
  (*next)->Run(cancel);
  next->reset();
}

grpc::ServerUnaryReactor* Service::GetMesh(grpc::CallbackServerContext* ctx, const v1::GetMeshRequest* request,
                                           v1::MeshInfo* response) {
  return Unary<v1::MeshInfo>(ctx, {"GetMesh", request->mesh_id()}, io_, request, response,
                             [this, request](const CallContext&) { return handlers_->GetMesh(*request); });
}

grpc::ServerWriteReactor<v1::DownloadMeshResponse>* Service::DownloadMesh(grpc::CallbackServerContext* ctx,
                                                                          const v1::DownloadMeshRequest* request) {
  return new PullReactor<v1::DownloadMeshResponse>(this, ctx, io_, {"DownloadMesh", request->mesh_id()}, request,
                                                   [this, request] { return handlers_->OpenDownload(*request); });
}

grpc::ServerUnaryReactor* Service::ListMeshes(grpc::CallbackServerContext* ctx, const v1::ListMeshesRequest* request,
                                              v1::ListMeshesResponse* response) {
  return Unary<v1::ListMeshesResponse>(ctx, {"ListMeshes", ""}, io_, request, response,
                                       [this, request](const CallContext& who) { return ListMeshesOf(who, *request); });
}

absl::StatusOr<v1::ListMeshesResponse> Service::ListMeshesOf(const CallContext& who,
                                                             const v1::ListMeshesRequest& request) {
  if (who.tenant.empty()) return handlers_->ListMeshes(request);
  // The tenant's ids are contiguous in id order, from its prefix on.
  const std::string prefix = TenantPrefix(who.tenant);
  v1::ListMeshesRequest scoped = request;
  scoped.set_page_token(prefix + request.page_token());
  GF_ASSIGN_OR_RETURN(v1::ListMeshesResponse page, handlers_->ListMeshes(scoped));
  v1::ListMeshesResponse mine;
  for (const v1::MeshInfo& m : page.meshes()) {
    if (!Owns(who.tenant, m.mesh_id())) return mine;  // past the tenant's last mesh
    *mine.add_meshes() = m;
  }
  if (!page.next_page_token().empty()) mine.set_next_page_token(page.next_page_token().substr(prefix.size()));
  return mine;
}

grpc::ServerUnaryReactor* Service::DeleteMesh(grpc::CallbackServerContext* ctx, const v1::DeleteMeshRequest* request,
                                              v1::DeleteMeshResponse* response) {
  return Unary<v1::DeleteMeshResponse>(ctx, {"DeleteMesh", request->mesh_id()}, io_, request, response,
                                       [this, request](const CallContext&) { return handlers_->DeleteMesh(*request); });
}

grpc::ServerWriteReactor<v1::ComputeDifferentialsResponse>* Service::ComputeDifferentials(
    grpc::CallbackServerContext* ctx, const v1::ComputeDifferentialsRequest* request) {
  return new WriteReactor<v1::ComputeDifferentialsResponse>(
      this, ctx, compute_, {"ComputeDifferentials", request->mesh_id()}, request,
      [this, request](const CancellationToken& cancel, ChunkSink<v1::ComputeDifferentialsResponse>* sink) {
        return handlers_->ComputeDifferentials(*request, cancel, sink);
      });
}

grpc::ServerUnaryReactor* Service::GetServerInfo(grpc::CallbackServerContext* ctx, const v1::GetServerInfoRequest*,
                                                 v1::ServerInfo* response) {
  return Unary<v1::ServerInfo>(ctx, {"GetServerInfo", ""}, nullptr, nullptr, response,
                               [this](const CallContext&) -> absl::StatusOr<v1::ServerInfo> { return handlers_->GetServerInfo(); });
}

grpc::ServerUnaryReactor* Service::GetStatistics(grpc::CallbackServerContext* ctx, const v1::GetStatisticsRequest*,
                                                 v1::Statistics* response) {
  return Unary<v1::Statistics>(ctx, {"GetStatistics", ""}, io_, nullptr, response,
                               [this](const CallContext&) -> absl::StatusOr<v1::Statistics> {
                                 v1::Statistics s = handlers_->GetStatistics();
                                 if (stream_limits_ != nullptr) {
                                   s.set_inflight_bytes(stream_limits_->reserved_bytes());
                                   s.set_inflight_budget_bytes(stream_limits_->max_inflight_bytes());
                                   s.set_open_streams(stream_limits_->open_streams());
                                 }
                                 return s;
                               });
}

grpc::ServerWriteReactor<v1::ProjectPointsResponse>* Service::ProjectPoints(grpc::CallbackServerContext* ctx,
                                                                            const v1::ProjectPointsRequest* request) {
  return new WriteReactor<v1::ProjectPointsResponse>(
      this, ctx, compute_, {"ProjectPoints", request->mesh_id()}, request,
      [this, request](const CancellationToken& cancel, ChunkSink<v1::ProjectPointsResponse>* sink) {
        return handlers_->ProjectPoints(*request, cancel, sink);
      });
}

grpc::ServerUnaryReactor* Service::HighOrderNodes(grpc::CallbackServerContext* ctx,
                                                  const v1::HighOrderNodesRequest* request,
                                                  v1::HighOrderNodesResponse* response) {
  return Unary<v1::HighOrderNodesResponse>(ctx, {"HighOrderNodes", request->mesh_id()}, compute_, request, response,
                                           [this, ctx, request](const CallContext&) { return handlers_->HighOrderNodes(*request, *TokenFor(ctx)); });
}

grpc::ServerUnaryReactor* Service::RefineMesh(grpc::CallbackServerContext* ctx, const v1::RefineMeshRequest* request,
                                              v1::MeshInfo* response) {
  return Unary<v1::MeshInfo>(ctx, {"RefineMesh", request->mesh_id()}, compute_, request, response,
                             [this, ctx, request](const CallContext&) { return handlers_->RefineMesh(*request, *TokenFor(ctx)); });
}

grpc::ServerUnaryReactor* Service::Integrate(grpc::CallbackServerContext* ctx, const v1::IntegrateRequest* request,
                                             v1::IntegrateResponse* response) {
  return Unary<v1::IntegrateResponse>(ctx, {"Integrate", request->mesh_id()}, compute_, request, response,
                                      [this, ctx, request](const CallContext&) { return handlers_->Integrate(*request, *TokenFor(ctx)); });
}

// ---- Jobs ------------------------------------------------------------------------------

namespace {
absl::Status NoJobs() { return absl::UnimplementedError("this server runs no jobs"); }
}  // namespace

std::string JobMeshId(const v1::Job& job) {
  switch (job.request().spec_case()) {
    case v1::StartJobRequest::kFlow: return job.request().flow().mesh_id();
    case v1::StartJobRequest::kMembrane: return job.request().membrane().mesh_id();
    default: return job.request().refine().mesh_id();
  }
}

absl::Status Service::OwnJob(const CallContext& who, const std::string& job_id) const {
  if (who.tenant.empty() || jobs_ == nullptr) return absl::OkStatus();
  v1::GetJobRequest get;
  get.set_job_id(job_id);
  absl::StatusOr<v1::Job> job = jobs_->GetJob(get);
  if (!job.ok()) return job.status();
  if (!Owns(who.tenant, JobMeshId(*job))) return JobNotFound(job_id);
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* Service::StartJob(grpc::CallbackServerContext* ctx, const v1::StartJobRequest* request,
                                            v1::Job* response) {
  Call call{"StartJob", request->has_refine()     ? request->refine().mesh_id()
                        : request->has_flow()     ? request->flow().mesh_id()
                        : request->has_membrane() ? request->membrane().mesh_id()
                                                  : ""};
  return Unary<v1::Job>(ctx, std::move(call), io_, request, response, [this, request](const CallContext&) -> absl::StatusOr<v1::Job> {
    if (jobs_ == nullptr) return NoJobs();
    return jobs_->StartJob(*request);  // its mesh id is scoped: the job is the tenant's
  });
}

grpc::ServerWriteReactor<v1::JobEvent>* Service::WatchJob(grpc::CallbackServerContext* ctx,
                                                          const v1::WatchJobRequest* request) {
  return new WatchJobReactor(this, ctx, jobs_, *request);
}

grpc::ServerUnaryReactor* Service::CancelJob(grpc::CallbackServerContext* ctx, const v1::CancelJobRequest* request,
                                             v1::Job* response) {
  return Unary<v1::Job>(ctx, {"CancelJob", request->job_id()}, io_, request, response,
                        [this, request](const CallContext& who) -> absl::StatusOr<v1::Job> {
                          if (jobs_ == nullptr) return NoJobs();
                          GF_RETURN_IF_ERROR(OwnJob(who, request->job_id()));
                          return jobs_->CancelJob(*request);
                        });
}

grpc::ServerUnaryReactor* Service::GetJob(grpc::CallbackServerContext* ctx, const v1::GetJobRequest* request,
                                          v1::Job* response) {
  return Unary<v1::Job>(ctx, {"GetJob", request->job_id()}, io_, request, response,
                        [this, request](const CallContext& who) -> absl::StatusOr<v1::Job> {
                          if (jobs_ == nullptr) return NoJobs();
                          GF_RETURN_IF_ERROR(OwnJob(who, request->job_id()));
                          return jobs_->GetJob(*request);
                        });
}

grpc::ServerUnaryReactor* Service::ListJobs(grpc::CallbackServerContext* ctx, const v1::ListJobsRequest* request,
                                            v1::ListJobsResponse* response) {
  return Unary<v1::ListJobsResponse>(ctx, {"ListJobs", ""}, io_, request, response,
                                     [this, request](const CallContext& who) -> absl::StatusOr<v1::ListJobsResponse> {
                                       if (jobs_ == nullptr) return NoJobs();
                                       GF_ASSIGN_OR_RETURN(v1::ListJobsResponse all, jobs_->ListJobs(*request));
                                       if (who.tenant.empty()) return all;
                                       v1::ListJobsResponse mine = all;
                                       mine.clear_jobs();
                                       for (const v1::Job& job : all.jobs()) {
                                         if (Owns(who.tenant, JobMeshId(job))) *mine.add_jobs() = job;
                                       }
                                       return mine;
                                     });
}

grpc::ServerUnaryReactor* Service::StartFlow(grpc::CallbackServerContext* ctx, const v1::FlowJob* request,
                                             v1::Job* response) {
  return Unary<v1::Job>(ctx, {"StartFlow", request->mesh_id()}, io_, request, response,
                        [this, request](const CallContext&) -> absl::StatusOr<v1::Job> {
                          if (jobs_ == nullptr) return NoJobs();
                          return jobs_->StartFlow(*request);
                        });
}

grpc::ServerUnaryReactor* Service::ApplyOperator(grpc::CallbackServerContext* ctx,
                                                 const v1::ApplyOperatorRequest* request,
                                                 v1::ApplyOperatorResponse* response) {
  return Unary<v1::ApplyOperatorResponse>(ctx, {"ApplyOperator", request->mesh_id()}, compute_, request, response,
                                          [this, ctx, request](const CallContext&) { return handlers_->ApplyOperator(*request, *TokenFor(ctx)); });
}

grpc::ServerUnaryReactor* Service::GetOperator(grpc::CallbackServerContext* ctx, const v1::GetOperatorRequest* request,
                                               v1::GetOperatorResponse* response) {
  return Unary<v1::GetOperatorResponse>(ctx, {"GetOperator", request->mesh_id()}, compute_, request, response,
                                        [this, ctx, request](const CallContext&) { return handlers_->GetOperator(*request, *TokenFor(ctx)); });
}

grpc::ServerWriteReactor<v1::ComputeMembraneResponse>* Service::ComputeMembrane(
    grpc::CallbackServerContext* ctx, const v1::ComputeMembraneRequest* request) {
  return new WriteReactor<v1::ComputeMembraneResponse>(
      this, ctx, compute_, {"ComputeMembrane", request->mesh_id()}, request,
      [this, request](const CancellationToken& cancel, ChunkSink<v1::ComputeMembraneResponse>* sink) {
        return handlers_->ComputeMembrane(*request, cancel, sink);
      });
}

grpc::ServerUnaryReactor* Service::StartMembraneSolve(grpc::CallbackServerContext* ctx,
                                                      const v1::MembraneSolveJob* request, v1::Job* response) {
  return Unary<v1::Job>(ctx, {"StartMembraneSolve", request->mesh_id()}, io_, request, response,
                        [this, request](const CallContext&) -> absl::StatusOr<v1::Job> {
                          if (jobs_ == nullptr) return NoJobs();
                          return jobs_->StartMembraneSolve(*request);
                        });
}

// ---- Streaming variants of the unary chapter-4 calls: progress, then the response ----

grpc::ServerWriteReactor<v1::HighOrderNodesResponse>* Service::HighOrderNodesStream(
    grpc::CallbackServerContext* ctx, const v1::HighOrderNodesRequest* request) {
  return new WriteReactor<v1::HighOrderNodesResponse>(
      this, ctx, compute_, {"HighOrderNodesStream", request->mesh_id()}, request,
      StreamWithProgress<v1::HighOrderNodesResponse>(
          [this, request](const CancellationToken& cancel, const RunContext::ProgressFn& progress) {
            return handlers_->HighOrderNodes(*request, cancel, progress);
          }));
}

grpc::ServerWriteReactor<v1::IntegrateResponse>* Service::IntegrateStream(grpc::CallbackServerContext* ctx,
                                                                          const v1::IntegrateRequest* request) {
  return new WriteReactor<v1::IntegrateResponse>(
      this, ctx, compute_, {"IntegrateStream", request->mesh_id()}, request,
      StreamWithProgress<v1::IntegrateResponse>(
          [this, request](const CancellationToken& cancel, const RunContext::ProgressFn& progress) {
            return handlers_->Integrate(*request, cancel, progress);
          }));
}

grpc::ServerWriteReactor<v1::RefineMeshResponse>* Service::RefineMeshStream(grpc::CallbackServerContext* ctx,
                                                                            const v1::RefineMeshRequest* request) {
  return new WriteReactor<v1::RefineMeshResponse>(
      this, ctx, compute_, {"RefineMeshStream", request->mesh_id()}, request,
      StreamWithProgress<v1::RefineMeshResponse>(
          [this, request](const CancellationToken& cancel,
                          const RunContext::ProgressFn& progress) -> absl::StatusOr<v1::RefineMeshResponse> {
            v1::RefineMeshResponse out;
            GF_ASSIGN_OR_RETURN(*out.mutable_mesh(), handlers_->RefineMesh(*request, cancel, progress));
            return out;
          }));
}

}  // namespace geomfit::server
