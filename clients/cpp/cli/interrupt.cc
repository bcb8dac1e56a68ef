#include "clients/cpp/cli/interrupt.h"

#include <fcntl.h>
#include <poll.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>

#include "clients/cpp/cli/cli.h"

namespace geomfit::cli {
namespace {

std::atomic<int> g_interrupts{0};
std::atomic<int> g_wake_fd{-1};  // the live handler's pipe (write end)
struct sigaction g_previous;

constexpr char kInterrupt = 'i', kQuit = 'q';

// Async-signal-safe: counts, wakes the helper thread, or exits on the second Ctrl-C.
void OnSigint(int) {
  if (g_interrupts.fetch_add(1) >= 1) {
    static const char kMsg[] = "\ngeomfit: interrupted twice: exiting\n";
    (void)!write(STDERR_FILENO, kMsg, sizeof(kMsg) - 1);
    _exit(kExitInterrupted);
  }
  const int fd = g_wake_fd.load();
  if (fd >= 0) (void)!write(fd, &kInterrupt, 1);
}

}  // namespace

InterruptHandler::InterruptHandler(std::function<void()> on_interrupt, int grace_ms)
    : on_interrupt_(std::move(on_interrupt)), grace_ms_(grace_ms) {
  if (pipe(pipe_) != 0) return;  // no handler: Ctrl-C keeps its default (terminate)
  fcntl(pipe_[1], F_SETFL, O_NONBLOCK);
  g_wake_fd.store(pipe_[1]);
  struct sigaction sa = {};
  sa.sa_handler = OnSigint;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESTART;
  sigaction(SIGINT, &sa, &g_previous);
  thread_ = std::thread([this] { Loop(); });
}

InterruptHandler::~InterruptHandler() {
  if (pipe_[1] < 0) return;
  sigaction(SIGINT, &g_previous, nullptr);
  g_wake_fd.store(-1);
  (void)!write(pipe_[1], &kQuit, 1);
  thread_.join();
  close(pipe_[0]);
  close(pipe_[1]);
}

bool InterruptHandler::Interrupted() { return g_interrupts.load() > 0; }

void InterruptHandler::Loop() {
  bool interrupted = false;
  while (true) {
    pollfd p = {pipe_[0], POLLIN, 0};
    const int ready = poll(&p, 1, interrupted ? grace_ms_ : -1);
    if (ready == 0) {  // interrupted, and the work did not end within the grace period
      std::fprintf(stderr, "geomfit: interrupted: the work did not stop within %d ms; exiting\n", grace_ms_);
      _exit(kExitInterrupted);
    }
    char c = 0;
    if (ready < 0 || read(pipe_[0], &c, 1) != 1) continue;
    if (c == kQuit) return;
    if (c == kInterrupt && !interrupted) {
      interrupted = true;
      if (on_interrupt_) on_interrupt_();
    }
  }
}

}  // namespace geomfit::cli
