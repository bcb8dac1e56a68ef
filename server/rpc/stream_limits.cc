#include "server/rpc/stream_limits.h"

#include <algorithm>

#include "absl/strings/str_cat.h"

namespace geomfit::server {

StreamLimits::StreamLimits(int64_t max_inflight_bytes, std::chrono::milliseconds idle)
    : limit_(max_inflight_bytes), idle_(idle) {
  if (idle_.count() > 0) thread_ = std::thread([this] { Run(); });
}

StreamLimits::~StreamLimits() {
  {
    std::lock_guard<std::mutex> lock(mu_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

absl::Status StreamLimits::Reserve(int64_t bytes) {
  int64_t now = reserved_.load();
  do {
    if (limit_ > 0 && now + bytes > limit_) {
      return absl::ResourceExhaustedError(absl::StrCat(
          "stream needs ", bytes, " bytes in flight; ", now, " of the ", limit_,
          " bytes of --max-inflight-bytes are reserved by other streams: retry later or send a smaller mesh"));
    }
  } while (!reserved_.compare_exchange_weak(now, now + bytes));
  return absl::OkStatus();
}

void StreamLimits::Release(int64_t bytes) { reserved_.fetch_sub(bytes); }

std::shared_ptr<StreamWatch> StreamLimits::Watch(std::function<bool()> expire) {
  if (idle_.count() <= 0) return nullptr;
  auto watch = std::make_shared<StreamWatch>();
  watch->expire = std::move(expire);
  std::lock_guard<std::mutex> lock(mu_);
  watched_.push_back(watch);
  return watch;
}

void StreamLimits::Run() {
  // Scans a few times per idle period: a stream ends between idle and 1.25 x idle
  // after its last message.
  const auto period = std::clamp<std::chrono::milliseconds>(idle_ / 4, std::chrono::milliseconds(10),
                                                             std::chrono::milliseconds(1000));
  std::unique_lock<std::mutex> lock(mu_);
  while (!cv_.wait_for(lock, period, [this] { return stop_; })) {
    std::vector<std::shared_ptr<StreamWatch>> watched = watched_;
    lock.unlock();
    const auto now = std::chrono::steady_clock::now();
    std::vector<const StreamWatch*> gone;
    for (const auto& w : watched) {
      std::lock_guard<std::recursive_mutex> stream(w->mu);
      if (!w->closed && now - w->last >= idle_ && w->expire()) w->closed = true;
      if (w->closed) gone.push_back(w.get());
    }
    lock.lock();
    watched_.erase(std::remove_if(watched_.begin(), watched_.end(),
                                  [&](const std::shared_ptr<StreamWatch>& w) {
                                    return std::find(gone.begin(), gone.end(), w.get()) != gone.end();
                                  }),
                   watched_.end());
  }
}

}  // namespace geomfit::server
