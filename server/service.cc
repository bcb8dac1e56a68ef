#include "server/service.h"

#include <deque>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

#include "absl/status/status.h"
#include "server/grpc_status.h"
#include "server/watch_job_reactor.h"

namespace geomfit::server {
namespace {

absl::Status QueueFull(const char* pool) {
  return absl::ResourceExhaustedError(std::string("server busy: the ") + pool +
                                      " queue is full (--queue); retry later");
}

/// A token that trips at the call's deadline and when the call is cancelled.
std::unique_ptr<CancellationToken> TokenFor(const grpc::CallbackServerContext* ctx) {
  const auto deadline = ctx->deadline();
  if (deadline >= std::chrono::system_clock::time_point::max() - std::chrono::hours(24 * 365)) {
    return std::make_unique<CancellationToken>();
  }
  const auto left = deadline - std::chrono::system_clock::now();
  return std::make_unique<CancellationToken>(
      std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(left));
}

/// Client-streaming call: messages are folded into an Assembler on the gRPC thread
/// (cheap copies); the end of the stream runs `finish` on the compute pool.
template <typename Request, typename Assembler>
class ReadReactor final : public grpc::ServerReadReactor<Request> {
 public:
  using FinishFn = std::function<absl::StatusOr<v1::MeshInfo>(const Assembler&)>;
  /// Runs on the compute thread once the call is answered (OK only).
  using AfterFn = std::function<void(const v1::MeshInfo&)>;

  ReadReactor(Service* service, grpc::CallbackServerContext* ctx, v1::MeshInfo* response, const char* method,
              FinishFn finish, AfterFn after = nullptr)
      : service_(service), ctx_(ctx), response_(response), assembler_(service->handlers()->options().max_vertices),
        finish_(std::move(finish)), after_(std::move(after)) {
    service_->Begin();
    call_.method = method;
    if (absl::Status s = service_->Admit(); !s.ok()) {
      Done(s);
      return;
    }
    this->StartRead(&request_);
  }

  void OnReadDone(bool ok) override {
    if (ok) {
      absl::Status s = assembler_.Add(request_);
      if (!s.ok()) return Done(s);
      request_.Clear();
      this->StartRead(&request_);
      return;
    }
    if (ctx_->IsCancelled()) return Done(absl::CancelledError("client cancelled the stream; nothing stored"));
    call_.bytes_in = assembler_.bytes();
    const bool queued = service_->compute()->TrySubmit([this] {
      absl::StatusOr<v1::MeshInfo> info = finish_(assembler_);
      if (info.ok()) {
        call_.mesh_id = info->mesh_id();
        *response_ = *info;
      }
      AfterFn after = std::move(after_);  // `this` may be gone once Done returns
      Done(info.status());
      if (after && info.ok()) after(*info);
    });
    if (!queued) Done(QueueFull("compute"));
  }

  void OnDone() override { delete this; }

 private:
  void Done(const absl::Status& s) {
    if (call_.mesh_id.empty()) call_.mesh_id = assembler_.mesh_id();
    this->Finish(service_->Finish(call_, s));
  }

  Service* service_;
  grpc::CallbackServerContext* ctx_;
  v1::MeshInfo* response_;
  Request request_;
  Assembler assembler_;
  FinishFn finish_;
  AfterFn after_;
  Service::Call call_{};
};

/// Server-streaming call: `work` runs on a pool thread (polling the call's token) and
/// hands over chunks as they are ready; each is written as soon as the previous write
/// is done, while the work goes on. The chunk pushed as `last` goes out together with
/// OK at once, from the thread that pushed it, even while the work is still returning
/// (a follower's last chunk is pushed by the thread that ends the computation, so the
/// response does not wait for the follower to wake). The reactor is deleted once both
/// gRPC is done with it (OnDone) and the work has returned.
template <typename Response>
class WriteReactor final : public grpc::ServerWriteReactor<Response>, private ChunkSink<Response> {
 public:
  using WorkFn = std::function<absl::Status(const CancellationToken&, ChunkSink<Response>*)>;

  WriteReactor(Service* service, grpc::CallbackServerContext* ctx, ThreadPool* pool, Service::Call call,
               WorkFn work)
      : service_(service), token_(TokenFor(ctx)), work_(std::move(work)), call_(std::move(call)) {
    service_->Begin();
    if (absl::Status s = service_->Admit(); !s.ok()) {
      Done(s);
      return;
    }
    working_ = true;
    if (!pool->TrySubmit([this] { Run(); })) {
      working_ = false;
      Done(QueueFull(pool == service->compute() ? "compute" : "io"));
    }
  }

