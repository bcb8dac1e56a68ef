#pragma once
// Generic callback reactors of the service: client-streaming (ReadReactor) and
// server-streaming (WriteReactor: chunks pushed by work on a pool; PullReactor: chunks
// pulled from a source) calls, plus the call token. Every server stream holds at most
// two encoded chunks, counted in the in-flight bytes (StreamLimits).
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <grpc/grpc.h>
#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "core/util/cancel.h"
#include "server/handlers/handlers.h"
#include "server/rpc/service.h"
#include "server/rpc/stream_limits.h"
#include "server/rpc/tenancy.h"
#include "server/thread_pool.h"

namespace geomfit::server {

/// A token that trips at the call's deadline (and when Cancel is called).
inline std::unique_ptr<CancellationToken> DeadlineToken(grpc::CallbackServerContext* ctx) {
  const auto deadline = ctx->deadline();
  if (deadline >= std::chrono::system_clock::time_point::max() - std::chrono::hours(24 * 365)) {
    return std::make_unique<CancellationToken>();
  }
  const auto left = deadline - std::chrono::system_clock::now();
  return std::make_unique<CancellationToken>(
      std::chrono::steady_clock::now() + std::chrono::duration_cast<std::chrono::steady_clock::duration>(left));
}

/// A token that trips at the call's deadline and when the client cancels the call (or
/// the server shuts down past its drain time): unary calls get no OnCancel, so the token
/// polls the context, which gRPC allows from any thread until the call is finished; the
/// token must not outlive the call (a unary call's work returns before it answers).
inline std::unique_ptr<CancellationToken> TokenFor(grpc::CallbackServerContext* ctx) {
  std::unique_ptr<CancellationToken> token = DeadlineToken(ctx);
  token->SetPoll([ctx] { return ctx->IsCancelled(); });
  return token;
}

/// Admits a server-streaming call and scopes its request's mesh ids to the caller's
/// tenant (gRPC hands the request over for the call's lifetime); returns the tenant.
inline absl::StatusOr<std::string> AdmitStream(Service* service, grpc::CallbackServerContext* ctx,
                                               const google::protobuf::Message* request) {
  absl::StatusOr<CallContext> who = service->Admit(ctx);
  if (!who.ok()) return who.status();
  ScopeIds(who->tenant, const_cast<google::protobuf::Message*>(request));
  return who->tenant;
}

/// How a server stream whose reader took nothing for `idle` ends (the watchdog).
inline absl::Status IdleStatus(std::chrono::milliseconds idle) {
  return absl::DeadlineExceededError(absl::StrCat("the reader took no message for ",
                                                  std::chrono::duration<double>(idle).count(),
                                                  " s (--stream-idle-seconds); stream ended"));
}

/// Ends a server stream with `status` at once: the call is cancelled with it, so the
/// status goes out with RST_STREAM ahead of the data the reader left unread (a Finish
/// would wait behind it). The pending write then fails and the reactor ends as after a
/// cancel, dropping what it holds.
inline void EndIdle(grpc::CallbackServerContext* ctx, const absl::Status& status) {
  const std::string message(status.message());
  grpc_call_cancel_with_status(ctx->c_call(), static_cast<grpc_status_code>(status.code()), message.c_str(),
                               nullptr);
}

/// What the server-streaming reactors (WriteReactor, PullReactor) share: the call's
/// record, its tenant, its share of StreamLimits and its idle watch, and the prologue
/// that sets them up (Open) and the watch's end (CloseWatch).
class ServerStreamBase {
 protected:
  ServerStreamBase(Service* service, grpc::CallbackServerContext* ctx, Service::Call call)
      : service_(service), ctx_(ctx), call_(std::move(call)), share_(service->stream_limits()) {}

