#pragma once
#include <atomic>
#include <chrono>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "geomfit/v1/geomfit.grpc.pb.h"
#include "server/handlers/handlers.h"
#include "server/handlers/jobs.h"
#include "server/auth.h"
#include "server/request_stats.h"
#include "server/rpc/stream_limits.h"
#include "server/rpc/tenancy.h"
#include "server/thread_pool.h"

namespace geomfit::server {

/// The mesh a job works on (its spec's), as stored: the job belongs to its tenant.
std::string JobMeshId(const v1::Job& job);

/// Thin adapter from the gRPC callback API to Handlers. gRPC threads only move
/// messages: every handler runs on a pool (compute: uploads, updates, fits; io:
/// store reads and deletes), and each call ends in Service::Finish, which logs one
/// line and records statistics.
/// UploadMesh and UpdatePositions are raw (ByteBuffer) methods: the reactor parses each
/// message itself, so that garbage is told from the end of the stream.
using ServiceBase = v1::GeomFit::WithRawCallbackMethod_UploadMesh<
    v1::GeomFit::WithRawCallbackMethod_UpdatePositions<v1::GeomFit::CallbackService>>;

class Service final : public ServiceBase {
 public:
  Service(Handlers* handlers, ThreadPool* compute, ThreadPool* io, RequestStats* stats)
      : handlers_(handlers), compute_(compute), io_(io), stats_(stats) {}

  /// From now on every new call gets UNAVAILABLE.
  void StartDraining() { draining_.store(true); }
  bool draining() const { return draining_.load(); }
  /// Calls begun (Begin) and not yet finished (Finish).
  int in_flight() const { return in_flight_.load(); }
  void Begin() { in_flight_.fetch_add(1); }

  /// Streams of v1::UploadMeshRequest answered by a v1::MeshInfo (see ServiceBase).
  grpc::ServerReadReactor<grpc::ByteBuffer>* UploadMesh(grpc::CallbackServerContext* ctx,
                                                        grpc::ByteBuffer* response) override;
  /// Streams of v1::UpdatePositionsRequest answered by a v1::MeshInfo.
  grpc::ServerReadReactor<grpc::ByteBuffer>* UpdatePositions(grpc::CallbackServerContext* ctx,
                                                             grpc::ByteBuffer* response) override;
  grpc::ServerUnaryReactor* SetPositions(grpc::CallbackServerContext* ctx, const v1::SetPositionsRequest* request,
                                         v1::MeshInfo* response) override;
  grpc::ServerUnaryReactor* GetMesh(grpc::CallbackServerContext* ctx, const v1::GetMeshRequest* request,
                                    v1::MeshInfo* response) override;
  grpc::ServerWriteReactor<v1::DownloadMeshResponse>* DownloadMesh(grpc::CallbackServerContext* ctx,
                                                                   const v1::DownloadMeshRequest* request) override;
  grpc::ServerUnaryReactor* ListMeshes(grpc::CallbackServerContext* ctx, const v1::ListMeshesRequest* request,
                                       v1::ListMeshesResponse* response) override;
  grpc::ServerUnaryReactor* DeleteMesh(grpc::CallbackServerContext* ctx, const v1::DeleteMeshRequest* request,
                                       v1::DeleteMeshResponse* response) override;
  grpc::ServerWriteReactor<v1::ComputeDifferentialsResponse>* ComputeDifferentials(
      grpc::CallbackServerContext* ctx, const v1::ComputeDifferentialsRequest* request) override;
  grpc::ServerUnaryReactor* GetServerInfo(grpc::CallbackServerContext* ctx, const v1::GetServerInfoRequest* request,
                                          v1::ServerInfo* response) override;
  grpc::ServerUnaryReactor* GetStatistics(grpc::CallbackServerContext* ctx, const v1::GetStatisticsRequest* request,
                                          v1::Statistics* response) override;
  grpc::ServerWriteReactor<v1::ProjectPointsResponse>* ProjectPoints(grpc::CallbackServerContext* ctx,
                                                                     const v1::ProjectPointsRequest* request) override;
  grpc::ServerUnaryReactor* HighOrderNodes(grpc::CallbackServerContext* ctx, const v1::HighOrderNodesRequest* request,
                                           v1::HighOrderNodesResponse* response) override;
  grpc::ServerUnaryReactor* RefineMesh(grpc::CallbackServerContext* ctx, const v1::RefineMeshRequest* request,
                                       v1::MeshInfo* response) override;
  grpc::ServerUnaryReactor* Integrate(grpc::CallbackServerContext* ctx, const v1::IntegrateRequest* request,
                                      v1::IntegrateResponse* response) override;

  // Jobs (job_handlers.h); UNIMPLEMENTED until SetJobs.
  grpc::ServerUnaryReactor* StartJob(grpc::CallbackServerContext* ctx, const v1::StartJobRequest* request,
                                     v1::Job* response) override;
  grpc::ServerWriteReactor<v1::JobEvent>* WatchJob(grpc::CallbackServerContext* ctx,
                                                   const v1::WatchJobRequest* request) override;
  grpc::ServerUnaryReactor* CancelJob(grpc::CallbackServerContext* ctx, const v1::CancelJobRequest* request,
                                      v1::Job* response) override;
  grpc::ServerUnaryReactor* GetJob(grpc::CallbackServerContext* ctx, const v1::GetJobRequest* request,
                                   v1::Job* response) override;
  grpc::ServerUnaryReactor* ListJobs(grpc::CallbackServerContext* ctx, const v1::ListJobsRequest* request,
                                     v1::ListJobsResponse* response) override;
  void SetJobs(JobHandlers* jobs) { jobs_ = jobs; }

