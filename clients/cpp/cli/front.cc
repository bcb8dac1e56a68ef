// The `geomfit` binary's lean front end (built with GEOMFIT_CLI_FRONT): it runs the
// in-process commands that need neither the service client nor the sparse solvers
// (curvature --local, generate, convert, --version) itself, and hands every other
// command line to `geomfit-full` next to it (exec, same arguments), so that a local
// run does not load and relocate gRPC, protobuf, OpenSSL, SuiteSparse and OpenBLAS:
// ~15 ms of start-up, ~70 shared libraries.
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <string>

#include "absl/strings/str_cat.h"
#include "clients/cpp/cli/cli.h"

namespace geomfit::cli {
namespace {
char** saved_argv = nullptr;
}  // namespace

void SaveCommandLine(char** argv) { saved_argv = argv; }

absl::Status RunInFullCli() {
  std::string self(4096, '\0');
  const ssize_t n = readlink("/proc/self/exe", self.data(), self.size() - 1);
  self = n > 0 ? self.substr(0, n) : std::string(saved_argv && saved_argv[0] ? saved_argv[0] : "");
  const std::string full = self.substr(0, self.rfind('/') + 1) + "geomfit-full";
  if (saved_argv == nullptr) return absl::InternalError("no command line to hand to geomfit-full");
  std::fflush(stdout);
  std::fflush(stderr);
  execv(full.c_str(), saved_argv);
  return absl::InternalError(absl::StrCat("cannot run ", full, " (every command but curvature --local, ",
                                          "generate and convert runs there): ", std::strerror(errno)));
}

}  // namespace geomfit::cli