  /// Counts the call (Service::Begin), admits it and scopes `request`'s mesh ids to the
  /// caller's tenant (AdmitStream), then, with an idle timeout, watches it: the
  /// watchdog calls `stalled(idle)` with the watch's mutex held. An error: the call is
  /// to end with it at once.
  absl::Status Open(const google::protobuf::Message* request, std::function<bool(std::chrono::milliseconds)> stalled) {
    service_->Begin();
    absl::StatusOr<std::string> tenant = AdmitStream(service_, ctx_, request);
    if (!tenant.ok()) return tenant.status();
    tenant_ = *std::move(tenant);
    if (StreamLimits* limits = service_->stream_limits(); limits != nullptr) {
      watch_ = limits->Watch([stalled = std::move(stalled), idle = limits->idle()] { return stalled(idle); });
    }
    return absl::OkStatus();
  }
  /// From OnDone: the watchdog is not inside `stalled` and never calls it again.
  void CloseWatch() {
    if (watch_ == nullptr) return;
    std::lock_guard<std::recursive_mutex> lock(watch_->mu);
    watch_->closed = true;
  }

  Service* service_;
  grpc::CallbackServerContext* ctx_;
  Service::Call call_;
  std::string tenant_;
  StreamShare share_;
  std::shared_ptr<StreamWatch> watch_;
};

/// Client-streaming call, read as raw bytes so that a message that does not parse ends
/// the call with INVALID_ARGUMENT (the typed API reports it like the end of the stream).
/// Messages are folded into an Assembler on the gRPC thread (cheap copies); once the
/// header is in, the stream reserves the bytes it declares against the in-flight budget
/// (StreamLimits) before buffering anything; a stream silent for the idle time ends with
/// DEADLINE_EXCEEDED. The header's lookup (`on_header`, which reads the store) runs on
/// the io pool, never on a gRPC thread: the next read starts once it is done (the
/// reservation itself is an O(1) atomic). The end of the stream runs `finish` on the
/// compute pool. Every end releases the reservation before the status goes out, and
/// nothing is committed unless the whole stream parsed and assembled.
template <typename Request, typename Assembler>
class ReadReactor final : public grpc::ServerReadReactor<grpc::ByteBuffer> {
 public:
  using FinishFn = std::function<absl::StatusOr<v1::MeshInfo>(const Assembler&, const CallContext&)>;
  /// Runs on the compute thread once the call is answered (OK only).
  using AfterFn = std::function<void(const v1::MeshInfo&)>;
  /// Once the header is in, before any rows: tells the assembler how many rows to expect
  /// (update streams look up their mesh). Optional.
  using HeaderFn = std::function<absl::Status(Assembler*)>;

  ReadReactor(Service* service, grpc::CallbackServerContext* ctx, grpc::ByteBuffer* response, const char* method,
              FinishFn finish, AfterFn after = nullptr, HeaderFn on_header = nullptr)
      : service_(service), ctx_(ctx), response_(response), limits_(service->stream_limits()),
        finish_(std::move(finish)), after_(std::move(after)), on_header_(std::move(on_header)) {
    assembler_.emplace(service->handlers()->options().max_vertices);
    service_->Begin();
    call_.method = method;
    if (limits_ != nullptr) {
      limits_->Opened();
      watch_ = limits_->Watch([this] { return Expire(); });
    }
    Lock lock = Locked();
    absl::StatusOr<CallContext> who = service_->Admit(ctx);
    if (!who.ok()) {
      Done(who.status());
      return;
    }
    who_ = *std::move(who);
    this->StartRead(&buffer_);
  }

  void OnReadDone(bool ok) override {
    Lock lock = Locked();
    if (ended_) return;  // expired meanwhile
    if (watch_ != nullptr) watch_->Touch();
    if (ok) {
      const absl::Status s = Take();
      if (!s.ok()) return Done(s);
      if (header_in_) return Header();
      this->StartRead(&buffer_);
      return;
    }
    if (ctx_->IsCancelled()) return Done(absl::CancelledError("client cancelled the stream; nothing stored"));
    if (watch_ != nullptr) watch_->closed = true;  // received in full: no longer idle
    if (absl::Status slot = service_->TakeComputeSlot(who_.tenant, &call_); !slot.ok()) return Done(slot);
    const absl::Status queued = service_->compute()->Submit(who_.tenant, [this] {
      absl::StatusOr<v1::MeshInfo> info = finish_(*assembler_, who_);
      if (info.ok()) UnscopeIds(who_.tenant, &*info);
      if (info.ok()) {
        call_.mesh_id = info->mesh_id();
        bool own = false;
        grpc::SerializationTraits<v1::MeshInfo>::Serialize(*info, response_, &own);
      }
      AfterFn after = std::move(after_);  // `this` may be gone once Done returns
      Lock lock = Locked();
      Done(info.status());
      lock = Lock();
      if (after && info.ok()) after(*info);
    });
    if (!queued.ok()) Done(queued);
  }