  // Flows and operators.
  grpc::ServerUnaryReactor* StartFlow(grpc::CallbackServerContext* ctx, const v1::FlowJob* request,
                                      v1::Job* response) override;
  grpc::ServerUnaryReactor* ApplyOperator(grpc::CallbackServerContext* ctx, const v1::ApplyOperatorRequest* request,
                                          v1::ApplyOperatorResponse* response) override;
  grpc::ServerUnaryReactor* GetOperator(grpc::CallbackServerContext* ctx, const v1::GetOperatorRequest* request,
                                        v1::GetOperatorResponse* response) override;

  // Membranes.
  grpc::ServerWriteReactor<v1::ComputeMembraneResponse>* ComputeMembrane(
      grpc::CallbackServerContext* ctx, const v1::ComputeMembraneRequest* request) override;
  grpc::ServerUnaryReactor* StartMembraneSolve(grpc::CallbackServerContext* ctx, const v1::MembraneSolveJob* request,
                                               v1::Job* response) override;

  // Streaming variants of HighOrderNodes, Integrate, RefineMesh: progress messages,
  // then the unary call's response.
  grpc::ServerWriteReactor<v1::HighOrderNodesResponse>* HighOrderNodesStream(
      grpc::CallbackServerContext* ctx, const v1::HighOrderNodesRequest* request) override;
  grpc::ServerWriteReactor<v1::IntegrateResponse>* IntegrateStream(grpc::CallbackServerContext* ctx,
                                                                   const v1::IntegrateRequest* request) override;
  grpc::ServerWriteReactor<v1::RefineMeshResponse>* RefineMeshStream(grpc::CallbackServerContext* ctx,
                                                                     const v1::RefineMeshRequest* request) override;

  /// What one call did, for the request log line.
  struct Call {
    const char* method;
    std::string mesh_id;
    int64_t bytes_in = 0, bytes_out = 0;
    std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
    std::optional<std::string> compute_slot;  ///< the tenant whose compute slot it holds (TakeComputeSlot)
  };
  /// Logs and records `call` (begun with Begin), returning the mapped status to
  /// finish the RPC with.
  grpc::Status Finish(const Call& call, const absl::Status& status);
  /// UNAVAILABLE while draining; with a token table, UNAUTHENTICATED without a valid
  /// `authorization: Bearer TOKEN`; else the caller (the one place that reads auth
  /// metadata).
  absl::StatusOr<CallContext> Admit(const grpc::CallbackServerContext* ctx) const;
  /// Multi-tenant mode (--auth-tokens); null: single tenant, no authentication.
  void SetTokens(const TokenTable* tokens) { tokens_ = tokens; }
  /// NOT_FOUND unless job `job_id` is the caller's (its input mesh is).
  absl::Status OwnJob(const CallContext& who, const std::string& job_id) const;
  /// --quota-inflight: `k` calls per tenant in compute at once (queued or running, until
  /// answered); 0 = unlimited.
  void SetInflightQuota(int k) { inflight_quota_ = k; }
  /// Before a call goes to the compute pool: one of `tenant`'s slots for `call`, given
  /// back by Finish; RESOURCE_EXHAUSTED naming the quota when they are all taken.
  absl::Status TakeComputeSlot(const std::string& tenant, Call* call);
  Handlers* handlers() { return handlers_; }
  ThreadPool* compute() { return compute_; }
  ThreadPool* io() { return io_; }
  /// In-flight budget and idle timeout of streams (null: neither).
  void SetStreamLimits(StreamLimits* limits) { stream_limits_ = limits; }
  StreamLimits* stream_limits() { return stream_limits_; }

 private:
  /// A unary call: admitted, `request`'s mesh ids scoped to the caller's tenant, `work`
  /// on `pool` (null: inline), the response's ids unscoped. `after` (optional) runs on
  /// the pool thread once an OK response is sent.
  template <typename Response>
  grpc::ServerUnaryReactor* Unary(grpc::CallbackServerContext* ctx, Call call, ThreadPool* pool,
                                  const google::protobuf::Message* request, Response* response,
                                  std::function<absl::StatusOr<Response>(const CallContext&)> work,
                                  std::function<void(const Response&)> after = nullptr);
  /// After an update is stored, before it is acknowledged: registers the next step's
  /// prefetch (Workspace::PlanPrefetch) in `next`.
  absl::StatusOr<v1::MeshInfo> Updated(absl::StatusOr<v1::MeshInfo> info,
                                       std::unique_ptr<Workspace::PendingPrefetch>* next);
  /// ListMeshes of the caller's meshes only.
  absl::StatusOr<v1::ListMeshesResponse> ListMeshesOf(const CallContext& who, const v1::ListMeshesRequest& request);
  /// Once the update is acknowledged: runs the prefetch `next` holds, if any.
  void RunPrefetch(std::unique_ptr<Workspace::PendingPrefetch>* next);

  Handlers* handlers_;
  ThreadPool* compute_;
  ThreadPool* io_;
  RequestStats* stats_;
  std::atomic<bool> draining_{false};
  std::atomic<int> in_flight_{0};
  JobHandlers* jobs_ = nullptr;
  const TokenTable* tokens_ = nullptr;
  StreamLimits* stream_limits_ = nullptr;
  int inflight_quota_ = 0;
  std::mutex slots_mu_;
  std::map<std::string, int> slots_;  ///< per tenant, while some are taken
};

}  // namespace geomfit::server
