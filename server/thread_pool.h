#pragma once
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"

namespace geomfit::server {

/// Fixed-size pool with a bounded queue: numerics run here, never on gRPC threads.
///
/// Fair across tenants: each tenant's tasks wait in a queue of their own, and the
/// workers take one task per tenant in turn (round robin over the tenants with tasks
/// waiting), so a task waits for the tasks running and at most one task of each other
/// tenant with tasks waiting, however long their backlogs. One tenant (single-tenant
/// mode) is plain FIFO.
class ThreadPool {
 public:
  /// `spin`: how long one idle worker at a time polls for the next task before it
  /// sleeps (a time-stepping client's next update comes within a millisecond or so:
  /// it then starts at once, on a core that has not gone idle); 0 = never.
  /// `name` names the pool in its errors ("the compute queue is full").
  ThreadPool(int threads, int max_queue, std::chrono::microseconds spin = std::chrono::microseconds(0),
             std::string name = "compute");
  ~ThreadPool();  ///< runs the queued tasks, then joins
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  /// Submit as the single tenant ""; false (task not taken) if it is refused.
  bool TrySubmit(std::function<void()> task) { return Submit("", std::move(task)).ok(); }
  /// Queues `task` in `tenant`'s queue. RESOURCE_EXHAUSTED when the queue is full (a
  /// tenant with fewer than its share, --queue / tenants waiting, of the queued tasks
  /// is still admitted, so the queue holds at most about twice --queue); UNAVAILABLE
  /// once the pool is stopping.
  absl::Status Submit(const std::string& tenant, std::function<void()> task);
  /// `tenant`'s tasks queued or running.
  int Active(const std::string& tenant) const;
  /// Finishes queued tasks and joins the workers; later submissions are refused.
  void Stop();
  int size() const { return static_cast<int>(workers_.size()); }

 private:
  /// One tenant's tasks.
  struct Lane {
    std::deque<std::function<void()>> queued;
    int active = 0;  ///< queued + running
  };
  void Run();

  /// Polls for a task for up to spin_ unless another worker already does; true if one came.
  bool Spin();

  const size_t max_queue_;
  const std::chrono::microseconds spin_;
  const std::string name_;
  std::atomic<size_t> queued_{0};
  std::atomic<bool> spinning_{false};
  std::atomic<bool> stop_spinning_{false};  ///< set by Stop
  mutable std::mutex mu_;
  std::condition_variable ready_;
  std::map<std::string, Lane> lanes_;  ///< tenants with tasks queued or running
  std::deque<std::string> turns_;      ///< tenants with tasks queued, in serving order
  size_t total_queued_ = 0;
  bool stopping_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace geomfit::server
