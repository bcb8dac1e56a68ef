#include "clients/cpp/cli/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"

namespace geomfit::cli {

ProgressBar& ProgressBar::Get() {
  static ProgressBar* bar = new ProgressBar(stderr);
  return *bar;
}

void ProgressBar::SetMode(Mode mode) {
  enabled_ = mode == Mode::kOn || (mode == Mode::kAuto && isatty(fileno(out_)));
}

std::string ProgressBar::Line(std::string_view phase, int64_t done, int64_t total, double seconds, int width) {
  std::string line = absl::StrFormat("%-10s", phase);
  const double rate = seconds > 0 ? static_cast<double>(done) / seconds : 0;
  if (total > 0) {
    const double f = std::clamp(static_cast<double>(done) / static_cast<double>(total), 0.0, 1.0);
    const int filled = static_cast<int>(std::lround(f * width));
    absl::StrAppendFormat(&line, " [%s%s] %3d%%  %d/%d", std::string(filled, '#'), std::string(width - filled, '.'),
                          static_cast<int>(std::floor(100 * f)), done, total);
    if (rate > 0) absl::StrAppendFormat(&line, "  %.3g/s", rate);
    if (done < total && rate > 0) {
      absl::StrAppendFormat(&line, "  ETA %.0f s", static_cast<double>(total - done) / rate);
    }
  } else if (done > 0) {
    absl::StrAppendFormat(&line, " %d", done);
    if (rate > 0) absl::StrAppendFormat(&line, "  %.3g/s", rate);
  }
  absl::StrAppendFormat(&line, "  %.1f s", seconds);
  return line;
}

void ProgressBar::Update(std::string_view phase, int64_t done, int64_t total) {
  if (!enabled_) return;
  std::lock_guard<std::mutex> lock(mu_);
  const auto now = std::chrono::steady_clock::now();
  if (!open_ || phase != phase_) {
    if (open_) Draw(true);
    phase_ = std::string(phase);
    done_ = 0;
    start_ = now;
    last_draw_ = {};
    open_ = true;
  }
  if (done < done_) return;
  done_ = done;
  total_ = total;
  const bool complete = total > 0 && done >= total;
  if (complete || now - last_draw_ >= std::chrono::milliseconds(100)) {
    last_draw_ = now;
    Draw(false);
  }
}

void ProgressBar::Finish() {
  if (!enabled_) return;
  std::lock_guard<std::mutex> lock(mu_);
  if (open_) Draw(true);
}

void ProgressBar::Draw(bool final) {
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
  // \r and clear-to-end-of-line redraw in place; the final draw ends the line.
  std::fprintf(out_, "\r%s\033[K%s", Line(phase_, done_, total_, seconds).c_str(), final ? "\n" : "");
  std::fflush(out_);
  if (final) open_ = false;
}

RunContext ProgressBar::Context(int threads) {
  if (!enabled_) return RunContext(nullptr, threads);
  return RunContext(nullptr, threads, [this](const Progress& p) { Update(p.phase, p.done, p.total); });
}

}  // namespace geomfit::cli
