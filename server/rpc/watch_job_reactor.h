#pragma once
// WatchJob's server-streaming reactor: writes a job's events as they are logged,
// without holding a thread while it waits. When it has written everything logged so
// far it leaves a one-shot subscription with the JobManager; the job thread that logs
// the next event calls it back. Ends after the final event, or when the client goes.
// Bounded like every server stream: it holds at most one batch of events (counted in
// StreamLimits' in-flight bytes), and a watcher that takes no event for
// --stream-idle-seconds while one is being written is ended with DEADLINE_EXCEEDED (a
// watcher waiting for a quiet job is not idle: nothing is being written to it).
#include <chrono>
#include <deque>
#include <memory>
#include <mutex>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/handlers/jobs.h"
#include "server/rpc/reactors.h"
#include "server/rpc/service.h"
#include "server/rpc/stream_limits.h"
#include "server/rpc/tenancy.h"

namespace geomfit::server {

class WatchJobReactor final : public grpc::ServerWriteReactor<v1::JobEvent> {
 public:
  /// Events read per visit to the log.
  static constexpr int kBatch = 64;

  WatchJobReactor(Service* service, grpc::CallbackServerContext* ctx, JobHandlers* jobs,
                  const v1::WatchJobRequest& request)
      : service_(service), ctx_(ctx), jobs_(jobs), job_id_(request.job_id()), next_(request.from_event()),
        share_(service->stream_limits()) {
    call_.method = "WatchJob";
    call_.mesh_id = job_id_;
    service_->Begin();
    absl::StatusOr<CallContext> who = service_->Admit(ctx);
    absl::Status s = who.status();
    if (s.ok() && jobs_ == nullptr) s = absl::UnimplementedError("this server runs no jobs");
    if (s.ok()) {
      tenant_ = who->tenant;
      s = service_->OwnJob(*who, job_id_);
    }
    if (s.ok() && service_->stream_limits() != nullptr) {
      watch_ = service_->stream_limits()->Watch([this, idle = service_->stream_limits()->idle()] {
        return Stalled(idle);
      });
    }
    std::unique_lock<std::mutex> lock(mu_);
    if (!s.ok()) {
      End(lock, s);
      return;
    }
    Pump(lock);
  }

  void OnWriteDone(bool ok) override {
    std::unique_lock<std::mutex> lock(mu_);
    writing_ = false;
    share_.Release(current_bytes_);
    current_bytes_ = 0;
    if (!ok) broken_ = true;
    Pump(lock);
  }
  void OnCancel() override {
    std::unique_lock<std::mutex> lock(mu_);
    broken_ = true;
    Pump(lock);
  }
  void OnDone() override {
    if (watch_ != nullptr) {
      std::lock_guard<std::recursive_mutex> watch(watch_->mu);  // the watchdog is not in Stalled
      watch_->closed = true;
    }
    std::unique_lock<std::mutex> lock(mu_);
    done_ = true;
    Withdraw();
    if (subscribed_) return;  // the callback is under way: it deletes the reactor
    lock.unlock();
    delete this;
  }

 private:
  /// The job logged more (called once per subscription, from the logging thread).
  void OnMore() {
    std::unique_lock<std::mutex> lock(mu_);
    subscribed_ = false;
    if (done_) {
      lock.unlock();
      delete this;
      return;
    }
    Pump(lock);
  }
  /// Drops the subscription unless its callback already fired (then it is coming).
  void Withdraw() {
    if (subscribed_ && jobs_->manager()->Unsubscribe(job_id_, subscription_)) subscribed_ = false;
  }
  /// Writes the next event, subscribes for more, or finishes; unlocks before gRPC calls.
  void Pump(std::unique_lock<std::mutex>& lock) {
    if (writing_ || finished_) return;
    if (broken_) {
      Withdraw();
      End(lock, idle_ended_ ? idle_status_ : absl::CancelledError("the client went away during the watch"));
      return;
    }
    if (queue_.empty()) {
      if (subscribed_) return;
      bool end = false;
      absl::StatusOr<std::vector<v1::JobEvent>> events =
          jobs_->ReadEvents(job_id_, next_, kBatch, &end, [this] { OnMore(); }, &subscription_);
      if (!events.ok()) {
        End(lock, events.status());
        return;
      }
      if (events->empty()) {  // subscribed: OnMore comes with the next event
        subscribed_ = true;
        return;
      }
      next_ = events->back().seq() + 1;
      for (v1::JobEvent& e : *events) {
        share_.Hold(static_cast<int64_t>(e.ByteSizeLong()));
        queue_.push_back(std::move(e));
      }
    }
    current_ = std::move(queue_.front());
    queue_.pop_front();
    current_bytes_ = static_cast<int64_t>(current_.ByteSizeLong());  // held since it was read
    UnscopeIds(tenant_, &current_);
    writing_ = true;
    write_started_ = std::chrono::steady_clock::now();
    call_.bytes_out += static_cast<int64_t>(current_.ByteSizeLong());
    if (current_.final()) {
      finished_ = true;
      queue_.clear();
      share_.Close();
      lock.unlock();
      StartWriteAndFinish(&current_, grpc::WriteOptions(), service_->Finish(call_, absl::OkStatus()));
      return;
    }
    lock.unlock();
    StartWrite(&current_);
  }

  /// Finishes the call with `s` (lock held; unlocks): what it holds is released first.
  void End(std::unique_lock<std::mutex>& lock, const absl::Status& s) {
    finished_ = true;
    queue_.clear();
    share_.Close();
    lock.unlock();
    Finish(service_->Finish(call_, s));
  }
  /// The watchdog (watch mutex held): an event the watcher has not taken for `idle`.
  bool Stalled(std::chrono::milliseconds idle) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (!writing_ || std::chrono::steady_clock::now() - write_started_ < idle) return false;
      idle_ended_ = true;
      idle_status_ = IdleStatus(idle);
    }
    EndIdle(ctx_, idle_status_);
    return true;
  }

  Service* service_;
  grpc::CallbackServerContext* ctx_;
  JobHandlers* jobs_;
  const std::string job_id_;
  std::string tenant_;
  int64_t next_;
  Service::Call call_{};
  std::mutex mu_;
  StreamShare share_;
  std::shared_ptr<StreamWatch> watch_;
  std::chrono::steady_clock::time_point write_started_;
  bool idle_ended_ = false;  ///< ended by the watchdog, with idle_status_
  absl::Status idle_status_;
  std::deque<v1::JobEvent> queue_;
  v1::JobEvent current_;
  int64_t current_bytes_ = 0;
  uint64_t subscription_ = 0;
  bool writing_ = false, finished_ = false, broken_ = false, done_ = false, subscribed_ = false;
};

}  // namespace geomfit::server
