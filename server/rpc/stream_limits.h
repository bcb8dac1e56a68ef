#pragma once
// Bounded memory for streamed calls: the in-flight byte budget that client streams
// reserve their declared size against (--max-inflight-bytes) and that server streams'
// encoded chunks are counted in, the count of open streams, and the idle watchdog that
// ends streams silent (or unread) for --stream-idle-seconds.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/status/status.h"

namespace geomfit::server {

/// One watched stream. Its reactor guards its own state with `mu`; the watchdog calls
/// `expire` with `mu` held once `last` is older than the idle time, unless `closed` (the
/// reactor no longer waits on the client); `expire` returns whether it ended the call
/// (else it is asked again at the next scan).
struct StreamWatch {
  std::recursive_mutex mu;  ///< recursive: a reaction run inline from StartRead is safe
  std::chrono::steady_clock::time_point last = std::chrono::steady_clock::now();
  bool closed = false;
  std::function<bool()> expire;
  /// A message arrived or a write completed (call with `mu` held).
  void Touch() { last = std::chrono::steady_clock::now(); }
};

class StreamLimits {
 public:
  /// `max_inflight_bytes` 0: no budget; `idle` zero: no idle timeout (no thread).
  StreamLimits(int64_t max_inflight_bytes, std::chrono::milliseconds idle);
  ~StreamLimits();
  StreamLimits(const StreamLimits&) = delete;
  StreamLimits& operator=(const StreamLimits&) = delete;

  /// Reserves `bytes` for a stream, or RESOURCE_EXHAUSTED naming --max-inflight-bytes
  /// (nothing reserved) if they do not fit next to the other streams' reservations.
  absl::Status Reserve(int64_t bytes);
  void Release(int64_t bytes);
  /// Counts `bytes` a server stream holds (encoded messages not yet written) in the
  /// reserved bytes; never refused: such a stream holds at most two chunks.
  void Hold(int64_t bytes) { reserved_.fetch_add(bytes); }
  void Opened() { open_.fetch_add(1); }
  void Closed() { open_.fetch_sub(1); }

  /// A new watched stream; `expire` ends it (DEADLINE_EXCEEDED, or a cancel) once it
  /// has not been touched for the idle time. Null without an idle timeout.
  std::shared_ptr<StreamWatch> Watch(std::function<bool()> expire);

  int64_t reserved_bytes() const { return reserved_.load(); }
  int64_t open_streams() const { return open_.load(); }
  int64_t max_inflight_bytes() const { return limit_; }
  std::chrono::milliseconds idle() const { return idle_; }

 private:
  void Run();

  const int64_t limit_;
  const std::chrono::milliseconds idle_;
  std::atomic<int64_t> reserved_{0};
  std::atomic<int64_t> open_{0};
  std::mutex mu_;
  std::condition_variable cv_;
  bool stop_ = false;
  std::vector<std::shared_ptr<StreamWatch>> watched_;
  std::thread thread_;
};

/// One server stream's share of StreamLimits: open while it lives, and the bytes of its
/// encoded messages not yet written (Hold). Not thread-safe: guarded by the reactor's
/// lock. Null limits: counts nothing.
class StreamShare {
 public:
  explicit StreamShare(StreamLimits* limits) : limits_(limits) {
    if (limits_ != nullptr) limits_->Opened();
  }
  ~StreamShare() { Close(); }
  StreamShare(const StreamShare&) = delete;
  StreamShare& operator=(const StreamShare&) = delete;

  void Hold(int64_t bytes) {
    if (limits_ != nullptr) limits_->Hold(bytes);
    held_ += bytes;
  }
  void Release(int64_t bytes) {
    if (limits_ != nullptr) limits_->Release(bytes);
    held_ -= bytes;
  }
  /// Releases everything and stops counting the stream as open (once; before its
  /// status goes out, so a client that sees the end sees the accounting back).
  void Close() {
    Release(held_);
    if (limits_ != nullptr) limits_->Closed();
    limits_ = nullptr;
  }
  int64_t held() const { return held_; }

 private:
  StreamLimits* limits_;
  int64_t held_ = 0;
};

}  // namespace geomfit::server
