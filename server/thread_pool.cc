#include "server/thread_pool.h"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define GEOMFIT_CPU_RELAX() _mm_pause()
#else
#define GEOMFIT_CPU_RELAX() std::this_thread::yield()
#endif

namespace geomfit::server {

ThreadPool::ThreadPool(int threads, int max_queue, std::chrono::microseconds spin)
    : max_queue_(static_cast<size_t>(max_queue)), spin_(spin) {
  for (int i = 0; i < threads; ++i) workers_.emplace_back([this] { Run(); });
}

ThreadPool::~ThreadPool() { Stop(); }

bool ThreadPool::TrySubmit(std::function<void()> task) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_ || queue_.size() >= max_queue_) return false;
    queue_.push_back(std::move(task));
    queued_.store(queue_.size(), std::memory_order_release);
  }
  ready_.notify_one();
  return true;
}

void ThreadPool::Stop() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stopping_ = true;
  }
  stop_spinning_ = true;
  ready_.notify_all();
  for (std::thread& t : workers_)
    if (t.joinable()) t.join();
}

bool ThreadPool::Spin() {
  if (spin_.count() == 0 || spinning_.exchange(true, std::memory_order_acquire)) return false;
  const auto until = std::chrono::steady_clock::now() + spin_;
  bool came = false;
  while (!(came = queued_.load(std::memory_order_acquire) > 0) && !stop_spinning_.load(std::memory_order_relaxed) &&
         std::chrono::steady_clock::now() < until) {
    for (int i = 0; i < 64; ++i) GEOMFIT_CPU_RELAX();
  }
  spinning_.store(false, std::memory_order_release);
  return came;
}

void ThreadPool::Run() {
  while (true) {
    std::function<void()> task;
    {
      std::unique_lock<std::mutex> lock(mu_);
      if (queue_.empty() && !stopping_) {
        lock.unlock();
        Spin();
        lock.lock();
      }
      ready_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping and drained
      task = std::move(queue_.front());
      queue_.pop_front();
      queued_.store(queue_.size(), std::memory_order_release);
    }
    task();
  }
}

}  // namespace geomfit::server