  void OnDone() override {
    {
      Lock lock = Locked();  // the watchdog is not inside Expire
      if (watch_ != nullptr) watch_->closed = true;
    }
    delete this;
  }

 private:
  using Lock = std::unique_lock<std::recursive_mutex>;
  /// The watch's mutex (shared with the watchdog), or the reactor's own.
  Lock Locked() { return Lock(watch_ != nullptr ? watch_->mu : mu_); }

  /// Parses message `count_` and folds it in; header_in_ once it brought the header.
  absl::Status Take() {
    ++count_;
    call_.bytes_in += static_cast<int64_t>(buffer_.Length());
    Request request;
    const grpc::Status parsed = grpc::SerializationTraits<Request>::Deserialize(&buffer_, &request);
    buffer_.Clear();
    if (!parsed.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("message ", count_, " of the stream is not a valid ",
                                                     Request::descriptor()->full_name(), "; nothing stored"));
    }
    ScopeIds(who_.tenant, &request);
    const bool had_header = assembler_->has_header();
    GF_RETURN_IF_ERROR(assembler_->Add(request));
    header_in_ = !had_header && assembler_->has_header();
    return absl::OkStatus();
  }

  /// The header is in (lock held, no read pending): `on_header_` runs on the io pool,
  /// unlocked (nothing else touches the assembler meanwhile: no read is pending, and
  /// the watchdog waits while busy_), then the declared size is reserved and reading
  /// resumes.
  void Header() {
    header_in_ = false;
    if (!on_header_) return Resume(Reserve());
    busy_ = true;
    const absl::Status queued = service_->io()->Submit(who_.tenant, [this] {
      const absl::Status looked_up = on_header_(&*assembler_);
      Lock lock = Locked();
      busy_ = false;
      if (watch_ != nullptr) watch_->Touch();  // the client waited for us, not we for it
      Resume(looked_up.ok() ? Reserve() : looked_up);
    });
    if (!queued.ok()) {
      busy_ = false;
      Done(queued);
    }
  }
  /// Reserves the declared size against the budget.
  absl::Status Reserve() {
    if (limits_ == nullptr) return absl::OkStatus();
    const int64_t bytes = assembler_->DeclaredBytes();
    GF_RETURN_IF_ERROR(limits_->Reserve(bytes));
    reserved_ = bytes;
    return absl::OkStatus();
  }
  /// Reads on after the header, or ends the call (lock held).
  void Resume(const absl::Status& s) {
    if (!s.ok()) return Done(s);
    this->StartRead(&buffer_);
  }

  /// The watchdog: no message for the idle time (the watch's mutex is held); asks again
  /// later while the header is looked up.
  bool Expire() {
    if (busy_) return false;
    if (ended_) return true;
    const double seconds = std::chrono::duration<double>(limits_->idle()).count();
    Done(absl::DeadlineExceededError(absl::StrCat("no message for ", seconds,
                                                  " s (--stream-idle-seconds); stream ended, nothing stored")));
    return true;
  }

  /// Ends the call once (lock held, or the stream is received in full): releases the
  /// reservation and the buffered rows before the status goes out.
  void Done(const absl::Status& s) {
    if (ended_) return;
    ended_ = true;
    if (call_.mesh_id.empty()) call_.mesh_id = assembler_->mesh_id();
    assembler_.reset();
    if (limits_ != nullptr) {
      limits_->Release(reserved_);
      reserved_ = 0;
      limits_->Closed();
    }
    this->Finish(service_->Finish(call_, s));
  }

