#include "server/workspace/evaluation.h"

#include <algorithm>
#include <chrono>
#include <utility>

namespace geomfit::server {

Evaluation::Evaluation(CacheKey key, std::shared_ptr<const Mesh> mesh, uint32_t mask)
    : key_(std::move(key)), mesh_(std::move(mesh)), num_vertices_(mesh_->NumVertices()), mask_(mask) {}

const std::shared_ptr<Differentials>& Evaluation::filling() {
  std::call_once(allocated_,
                 [&] { filling_ = std::make_shared<Differentials>(AllocateDifferentials(num_vertices_, mask_)); });
  return filling_;
}

void Evaluation::Filled(int64_t begin, int64_t end) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    pending_[begin] = end;
    for (auto it = pending_.find(filled_); it != pending_.end(); it = pending_.find(filled_)) {
      filled_ = it->second;
      pending_.erase(it);
    }
    // The last rows wake nobody: the end follows at once, and followers then have
    // nothing to send (the owner sends their last chunks).
    if (filled_ >= wake_at_ && filled_ < num_vertices_) {
      wake_at_ = std::numeric_limits<int64_t>::max();
      cv_.notify_all();
    }
  }
  if (listener_) listener_();
}

void Evaluation::Finish(absl::StatusOr<Evaluated> result) {
  std::map<int, EndHook> hooks;
  {
    std::lock_guard<std::mutex> lock(mu_);
    ended_ = true;
    result_ = std::move(result);
    if (result_.ok()) filled_ = num_vertices_;
    hooks.swap(hooks_);
    running_hooks_ = !hooks.empty();
    if (!running_hooks_) cv_.notify_all();
  }
  if (hooks.empty()) return;
  // Followers wake once their last chunks are out, not to compete with them for a core.
  for (auto& [handle, hook] : hooks) hook(result_);  // result_ no longer changes
  std::lock_guard<std::mutex> lock(mu_);
  running_hooks_ = false;
  cv_.notify_all();
}

int Evaluation::Follow(EndHook hook) {
  std::unique_lock<std::mutex> lock(mu_);
  const int handle = next_hook_++;
  if (!ended_) {
    hooks_.emplace(handle, std::move(hook));
    return handle;
  }
  lock.unlock();
  hook(result_);  // final once ended_ is set
  return handle;
}

bool Evaluation::Unfollow(int handle) {
  std::unique_lock<std::mutex> lock(mu_);
  if (hooks_.erase(handle) > 0) return false;
  cv_.wait(lock, [&] { return !running_hooks_; });
  return true;
}

int64_t Evaluation::filled() const {
  std::lock_guard<std::mutex> lock(mu_);
  return filled_;
}

absl::StatusOr<int64_t> Evaluation::WaitFor(int64_t rows, const CancellationToken& cancel) {
  std::unique_lock<std::mutex> lock(mu_);
  while (filled_ < rows && !ended_) {
    if (absl::Status s = cancel.Check(); !s.ok()) return s;
    wake_at_ = std::min(wake_at_, rows);
    // The token has no condition variable to signal: poll it between short waits.
    cv_.wait_for(lock, std::chrono::milliseconds(10));
  }
  return filled_;
}

bool Evaluation::ended() const {
  std::lock_guard<std::mutex> lock(mu_);
  return ended_;
}

absl::StatusOr<Evaluated> Evaluation::result() const {
  std::lock_guard<std::mutex> lock(mu_);
  return result_;
}

const Differentials* Evaluation::values() const {
  std::lock_guard<std::mutex> lock(mu_);
  if (ended_ && result_.ok()) return result_->values.get();
  return filled_ > 0 ? filling_.get() : nullptr;  // filled_ > 0: filling_ was set before
}

}  // namespace geomfit::server
