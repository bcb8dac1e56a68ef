#pragma once
// Ctrl-C while a job or an in-process computation runs: the command stops its work (the
// server's job is cancelled, the local RunContext's token too) and exits at once.
#include <functional>
#include <thread>

namespace geomfit::cli {

/// While alive, the first SIGINT calls `on_interrupt` on a helper thread (never in the
/// signal handler: it may make an RPC) and the work is expected to end by itself (a
/// watched job's final CANCELLED event, a cancelled RunContext); if it has not ended
/// `grace_ms` later, or at a second SIGINT, the process exits with 130. The previous
/// SIGINT disposition is restored on destruction. One at a time.
class InterruptHandler {
 public:
  explicit InterruptHandler(std::function<void()> on_interrupt, int grace_ms = 5000);
  ~InterruptHandler();
  InterruptHandler(const InterruptHandler&) = delete;
  InterruptHandler& operator=(const InterruptHandler&) = delete;

  /// Whether a SIGINT arrived since the process started.
  static bool Interrupted();

 private:
  void Loop();

  std::function<void()> on_interrupt_;
  int grace_ms_;
  int pipe_[2] = {-1, -1};
  std::thread thread_;
};

}  // namespace geomfit::cli