  Service* service_;
  grpc::CallbackServerContext* ctx_;
  grpc::ByteBuffer* response_;
  StreamLimits* limits_;
  std::shared_ptr<StreamWatch> watch_;
  std::recursive_mutex mu_;
  grpc::ByteBuffer buffer_;
  std::optional<Assembler> assembler_;
  FinishFn finish_;
  AfterFn after_;
  HeaderFn on_header_;
  CallContext who_;
  Service::Call call_{};
  int64_t count_ = 0;     ///< messages received
  int64_t reserved_ = 0;  ///< bytes held in the budget
  bool header_in_ = false;  ///< the last message brought the header
  bool busy_ = false;       ///< the header is being looked up on the io pool
  bool ended_ = false;
};

/// Server-streaming call: `work` runs on a pool thread (polling the call's token) and
/// hands over chunks as they are ready; each is written as soon as the previous write
/// is done, while the work goes on. Bounded whatever the reader does: a lazy chunk
/// (PushLazy) is encoded only when the previous write is done, on the thread that saw
/// it complete, and an eager one (Push) waits while kMaxHeld encoded chunks are held
/// (woken by a completed write, a cancel, the idle watchdog or the server's shutdown).
/// So a reader that stops reading makes the stream hold at most two encoded chunks
/// (counted in StreamLimits' in-flight bytes) plus what the lazy ones read; once a write
/// has waited for the idle time the call ends with DEADLINE_EXCEEDED and the chunks
/// not written are dropped. The chunk pushed as `last` goes out together with OK at
/// once, from the thread that pushed it (or that saw the write before it complete),
/// even while the work is still returning. The reactor is deleted once both gRPC is
/// done with it (OnDone) and the work has returned. The work may thus outlive the call's
/// context (gRPC frees it after OnDone), so its token never polls the context: OnCancel
/// (client, deadline, shutdown, idle watchdog) and OnDone trip it, and it checks the
/// deadline itself.
template <typename Response>
class WriteReactor final : public grpc::ServerWriteReactor<Response>,
                           private ChunkSink<Response>,
                           private ServerStreamBase {
 public:
  using WorkFn = std::function<absl::Status(const CancellationToken&, ChunkSink<Response>*)>;
  /// Encoded chunks held at most: the one being written and one eager chunk queued.
  static constexpr int kMaxHeld = 2;

  /// `request`'s mesh ids are scoped to the caller's tenant before `work` runs (gRPC
  /// hands the request over for the call's lifetime); the chunks' are unscoped.
  WriteReactor(Service* service, grpc::CallbackServerContext* ctx, ThreadPool* pool, Service::Call call,
               const google::protobuf::Message* request, WorkFn work)
      : ServerStreamBase(service, ctx, std::move(call)), token_(DeadlineToken(ctx)), work_(std::move(work)) {
    if (absl::Status admitted = Open(request, [this](std::chrono::milliseconds idle) { return Stalled(idle); });
        !admitted.ok()) {
      Done(admitted);
      return;
    }
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
    share_.Release(current_bytes_);
    current_bytes_ = 0;
    current_ = Response();  // its memory goes now, not at the next write
    if (!ok) {
      broken_ = true;
      DropQueue();
      token_->Cancel();
    }
    room_.notify_all();
    Pump(lock);
  }
  void OnCancel() override {
    token_->Cancel();
    std::lock_guard<std::mutex> lock(mu_);
    room_.notify_all();
  }
  void OnDone() override {
    CloseWatch();
    token_->Cancel();  // the call is over: what the work does next goes nowhere
    std::unique_lock<std::mutex> lock(mu_);
    done_ = true;
    room_.notify_all();
    if (working_) return;  // the work deletes it when it returns
    lock.unlock();
    delete this;
  }

 private:
  /// A chunk pushed and not written yet: encoded (eager, `bytes` held) or to be made.
  struct Pending {
    std::optional<Response> chunk;
    std::function<Response()> make;
    int64_t bytes = 0;
  };

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
  /// Waits while kMaxHeld encoded chunks are held (the bounded wait also sees the
  /// call's deadline); drops the chunk once the call is over.
  void Push(Response chunk, bool last) override {
    std::unique_lock<std::mutex> lock(mu_);
    while (!Over() && eager_ + (writing_ ? 1 : 0) >= kMaxHeld) room_.wait_for(lock, std::chrono::milliseconds(50));
    if (Over()) return;
    const auto bytes = static_cast<int64_t>(chunk.ByteSizeLong());
    share_.Hold(bytes);
    ++eager_;
    queue_.push_back(Pending{std::move(chunk), nullptr, bytes});
    last_queued_ = last_queued_ || last;
    Pump(lock);
  }
  void PushLazy(std::function<Response()> make, bool last) override {
    std::unique_lock<std::mutex> lock(mu_);
    if (broken_ || finished_) return;
    queue_.push_back(Pending{std::nullopt, std::move(make), 0});
    last_queued_ = last_queued_ || last;
    Pump(lock);
  }
  /// The call is over for the work's chunks (lock held).
  bool Over() const { return broken_ || finished_ || done_ || token_->IsCancelled(); }
  /// Drops the chunks not written (lock held): the lazy ones let go of what they read.
  void DropQueue() {
    for (const Pending& p : queue_) share_.Release(p.bytes);
    queue_.clear();
    eager_ = 0;
  }
  /// Starts the next write (encoding a lazy chunk now), or finishes the call, if the
  /// state allows; unlocks first. Everything held is released before the status goes.
  void Pump(std::unique_lock<std::mutex>& lock) {
    if (writing_ || finished_) return;
    absl::Status end;
    if (broken_) {
      if (!returned_) return;
      end = idle_ended_ ? idle_status_ : absl::CancelledError("client went away during the response stream");
    } else if (returned_ && !last_queued_ && (!end_.ok() || queue_.empty())) {
      end = end_;  // an error drops the chunks not written yet
    } else {
      if (queue_.empty()) return;
      const bool final = last_queued_ && queue_.size() == 1;
      Pending next = std::move(queue_.front());
      queue_.pop_front();
      if (next.make) {
        current_ = next.make();
      } else {
        current_ = *std::move(next.chunk);
        share_.Release(next.bytes);
        --eager_;
      }
      next = Pending();  // a lazy chunk lets go of what it read
      UnscopeIds(tenant_, &current_);
      current_bytes_ = static_cast<int64_t>(current_.ByteSizeLong());
      share_.Hold(current_bytes_);
      writing_ = true;
      write_started_ = std::chrono::steady_clock::now();
      finished_ = final;
      call_.bytes_out += current_bytes_;
      if (final) share_.Close();
      lock.unlock();
      if (!final) return this->StartWrite(&current_);
      return this->StartWriteAndFinish(&current_, grpc::WriteOptions(), service_->Finish(call_, absl::OkStatus()));
    }
    finished_ = true;
    DropQueue();
    share_.Close();
    room_.notify_all();
    lock.unlock();
    Done(end);
  }
  void Done(const absl::Status& s) {
    share_.Close();  // no-op after Pump's
    this->Finish(service_->Finish(call_, s));
  }
  /// The watchdog (watch mutex held): a write the reader has not taken for `idle` means
  /// a reader that stopped reading; the call ends (EndIdle), dropping the chunks.
  bool Stalled(std::chrono::milliseconds idle) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (!writing_ || std::chrono::steady_clock::now() - write_started_ < idle) return false;
      token_->Cancel();
      idle_ended_ = true;
      idle_status_ = IdleStatus(idle);
      room_.notify_all();
    }
    EndIdle(ctx_, idle_status_);
    return true;
  }

  std::chrono::steady_clock::time_point write_started_;
  std::unique_ptr<CancellationToken> token_;
  WorkFn work_;
  std::mutex mu_;
  std::condition_variable room_;  ///< a held chunk was written, or the call is over
  std::deque<Pending> queue_;
  int eager_ = 0;  ///< encoded chunks in queue_
  Response current_;
  int64_t current_bytes_ = 0;
  bool writing_ = false, last_queued_ = false, broken_ = false, finished_ = false;
  bool returned_ = false;  ///< the work returned (its status is end_)
  bool working_ = false;   ///< the work was submitted and Run has not let go of the reactor
  bool done_ = false;      ///< OnDone was called
  bool idle_ended_ = false;  ///< ended by the idle watchdog (with idle_status_)
  absl::Status idle_status_;
  absl::Status end_;
};

