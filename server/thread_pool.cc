#include "server/thread_pool.h"

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#define GEOMFIT_CPU_RELAX() _mm_pause()
#else
#define GEOMFIT_CPU_RELAX() std::this_thread::yield()
#endif

#include <algorithm>

#include "absl/strings/str_cat.h"

namespace geomfit::server {

ThreadPool::ThreadPool(int threads, int max_queue, std::chrono::microseconds spin, std::string name)
    : max_queue_(static_cast<size_t>(max_queue)), spin_(spin), name_(std::move(name)) {
  for (int i = 0; i < threads; ++i) workers_.emplace_back([this] { Run(); });
}

ThreadPool::~ThreadPool() { Stop(); }

absl::Status ThreadPool::Submit(const std::string& tenant, std::function<void()> task) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_) return absl::UnavailableError(absl::StrCat("server is stopping: the ", name_, " pool takes no task"));
    Lane& lane = lanes_[tenant];  // erased below if refused while empty
    absl::Status refused;
    if (total_queued_ >= max_queue_) {
      // A full queue still admits a tenant below its share, so one tenant's backlog
      // cannot lock the others out.
      const size_t waiting = turns_.size() + (lane.queued.empty() ? 1 : 0);
      if (lane.queued.size() >= std::max<size_t>(1, max_queue_ / waiting)) {
        refused = absl::ResourceExhaustedError(
            absl::StrCat("server busy: the ", name_, " queue is full (--queue); retry later"));
      }
    }
    if (!refused.ok()) {
      if (lane.active == 0) lanes_.erase(tenant);
      return refused;
    }
    if (lane.queued.empty()) turns_.push_back(tenant);
    lane.queued.push_back(std::move(task));
    ++lane.active;
    queued_.store(++total_queued_, std::memory_order_release);
  }
  ready_.notify_one();
  return absl::OkStatus();
}

int ThreadPool::Active(const std::string& tenant) const {
  std::lock_guard<std::mutex> lock(mu_);
  const auto it = lanes_.find(tenant);
  return it == lanes_.end() ? 0 : it->second.active;
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
    std::string tenant;
    {
      std::unique_lock<std::mutex> lock(mu_);
      if (turns_.empty() && !stopping_) {
        lock.unlock();
        Spin();
        lock.lock();
      }
      ready_.wait(lock, [this] { return stopping_ || !turns_.empty(); });
      if (turns_.empty()) return;  // stopping and drained
      // Round robin: the next tenant's oldest task; the tenant goes to the back of the
      // line if it has more.
      tenant = std::move(turns_.front());
      turns_.pop_front();
      Lane& lane = lanes_[tenant];
      task = std::move(lane.queued.front());
      lane.queued.pop_front();
      if (!lane.queued.empty()) turns_.push_back(tenant);
      queued_.store(--total_queued_, std::memory_order_release);
    }
    task();
    task = nullptr;  // what the task holds goes before its tenant's lane can
    std::lock_guard<std::mutex> lock(mu_);
    const auto it = lanes_.find(tenant);
    if (--it->second.active == 0) lanes_.erase(it);
  }
}

}  // namespace geomfit::server
