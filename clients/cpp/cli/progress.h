#pragma once
// Progress bars of the `geomfit` tool on stderr: phase, bar, done/total, rate and ETA,
// redrawn in place at most 10 times a second. On by default when stderr is a terminal;
// --progress / --no-progress (any command) force it on or off.
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <mutex>
#include <string>
#include <string_view>

#include "core/util/run_context.h"

namespace geomfit::cli {

class ProgressBar {
 public:
  enum class Mode { kAuto, kOn, kOff };

  /// The tool's bar (drawing on stderr).
  static ProgressBar& Get();

  explicit ProgressBar(std::FILE* out) : out_(out) {}
  /// kAuto: on iff the output is a terminal.
  void SetMode(Mode mode);
  bool enabled() const { return enabled_; }

  /// Reports `done` of `total` (0: unknown) in `phase`; thread-safe. A new phase ends
  /// the previous one's line. Reports behind the latest (threads finish out of order)
  /// are ignored.
  void Update(std::string_view phase, int64_t done, int64_t total);
  /// Starts a phase without a count (reading, writing): elapsed time only.
  void Begin(std::string_view phase) { Update(phase, 0, 0); }
  /// Ends the current phase's line (final figures, newline).
  void Finish();

  /// A RunContext on `threads` that reports here (no callback when disabled).
  RunContext Context(int threads = 0);

  /// "[#####.....]  45%  1234/2742  1.2e+05/s  ETA 3 s" (tests format with it too).
  static std::string Line(std::string_view phase, int64_t done, int64_t total, double seconds, int width = 24);

 private:
  void Draw(bool final);

  std::FILE* out_;
  bool enabled_ = false;
  std::mutex mu_;
  std::string phase_;
  int64_t done_ = 0, total_ = 0;
  std::chrono::steady_clock::time_point start_, last_draw_;
  bool open_ = false;  // a line is drawn and not yet ended
};

}  // namespace geomfit::cli