/// Server-streaming call whose chunks come from a ChunkSource one at a time, the next
/// made when the previous write is done (flow control): `open` runs on `pool`, each
/// further chunk on the gRPC thread that saw the write complete. A reader that stops
/// reading holds the source and two chunks (counted in StreamLimits' in-flight bytes);
/// with an idle timeout, a reader that takes no chunk for that long is ended with
/// DEADLINE_EXCEEDED.
template <typename Response>
class PullReactor final : public grpc::ServerWriteReactor<Response>, private ServerStreamBase {
 public:
  using OpenFn = std::function<absl::StatusOr<std::unique_ptr<ChunkSource<Response>>>()>;

  /// `request`'s mesh ids are scoped to the caller's tenant before `open` runs.
  PullReactor(Service* service, grpc::CallbackServerContext* ctx, ThreadPool* pool, Service::Call call,
              const google::protobuf::Message* request, OpenFn open)
      : ServerStreamBase(service, ctx, std::move(call)), open_(std::move(open)) {
    if (absl::Status admitted = Open(request, [this](std::chrono::milliseconds idle) { return Stalled(idle); });
        !admitted.ok()) {
      Done(admitted);
      return;
    }
    if (absl::Status queued = pool->Submit(tenant_, [this] { Start(); }); !queued.ok()) Done(queued);
  }

