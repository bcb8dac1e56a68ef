#pragma once
// WatchJob's server-streaming reactor: writes a job's events as they are logged,
// without holding a thread while it waits. When it has written everything logged so
// far it leaves a one-shot subscription with the JobManager; the job thread that logs
// the next event calls it back. Ends after the final event, or when the client goes.
#include <deque>
#include <memory>
#include <mutex>
#include <string>

#include <grpcpp/grpcpp.h>

#include "absl/status/status.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/handlers/jobs.h"
#include "server/rpc/service.h"
#include "server/rpc/tenancy.h"

namespace geomfit::server {

class WatchJobReactor final : public grpc::ServerWriteReactor<v1::JobEvent> {
 public:
  /// Events read per visit to the log.
  static constexpr int kBatch = 64;

  WatchJobReactor(Service* service, grpc::CallbackServerContext* ctx, JobHandlers* jobs,
                  const v1::WatchJobRequest& request)
      : service_(service), jobs_(jobs), job_id_(request.job_id()), next_(request.from_event()) {
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
    std::unique_lock<std::mutex> lock(mu_);
    if (!s.ok()) {
      finished_ = true;
      lock.unlock();
      Finish(service_->Finish(call_, s));
      return;
    }
    Pump(lock);
  }

  void OnWriteDone(bool ok) override {
    std::unique_lock<std::mutex> lock(mu_);
    writing_ = false;
    if (!ok) broken_ = true;
    Pump(lock);
  }
  void OnCancel() override {
    std::unique_lock<std::mutex> lock(mu_);
    broken_ = true;
    Pump(lock);
  }
  void OnDone() override {
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
      finished_ = true;
      Withdraw();
      lock.unlock();
      Finish(service_->Finish(call_, absl::CancelledError("the client went away during the watch")));
      return;
    }
    if (queue_.empty()) {
      if (subscribed_) return;
      bool end = false;
      absl::StatusOr<std::vector<v1::JobEvent>> events =
          jobs_->ReadEvents(job_id_, next_, kBatch, &end, [this] { OnMore(); }, &subscription_);
      if (!events.ok()) {
        finished_ = true;
        lock.unlock();
        Finish(service_->Finish(call_, events.status()));
        return;
      }
      if (events->empty()) {  // subscribed: OnMore comes with the next event
        subscribed_ = true;
        return;
      }
      next_ = events->back().seq() + 1;
      for (v1::JobEvent& e : *events) queue_.push_back(std::move(e));
    }
    current_ = std::move(queue_.front());
    queue_.pop_front();
    UnscopeIds(tenant_, &current_);
    writing_ = true;
    call_.bytes_out += static_cast<int64_t>(current_.ByteSizeLong());
    if (current_.final()) {
      finished_ = true;
      lock.unlock();
      StartWriteAndFinish(&current_, grpc::WriteOptions(), service_->Finish(call_, absl::OkStatus()));
      return;
    }
    lock.unlock();
    StartWrite(&current_);
  }

  Service* service_;
  JobHandlers* jobs_;
  const std::string job_id_;
  std::string tenant_;
  int64_t next_;
  Service::Call call_{};
  std::mutex mu_;
  std::deque<v1::JobEvent> queue_;
  v1::JobEvent current_;
  uint64_t subscription_ = 0;
  bool writing_ = false, finished_ = false, broken_ = false, done_ = false, subscribed_ = false;
};

}  // namespace geomfit::server
