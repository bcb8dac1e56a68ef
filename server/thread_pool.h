#pragma once
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace geomfit::server {

/// Fixed-size pool with a bounded queue: numerics run here, never on gRPC threads.
class ThreadPool {
 public:
  /// `spin`: how long one idle worker at a time polls for the next task before it
  /// sleeps (a time-stepping client's next update comes within a millisecond or so:
  /// it then starts at once, on a core that has not gone idle); 0 = never.
  ThreadPool(int threads, int max_queue, std::chrono::microseconds spin = std::chrono::microseconds(0));
  ~ThreadPool();  ///< runs the queued tasks, then joins
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  /// false (task not taken) when the queue is full or the pool is stopping.
  bool TrySubmit(std::function<void()> task);
  /// Finishes queued tasks and joins the workers; later submissions are refused.
  void Stop();
  int size() const { return static_cast<int>(workers_.size()); }

 private:
  void Run();

  /// Polls for a task for up to spin_ unless another worker already does; true if one came.
  bool Spin();

  const size_t max_queue_;
  const std::chrono::microseconds spin_;
  std::atomic<size_t> queued_{0};
  std::atomic<bool> spinning_{false};
  std::atomic<bool> stop_spinning_{false};  ///< set by Stop
  std::mutex mu_;
  std::condition_variable ready_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace geomfit::server
