#pragma once
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
  ThreadPool(int threads, int max_queue);
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

  const size_t max_queue_;
  std::mutex mu_;
  std::condition_variable ready_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> workers_;
};

}  // namespace geomfit::server