  void OnWriteDone(bool ok) override {
    std::unique_lock<std::mutex> lock(mu_);
    writing_ = false;
    if (!ok) {
      broken_ = true;
      queue_.clear();
      token_->Cancel();
    }
    Pump(lock);
  }
  void OnCancel() override { token_->Cancel(); }
  void OnDone() override {
    std::unique_lock<std::mutex> lock(mu_);
    done_ = true;
    if (working_) return;  // the work deletes it when it returns
    lock.unlock();
    delete this;
  }

 private:
  void Run() {
    const absl::Status status = work_(*token_, this);
    std::unique_lock<std::mutex> lock(mu_);
    returned_ = true;
    end_ = status;
    Pump(lock);
    if (!lock.owns_lock()) lock.lock();
    working_ = false;
    const bool gone = done_;  // else OnDone deletes it
    lock.unlock();
    if (gone) delete this;
  }
  /// `last`: this chunk ends the call with OK; the work's own status is then ignored.
  void Push(Response chunk, bool last) override {
    std::unique_lock<std::mutex> lock(mu_);
    if (broken_ || finished_) return;
    queue_.push_back(std::move(chunk));
    last_queued_ = last_queued_ || last;
    Pump(lock);
  }
  /// Starts the next write, or finishes the call, if the state allows; unlocks first.
  void Pump(std::unique_lock<std::mutex>& lock) {
    if (writing_ || finished_) return;
    absl::Status end;
    if (broken_) {
      if (!returned_) return;
      end = absl::CancelledError("client went away during the response stream");
    } else if (returned_ && !last_queued_ && (!end_.ok() || queue_.empty())) {
      end = end_;  // an error drops the chunks not written yet
    } else {
      if (queue_.empty()) return;
      const bool final = last_queued_ && queue_.size() == 1;
      current_ = std::move(queue_.front());
      queue_.pop_front();
      writing_ = true;
      finished_ = final;
      call_.bytes_out += static_cast<int64_t>(current_.ByteSizeLong());
      lock.unlock();
      if (!final) return this->StartWrite(&current_);
      return this->StartWriteAndFinish(&current_, grpc::WriteOptions(), service_->Finish(call_, absl::OkStatus()));
    }
    finished_ = true;
    lock.unlock();
    Done(end);
  }
  void Done(const absl::Status& s) { this->Finish(service_->Finish(call_, s)); }

