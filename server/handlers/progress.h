#pragma once
// Progress of a request in its own response stream (proto message Progress): a
// RunContext's reports, which come from many threads out of order and thousands of times
// a second, thinned to what a client wants to draw.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <functional>
#include <mutex>
#include <string>
#include <utility>

#include "absl/status/statusor.h"
#include "core/util/cancel.h"
#include "core/util/run_context.h"
#include "geomfit/v1/geomfit.pb.h"
#include "server/handlers/handlers.h"

namespace geomfit::server {

/// Passes on, per named phase, the first report, the last (done = total) and between them at
/// most one every `interval`, with `done` never decreasing; reports behind the latest
/// (threads finishing out of order) are dropped. `emit` runs under a lock, so its calls
/// are serialized and in order. Thread-safe.
class ProgressThrottle {
 public:
  using EmitFn = std::function<void(const Progress&)>;
  explicit ProgressThrottle(EmitFn emit, std::chrono::milliseconds interval = std::chrono::milliseconds(100))
      : emit_(std::move(emit)), interval_(interval) {}

  void Report(const Progress& p) {
    if (p.phase.empty()) return;  // a loop that names no phase
    std::lock_guard<std::mutex> lock(mu_);
    const auto now = std::chrono::steady_clock::now();
    const bool first = !started_ || p.phase != phase_;
    if (!first && (p.done <= done_ || ended_)) return;
    const bool last = p.total > 0 && p.done >= p.total;
    if (!first && !last && now - last_emit_ < interval_) {
      done_ = std::max(done_, p.done);  // the next report that passes carries at least this
      return;
    }
    if (first) phase_ = std::string(p.phase);
    started_ = true;
    done_ = p.done;
    ended_ = last;
    last_emit_ = now;
    emit_(Progress{phase_, p.done, p.total});
  }
  /// A RunContext progress callback reporting here (the throttle must outlive its uses).
  RunContext::ProgressFn Callback() {
    return [this](const Progress& p) { Report(p); };
  }

 private:
  const EmitFn emit_;
  const std::chrono::milliseconds interval_;
  std::mutex mu_;
  bool started_ = false, ended_ = false;
  std::string phase_;
  int64_t done_ = 0;
  std::chrono::steady_clock::time_point last_emit_;
};

inline void ToProto(const Progress& p, v1::Progress* out) {
  out->set_phase(std::string(p.phase));
  out->set_done(p.done);
  out->set_total(p.total);
}

/// A throttle's emit function that sends each report into `sink` as a message with only
/// `progress` set (before or among the result chunks, which it leaves unchanged).
template <typename Response>
ProgressThrottle::EmitFn ProgressMessages(ChunkSink<Response>* sink) {
  return [sink](const Progress& p) {
    Response message;
    ToProto(p, message.mutable_progress());
    sink->Push(std::move(message), false);
  };
}

/// A server-streaming work function (WriteReactor's) for the streaming variant of a
/// unary call: `fn`'s progress as messages with only `progress` set, then its response
/// as the last message.
template <typename Response>
std::function<absl::Status(const CancellationToken&, ChunkSink<Response>*)> StreamWithProgress(
    std::function<absl::StatusOr<Response>(const CancellationToken&, const RunContext::ProgressFn&)> fn) {
  return [fn = std::move(fn)](const CancellationToken& cancel, ChunkSink<Response>* sink) -> absl::Status {
    ProgressThrottle throttle(ProgressMessages(sink));
    absl::StatusOr<Response> out = fn(cancel, throttle.Callback());
    if (!out.ok()) return out.status();
    sink->Push(*std::move(out), true);
    return absl::OkStatus();
  };
}

}  // namespace geomfit::server
