// The `geomfit` command-line tool: command dispatch, help, exit codes.
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/interrupt.h"
#include "clients/cpp/cli/progress.h"

namespace geomfit::cli {
namespace {

struct Command {
  const char* name;
  const char* summary;
  absl::Status (*run)(const std::vector<std::string>& args);
};

constexpr Command kCommands[] = {
    {"curvature", "normals, curvatures and principal directions of a mesh", RunCurvature},
    {"generate", "generate a test mesh on an analytic surface", RunGenerate},
    {"convert", "convert a mesh between OBJ, OFF, PLY, STL (and write VTP)", RunConvert},
#ifndef GEOMFIT_CLI_FRONT  // the rest run in geomfit-full (front.cc)
    {"project", "project points onto the reconstructed high-order surface", RunProject},
    {"refine", "refine a mesh uniformly onto the reconstructed surface", RunRefine},
    {"nodes", "quadratic or cubic element nodes on the reconstructed surface", RunNodes},
    {"integrate", "high-order area, volume, scalar and flux integrals", RunIntegrate},
    {"flow", "mean-curvature flow or surface diffusion (--server job or --local)", RunFlowCommand},
    {"operator", "a GFD surface operator as a sparse matrix (--server)", RunOperatorCommand},
    {"membrane", "membrane stress and interface pressure; pressure-load solve (--server job or --local)",
     RunMembraneCommand},
#endif
};

bool IsRemoteCommand(const std::string& name) {
  for (const std::string& r : RemoteCommandNames())
    if (r == name) return true;
  return false;
}

std::string MainUsage() {
  std::string out =
      "usage: geomfit COMMAND [options]\n"
      "       geomfit COMMAND --help\n"
      "       geomfit --version\n\n"
      "High-order differential geometry of surface meshes (OBJ, OFF, PLY, STL).\n\n"
      "commands:\n";
  for (const Command& c : kCommands) absl::StrAppendFormat(&out, "  %-12s %s\n", c.name, c.summary);
#ifdef GEOMFIT_WITH_CLIENT
  absl::StrAppend(&out, "\nservice commands (--server HOST:PORT): ",
                  absl::StrJoin(RemoteCommandNames(), ", "), "; and curvature --server\n");
#else
  out += "\n(built without the service client: --server and the service commands are off)\n";
#endif
  out += "\nevery command: --progress / --no-progress force the progress bar on stderr on or off\n"
         "(default: on when stderr is a terminal)\n";
  out += "\nexit status: 0 success, 1 runtime error, 2 usage error\n";
  return out;
}

absl::Status Dispatch(const std::string& name, const std::vector<std::string>& args) {
  for (const Command& c : kCommands)
    if (name == c.name) return c.run(args);
#ifdef GEOMFIT_CLI_FRONT
  return RunInFullCli();  // its table is the whole one: it reports unknown commands
#endif
  if (IsRemoteCommand(name)) {
#ifdef GEOMFIT_WITH_CLIENT
    return RunRemoteCommand(name, args);
#else
    return UsageError(kNoClientMessage);
#endif
  }
  return UsageError(absl::StrCat("unknown command '", name, "' (see 'geomfit --help')"));
}

}  // namespace


int Main(int argc, char** argv) {
#ifdef GEOMFIT_CLI_FRONT
  SaveCommandLine(argv);
#endif
  std::vector<std::string> args;
  ProgressBar::Mode progress = ProgressBar::Mode::kAuto;
  bool options_end = false;  // after `--`, everything is an argument
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    options_end = options_end || arg == "--";
    if (!options_end && (arg == "--progress" || arg == "--no-progress")) {
      progress = arg == "--progress" ? ProgressBar::Mode::kOn : ProgressBar::Mode::kOff;
    } else {
      args.push_back(arg);
    }
  }
  ProgressBar::Get().SetMode(progress);
  if (args.empty()) {
    std::fputs("geomfit: error: missing command (see 'geomfit --help')\n", stderr);
    return kExitUsageError;
  }
  const std::string& command = args[0];
  if (command == "--help" || command == "-h" || command == "help") {
#ifdef GEOMFIT_CLI_FRONT
    // The whole command list is geomfit-full's.
    std::fprintf(stderr, "geomfit: error: %s\n", std::string(RunInFullCli().message()).c_str());
    return kExitRuntimeError;
#endif
    std::fputs(MainUsage().c_str(), stdout);
    return kExitOk;
  }
  if (command == "--version") {
    std::printf("%s\n", VersionLine("geomfit").c_str());
    return kExitOk;
  }
  absl::Status status;
  try {
    status = Dispatch(command, std::vector<std::string>(args.begin() + 1, args.end()));
  } catch (const std::exception& e) {
    status = absl::InternalError(absl::StrCat("unexpected exception: ", e.what()));
  }
  ProgressBar::Get().Finish();
  if (status.ok()) return kExitOk;
  if (status.code() == absl::StatusCode::kCancelled && InterruptHandler::Interrupted()) {
    std::fprintf(stderr, "geomfit: interrupted: %s\n", std::string(status.message()).c_str());
    return kExitInterrupted;
  }
  // One line on stderr, whatever the message holds.
  const std::string message = absl::StrReplaceAll(status.message(), {{"\r", " "}, {"\n", "; "}});
  std::fprintf(stderr, "geomfit: error: %s\n", message.c_str());
  return IsUsageError(status) ? kExitUsageError : kExitRuntimeError;
}

}  // namespace geomfit::cli

int main(int argc, char** argv) { return geomfit::cli::Main(argc, argv); }
