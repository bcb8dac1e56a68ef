// `geomfit jobs list|get|watch|cancel --server HOST:PORT` and the job mode of
// `geomfit refine --job`: work that outlives one call, watched event by event.
#ifdef GEOMFIT_WITH_CLIENT
#include <cstdio>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/strip.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/interrupt.h"
#include "clients/cpp/cli/progress.h"
#include "clients/cpp/client/client.h"
#include "core/util/status_macros.h"

namespace geomfit::cli {
namespace {

std::string StateName(v1::JobState s) {
  return std::string(absl::StripPrefix(v1::JobState_Name(s), "JOB_STATE_"));
}

std::string JobTable(const std::vector<v1::Job>& jobs) {
  std::string out = "job_id\tkind\tstate\tcreated_unix_ms\tupdated_unix_ms\tlast_event\tresults\terror\n";
  for (const v1::Job& j : jobs) {
    std::string results;
    for (const auto& r : j.results()) absl::StrAppend(&results, results.empty() ? "" : ",", r.mesh_id());
    absl::StrAppendFormat(&out, "%s\t%s\t%s\t%d\t%d\t%d\t%s\t%s\n", j.job_id(), j.kind(), StateName(j.state()),
                          j.created_unix_ms(), j.updated_unix_ms(), j.last_event(), results, j.error());
  }
  return out;
}

absl::Status PrintJobs(const std::vector<v1::Job>& jobs) {
  std::fputs(JobTable(jobs).c_str(), stdout);
  return absl::OkStatus();
}

}  // namespace

absl::Status JobOutcome(const v1::JobEvent& last, const std::string& what) {
  if (!last.final()) return absl::UnavailableError(absl::StrCat(what, " ", last.job_id(), ": the watch ended early"));
  if (last.state() == v1::JOB_STATE_SUCCEEDED) return absl::OkStatus();
  const std::string text = absl::StrCat(what, " ", last.job_id(), " ", StateName(last.state()), ": ", last.message());
  return last.state() == v1::JOB_STATE_CANCELLED ? absl::CancelledError(text) : absl::AbortedError(text);
}

absl::Status WatchJobCancellingOnInterrupt(Client& client, const std::string& job_id, int64_t from_event,
                                           const std::function<bool(const v1::JobEvent&)>& on_event,
                                           v1::JobEvent* last) {
  const InterruptHandler interrupt([&] {
    std::fprintf(stderr, "\ngeomfit: interrupted: cancelling job %s\n", job_id.c_str());
    if (const absl::StatusOr<v1::Job> job = client.CancelJob(job_id); !job.ok())
      std::fprintf(stderr, "geomfit: could not cancel job %s: %s\n", job_id.c_str(),
                   std::string(job.status().message()).c_str());
  });
  return client.WatchJob(job_id, from_event, [&](const v1::JobEvent& e) {
    *last = e;
    return on_event(e);
  });
}

std::string FormatJobEvent(const v1::JobEvent& e) {
  std::string line = absl::StrFormat("job %s #%d %s", e.job_id(), e.seq(), StateName(e.state()));
  if (e.step() > 0) absl::StrAppend(&line, " step ", e.step());
  if (!e.phase().empty()) absl::StrAppend(&line, " ", e.phase());
  if (e.total() > 0) absl::StrAppend(&line, " ", e.done(), "/", e.total());
  const std::map<std::string, int64_t> counts(e.counts().begin(), e.counts().end());
  for (const auto& [k, v] : counts) absl::StrAppend(&line, " ", k, "=", v);
  const std::map<std::string, double> values(e.values().begin(), e.values().end());
  for (const auto& [k, v] : values) absl::StrAppendFormat(&line, " %s=%.6g", k, v);
  for (const auto& r : e.results()) absl::StrAppend(&line, " result=", r.mesh_id(), "@", r.revision());
  if (!e.message().empty()) absl::StrAppend(&line, ": ", e.message());
  return line;
}

absl::Status RunJobs(const std::vector<std::string>& args) {
  const std::string usage = "usage: geomfit jobs list|get|watch|cancel --server HOST:PORT [JOB_ID] [options]";
  if (args.empty() || args[0] == "--help" || args[0] == "-h") {
    if (args.empty()) return UsageError(absl::StrCat("'geomfit jobs' needs a subcommand; ", usage));
    std::printf("%s\n\nLong-running jobs on a geomfit server (started e.g. by 'geomfit refine --job').\n"
                "  list    every job: id, kind, state, times, last event, results, error\n"
                "  get     one job\n"
                "  watch   a job's events as they come (one line each) until it ends; --from N resumes;\n"
                "          Ctrl-C cancels the job\n"
                "  cancel  cancels a job (it then stores nothing)\n",
                usage.c_str());
    return absl::OkStatus();
  }
  const std::string sub = args[0];
  const std::vector<std::string> rest(args.begin() + 1, args.end());
  std::string server, id;
  if (sub == "list") {
    ArgParser p("geomfit jobs list", "--server HOST:PORT", "Lists the server's jobs in creation order.");
    p.Server(&server, "geomfit server");
    GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, rest, server));
    if (!run) return absl::OkStatus();
    GF_ASSIGN_OR_RETURN(std::vector<v1::Job> jobs, ConnectTo(server)->ListJobs());
    return PrintJobs(jobs);
  }
  if (sub == "get" || sub == "cancel") {
    ArgParser p("geomfit jobs " + sub, "--server HOST:PORT JOB_ID",
                sub == "get" ? "Prints one job." : "Cancels a job; prints it (CANCELLED once it stopped).");
    p.Server(&server, "geomfit server").Positional("JOB_ID", &id, "the job");
    GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, rest, server));
    if (!run) return absl::OkStatus();
    std::unique_ptr<Client> client = ConnectTo(server);
    GF_ASSIGN_OR_RETURN(v1::Job job, sub == "get" ? client->GetJob(id) : client->CancelJob(id));
    return PrintJobs({job});
  }
  if (sub == "watch") {
    int from = 0;
    ArgParser p("geomfit jobs watch", "--server HOST:PORT JOB_ID [--from N]",
                "Prints the job's events, one line each, as they come; ends with the job (exit 1\n"
                "unless it SUCCEEDED). After a disconnect, --from LAST+1 resumes. Ctrl-C cancels\n"
                "the job on the server and exits (130) once it stopped.");
    p.Server(&server, "geomfit server")
        .Positional("JOB_ID", &id, "the job")
        .Int("from", &from, "first event (seq) to print; 0 = from the beginning");
    GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, rest, server));
    if (!run) return absl::OkStatus();
    if (from < 0) return UsageError("--from must not be negative");
    v1::JobEvent last;
    GF_RETURN_IF_ERROR(WatchJobCancellingOnInterrupt(*ConnectTo(server), id, from, [&](const v1::JobEvent& e) {
      std::printf("%s\n", FormatJobEvent(e).c_str());
      std::fflush(stdout);
      return true;
    }, &last));
    return JobOutcome(last);
  }
  return UsageError(absl::StrCat("unknown jobs subcommand '", sub, "'; ", usage));
}

absl::StatusOr<std::vector<v1::JobResultMesh>> RunRefineJob(Client& client, const v1::RefineJob& spec) {
  v1::StartJobRequest request;
  *request.mutable_refine() = spec;
  GF_ASSIGN_OR_RETURN(const v1::Job job, client.StartJob(request));
  std::fprintf(stderr, "geomfit: started job %s (geomfit jobs watch|cancel --server ... %s)\n", job.job_id().c_str(),
               job.job_id().c_str());
  v1::JobEvent last;
  ProgressBar& bar = ProgressBar::Get();
  GF_RETURN_IF_ERROR(WatchJobCancellingOnInterrupt(client, job.job_id(), 0, [&](const v1::JobEvent& e) {
    if (bar.enabled()) {
      if (!e.phase().empty()) bar.Update(absl::StrCat(e.phase(), " ", e.step()), e.done(), e.total());
    } else {
      std::fprintf(stderr, "geomfit: %s\n", FormatJobEvent(e).c_str());
    }
    return true;
  }, &last));
  GF_RETURN_IF_ERROR(JobOutcome(last));
  return std::vector<v1::JobResultMesh>(last.results().begin(), last.results().end());
}

}  // namespace geomfit::cli
#endif  // GEOMFIT_WITH_CLIENT
