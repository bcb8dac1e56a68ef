#pragma once
// Generic callback reactors of the service: client-streaming (ReadReactor) and
// server-streaming (WriteReactor) calls whose work runs on a pool, plus the call token.
// Job event streams reuse WriteReactor.
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "core/util/cancel.h"
#include "server/handlers/handlers.h"
#include "server/rpc/service.h"
#include "server/rpc/tenancy.h"
#include "server/thread_pool.h"

namespace geomfit::server {

/// A token that trips at the call's deadline and when the client cancels the call (or
/// the server shuts down past its drain time): unary calls get no OnCancel, so the token
/// polls the context, which gRPC allows from any thread until the call is finished.
inline std::unique_ptr<CancellationToken> TokenFor(grpc::CallbackServerContext* ctx) {
  const auto deadline = ctx->deadline();
  std::unique_ptr<CancellationToken> token;
  if (deadline >= std::chrono::system_clock::time_point::max() - std::chrono::hours(24 * 365)) {
    token = std::make_unique<CancellationToken>();
  } else {
    const auto left = deadline - std::chrono::system_clock::now();
    token = std::make_unique<CancellationToken>(
        std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(left));
  }
  token->SetPoll([ctx] { return ctx->IsCancelled(); });
  return token;
}

/// Client-streaming call: messages are folded into an Assembler on the gRPC thread
/// (cheap copies); the end of the stream runs `finish` on the compute pool.
template <typename Request, typename Assembler>
class ReadReactor final : public grpc::ServerReadReactor<Request> {
 public:
  using FinishFn = std::function<absl::StatusOr<v1::MeshInfo>(const Assembler&, const CallContext&)>;
  /// Runs on the compute thread once the call is answered (OK only).
  using AfterFn = std::function<void(const v1::MeshInfo&)>;

  ReadReactor(Service* service, grpc::CallbackServerContext* ctx, v1::MeshInfo* response, const char* method,
              FinishFn finish, AfterFn after = nullptr)
      : service_(service), ctx_(ctx), response_(response), assembler_(service->handlers()->options().max_vertices),
        finish_(std::move(finish)), after_(std::move(after)) {
    service_->Begin();
    call_.method = method;
    absl::StatusOr<CallContext> who = service_->Admit(ctx);
    if (!who.ok()) {
      Done(who.status());
      return;
    }
    who_ = *std::move(who);
    this->StartRead(&request_);
  }

  void OnReadDone(bool ok) override {
    if (ok) {
      ScopeIds(who_.tenant, &request_);
      absl::Status s = assembler_.Add(request_);
      if (!s.ok()) return Done(s);
      request_.Clear();
      this->StartRead(&request_);
      return;
    }
    if (ctx_->IsCancelled()) return Done(absl::CancelledError("client cancelled the stream; nothing stored"));
    call_.bytes_in = assembler_.bytes();
    if (absl::Status slot = service_->TakeComputeSlot(who_.tenant, &call_); !slot.ok()) return Done(slot);
    const absl::Status queued = service_->compute()->Submit(who_.tenant, [this] {
      absl::StatusOr<v1::MeshInfo> info = finish_(assembler_, who_);
      if (info.ok()) UnscopeIds(who_.tenant, &*info);
      if (info.ok()) {
        call_.mesh_id = info->mesh_id();
        *response_ = *info;
      }
      AfterFn after = std::move(after_);  // `this` may be gone once Done returns
      Done(info.status());
      if (after && info.ok()) after(*info);
    });
    if (!queued.ok()) Done(queued);
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
  CallContext who_;
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

  /// `request`'s mesh ids are scoped to the caller's tenant before `work` runs (gRPC
  /// hands the request over for the call's lifetime); the chunks' are unscoped.
  WriteReactor(Service* service, grpc::CallbackServerContext* ctx, ThreadPool* pool, Service::Call call,
               const google::protobuf::Message* request, WorkFn work)
      : service_(service), token_(TokenFor(ctx)), work_(std::move(work)), call_(std::move(call)) {
    service_->Begin();
    absl::StatusOr<CallContext> who = service_->Admit(ctx);
    if (!who.ok()) {
      Done(who.status());
      return;
    }
    tenant_ = who->tenant;
    ScopeIds(tenant_, const_cast<google::protobuf::Message*>(request));
    if (pool == service->compute()) {
      if (absl::Status slot = service_->TakeComputeSlot(tenant_, &call_); !slot.ok()) {
        Done(slot);
        return;
      }
    }
    working_ = true;
    if (absl::Status queued = pool->Submit(tenant_, [this] { Run(); }); !queued.ok()) {
      working_ = false;
      Done(queued);
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
      UnscopeIds(tenant_, &current_);
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
  std::string tenant_;
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

}  // namespace geomfit::server