  Service* service_;
  std::unique_ptr<CancellationToken> token_;
  WorkFn work_;
  Service::Call call_;
  std::mutex mu_;
  std::deque<Response> queue_;
  Response current_;
  bool writing_ = false, last_queued_ = false, broken_ = false, finished_ = false;
  bool returned_ = false;  ///< the work returned (its status is end_)
  bool working_ = false;   ///< the work was submitted and Run has not let go of the reactor
  bool done_ = false;      ///< OnDone was called
  absl::Status end_;
};

/// A WriteReactor work function from a handler that returns all its chunks at once.
template <typename Response>
typename WriteReactor<Response>::WorkFn AllAtOnce(
    std::function<absl::StatusOr<std::vector<Response>>(const CancellationToken&)> fn) {
  return [fn = std::move(fn)](const CancellationToken& cancel, ChunkSink<Response>* sink) -> absl::Status {
    absl::StatusOr<std::vector<Response>> chunks = fn(cancel);
    if (!chunks.ok()) return chunks.status();
    for (size_t i = 0; i < chunks->size(); ++i) sink->Push(std::move((*chunks)[i]), i + 1 == chunks->size());
    return absl::OkStatus();
  };
}

}  // namespace

absl::Status Service::Admit() const {
  if (draining()) return absl::UnavailableError("server is shutting down; retry on another replica or later");
  return absl::OkStatus();
}

grpc::Status Service::Finish(const Call& call, const absl::Status& status) {
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
                                         Response* response, std::function<absl::StatusOr<Response>()> work,
                                         std::function<void(const Response&)> after) {
  grpc::ServerUnaryReactor* reactor = ctx->DefaultReactor();
  Begin();
  auto run = [this, reactor, response, work = std::move(work), after = std::move(after), call]() mutable {
    absl::StatusOr<Response> r = work();
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
  if (absl::Status s = Admit(); !s.ok()) {
    reactor->Finish(Finish(call, s));
  } else if (pool == nullptr) {
    run();
  } else if (!pool->TrySubmit(std::move(run))) {
    reactor->Finish(Finish(call, QueueFull(pool == compute_ ? "compute" : "io")));
  }
  return reactor;
}

grpc::ServerReadReactor<v1::UploadMeshRequest>* Service::UploadMesh(grpc::CallbackServerContext* ctx,
                                                                    v1::MeshInfo* response) {
  return new ReadReactor<v1::UploadMeshRequest, UploadAssembler>(
      this, ctx, response, "UploadMesh", [this](const UploadAssembler& a) { return handlers_->UploadMesh(a); });
}

grpc::ServerReadReactor<v1::UpdatePositionsRequest>* Service::UpdatePositions(grpc::CallbackServerContext* ctx,
                                                                              v1::MeshInfo* response) {
  auto next = std::make_shared<std::unique_ptr<Handlers::PendingPrefetch>>();
  return new ReadReactor<v1::UpdatePositionsRequest, PositionsAssembler>(
      this, ctx, response, "UpdatePositions",
      [this, next](const PositionsAssembler& a) { return Updated(handlers_->UpdatePositions(a), next.get()); },
      [this, next](const v1::MeshInfo&) { RunPrefetch(next.get()); });
}

grpc::ServerUnaryReactor* Service::SetPositions(grpc::CallbackServerContext* ctx,
                                                const v1::SetPositionsRequest* request, v1::MeshInfo* response) {
  Call call{"SetPositions", request->header().mesh_id()};
  call.bytes_in = static_cast<int64_t>(request->ByteSizeLong());
  auto next = std::make_shared<std::unique_ptr<Handlers::PendingPrefetch>>();
  return Unary<v1::MeshInfo>(
      ctx, std::move(call), compute_, response,
      [this, request, next] { return Updated(handlers_->SetPositions(*request), next.get()); },
      [this, next](const v1::MeshInfo&) { RunPrefetch(next.get()); });
}

absl::StatusOr<v1::MeshInfo> Service::Updated(absl::StatusOr<v1::MeshInfo> info,
                                              std::unique_ptr<Handlers::PendingPrefetch>* next) {
  if (info.ok()) *next = handlers_->PlanPrefetch(info->mesh_id(), info->revision());
  return info;
}

void Service::RunPrefetch(std::unique_ptr<Handlers::PendingPrefetch>* next) {
  if (*next == nullptr) return;
  CancellationToken cancel;
  cancel.SetPoll([this] { return draining(); });
  (*next)->Run(cancel);
  next->reset();
}

grpc::ServerUnaryReactor* Service::GetMesh(grpc::CallbackServerContext* ctx, const v1::GetMeshRequest* request,
                                           v1::MeshInfo* response) {
  return Unary<v1::MeshInfo>(ctx, {"GetMesh", request->mesh_id()}, io_, response,
                             [this, request] { return handlers_->GetMesh(*request); });
}

grpc::ServerWriteReactor<v1::DownloadMeshResponse>* Service::DownloadMesh(grpc::CallbackServerContext* ctx,
                                                                          const v1::DownloadMeshRequest* request) {
  return new WriteReactor<v1::DownloadMeshResponse>(
      this, ctx, io_, {"DownloadMesh", request->mesh_id()},
      AllAtOnce<v1::DownloadMeshResponse>(
          [this, request](const CancellationToken&) { return handlers_->DownloadMesh(*request); }));
}

grpc::ServerUnaryReactor* Service::ListMeshes(grpc::CallbackServerContext* ctx, const v1::ListMeshesRequest* request,
                                              v1::ListMeshesResponse* response) {
  return Unary<v1::ListMeshesResponse>(ctx, {"ListMeshes", ""}, io_, response,
                                       [this, request] { return handlers_->ListMeshes(*request); });
}

grpc::ServerUnaryReactor* Service::DeleteMesh(grpc::CallbackServerContext* ctx, const v1::DeleteMeshRequest* request,
                                              v1::DeleteMeshResponse* response) {
  return Unary<v1::DeleteMeshResponse>(ctx, {"DeleteMesh", request->mesh_id()}, io_, response,
                                       [this, request] { return handlers_->DeleteMesh(*request); });
}

grpc::ServerWriteReactor<v1::ComputeDifferentialsResponse>* Service::ComputeDifferentials(
    grpc::CallbackServerContext* ctx, const v1::ComputeDifferentialsRequest* request) {
  return new WriteReactor<v1::ComputeDifferentialsResponse>(
      this, ctx, compute_, {"ComputeDifferentials", request->mesh_id()},
      [this, request](const CancellationToken& cancel, ChunkSink<v1::ComputeDifferentialsResponse>* sink) {
        return handlers_->ComputeDifferentials(*request, cancel, sink);
      });
}

grpc::ServerUnaryReactor* Service::GetServerInfo(grpc::CallbackServerContext* ctx, const v1::GetServerInfoRequest*,
                                                 v1::ServerInfo* response) {
  return Unary<v1::ServerInfo>(ctx, {"GetServerInfo", ""}, nullptr, response,
                               [this]() -> absl::StatusOr<v1::ServerInfo> { return handlers_->GetServerInfo(); });
}

grpc::ServerUnaryReactor* Service::GetStatistics(grpc::CallbackServerContext* ctx, const v1::GetStatisticsRequest*,
                                                 v1::Statistics* response) {
  return Unary<v1::Statistics>(ctx, {"GetStatistics", ""}, io_, response,
                               [this]() -> absl::StatusOr<v1::Statistics> { return handlers_->GetStatistics(); });
}

grpc::ServerWriteReactor<v1::ProjectPointsResponse>* Service::ProjectPoints(grpc::CallbackServerContext* ctx,
                                                                            const v1::ProjectPointsRequest* request) {
  return new WriteReactor<v1::ProjectPointsResponse>(
      this, ctx, compute_, {"ProjectPoints", request->mesh_id()},
      AllAtOnce<v1::ProjectPointsResponse>(
          [this, request](const CancellationToken& cancel) { return handlers_->ProjectPoints(*request, cancel); }));
}

grpc::ServerUnaryReactor* Service::HighOrderNodes(grpc::CallbackServerContext* ctx,
                                                  const v1::HighOrderNodesRequest* request,
                                                  v1::HighOrderNodesResponse* response) {
  return Unary<v1::HighOrderNodesResponse>(ctx, {"HighOrderNodes", request->mesh_id()}, compute_, response,
                                           [this, ctx, request] { return handlers_->HighOrderNodes(*request, *TokenFor(ctx)); });
}

grpc::ServerUnaryReactor* Service::RefineMesh(grpc::CallbackServerContext* ctx, const v1::RefineMeshRequest* request,
                                              v1::MeshInfo* response) {
  return Unary<v1::MeshInfo>(ctx, {"RefineMesh", request->mesh_id()}, compute_, response,
                             [this, ctx, request] { return handlers_->RefineMesh(*request, *TokenFor(ctx)); });
}

grpc::ServerUnaryReactor* Service::Integrate(grpc::CallbackServerContext* ctx, const v1::IntegrateRequest* request,
                                             v1::IntegrateResponse* response) {
  return Unary<v1::IntegrateResponse>(ctx, {"Integrate", request->mesh_id()}, compute_, response,
                                      [this, ctx, request] { return handlers_->Integrate(*request, *TokenFor(ctx)); });
}

// ---- Jobs ------------------------------------------------------------------------------

namespace {
absl::Status NoJobs() { return absl::UnimplementedError("this server runs no jobs"); }
}  // namespace

grpc::ServerUnaryReactor* Service::StartJob(grpc::CallbackServerContext* ctx, const v1::StartJobRequest* request,
                                            v1::Job* response) {
  Call call{"StartJob", request->has_refine() ? request->refine().mesh_id() : ""};
  return Unary<v1::Job>(ctx, std::move(call), io_, response, [this, request]() -> absl::StatusOr<v1::Job> {
    if (jobs_ == nullptr) return NoJobs();
    return jobs_->StartJob(*request);
  });
}

grpc::ServerWriteReactor<v1::JobEvent>* Service::WatchJob(grpc::CallbackServerContext*,
                                                          const v1::WatchJobRequest* request) {
  return new WatchJobReactor(this, jobs_, *request);
}

grpc::ServerUnaryReactor* Service::CancelJob(grpc::CallbackServerContext* ctx, const v1::CancelJobRequest* request,
                                             v1::Job* response) {
  return Unary<v1::Job>(ctx, {"CancelJob", request->job_id()}, io_, response,
                        [this, request]() -> absl::StatusOr<v1::Job> {
                          if (jobs_ == nullptr) return NoJobs();
                          return jobs_->CancelJob(*request);
                        });
}

grpc::ServerUnaryReactor* Service::GetJob(grpc::CallbackServerContext* ctx, const v1::GetJobRequest* request,
                                          v1::Job* response) {
  return Unary<v1::Job>(ctx, {"GetJob", request->job_id()}, io_, response,
                        [this, request]() -> absl::StatusOr<v1::Job> {
                          if (jobs_ == nullptr) return NoJobs();
                          return jobs_->GetJob(*request);
                        });
}

grpc::ServerUnaryReactor* Service::ListJobs(grpc::CallbackServerContext* ctx, const v1::ListJobsRequest* request,
                                            v1::ListJobsResponse* response) {
  return Unary<v1::ListJobsResponse>(ctx, {"ListJobs", ""}, io_, response,
                                     [this, request]() -> absl::StatusOr<v1::ListJobsResponse> {
                                       if (jobs_ == nullptr) return NoJobs();
                                       return jobs_->ListJobs(*request);
                                     });
}

}  // namespace geomfit::server