  void OnWriteDone(bool ok) override {
    if (watch_ != nullptr) {
      std::lock_guard<std::recursive_mutex> lock(watch_->mu);
      watch_->Touch();
    }
    if (!ok) {
      if (idle_ended_.load()) return Done(idle_status_);
      return Done(absl::CancelledError("client went away during the response stream"));
    }
    WriteNext();
  }
  void OnDone() override {
    CloseWatch();
    delete this;
  }

 private:
  void Start() {
    absl::StatusOr<std::unique_ptr<ChunkSource<Response>>> source = open_();
    if (!source.ok()) return Done(source.status());
    source_ = *std::move(source);
    has_next_ = source_->Next(&next_);
    WriteNext();
  }
  /// Writes the chunk made ahead and makes the one after it: the last goes out with OK.
  void WriteNext() {
    if (!has_next_) return Done(absl::OkStatus());  // an empty source
    std::swap(current_, next_);
    has_next_ = source_->Next(&next_);
    UnscopeIds(tenant_, &current_);
    const auto bytes = static_cast<int64_t>(current_.ByteSizeLong());
    call_.bytes_out += bytes;
    share_.Release(share_.held());
    share_.Hold(bytes + (has_next_ ? static_cast<int64_t>(next_.ByteSizeLong()) : 0));
    if (has_next_) return this->StartWrite(&current_);
    source_.reset();
    finished_ = true;
    share_.Close();
    this->StartWriteAndFinish(&current_, grpc::WriteOptions(), service_->Finish(call_, absl::OkStatus()));
  }
  void Done(const absl::Status& s) {
    if (finished_) return;
    finished_ = true;
    source_.reset();
    share_.Close();
    this->Finish(service_->Finish(call_, s));
  }
  /// The watchdog (watch mutex held): the reader took no chunk for `idle`; the call ends
  /// (EndIdle).
  bool Stalled(std::chrono::milliseconds idle) {
    idle_status_ = IdleStatus(idle);
    idle_ended_.store(true);
    EndIdle(ctx_, idle_status_);
    return true;
  }

  OpenFn open_;
  std::atomic<bool> idle_ended_{false};  ///< ended by the watchdog, with idle_status_
  absl::Status idle_status_;
  std::unique_ptr<ChunkSource<Response>> source_;
  Response current_, next_;
  bool has_next_ = false;
  bool finished_ = false;
};

}  // namespace geomfit::server
