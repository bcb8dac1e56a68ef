#include "server/jobs/job_manager.h"

#include <algorithm>
#include <chrono>
#include <random>
#include <utility>

#include <spdlog/spdlog.h>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/util/status_macros.h"
#include "server/mesh_store.h"

namespace geomfit::server {
namespace {

constexpr char kInterruptedByRestart[] = "interrupted by restart";
constexpr char kInterruptedByShutdown[] = "interrupted by server shutdown";

/// The final event a finished record stands for (a job whose log is gone).
JobEvent FinalEventOf(const JobRecord& r) {
  JobEvent e;
  e.seq = r.last_seq;
  e.state = r.state;
  e.unix_ms = r.updated_unix_ms;
  e.results = r.results;
  e.error_code = r.error_code;
  e.message = r.error;
  e.final = true;
  return e;
}

}  // namespace

int64_t JobEvent::ArrayBytes() const {
  int64_t n = 0;
  for (const JobArray& a : arrays) n += static_cast<int64_t>(sizeof(double) * a.data.size());
  return n;
}

/// A job in memory. Lock order: JobManager::mu_ before Job::mu, never the reverse.
struct JobManager::Job {
  std::mutex mu;
  std::condition_variable changed;  ///< an event was appended
  JobRecord record;
  JobRunFn run;
  CancellationToken token;
  std::deque<JobEvent> events;  ///< contiguous seqs; the last is the latest
  int64_t next_seq = 1;
  int64_t array_bytes = 0;
  std::map<uint64_t, std::function<void()>> subscribers;  ///< one-shot, see Read
  bool cancel_requested = false;  ///< by a client
  bool shutdown = false;          ///< by Shutdown
};

/// JobEvents of one run, and its RunContext progress reporting: a progress event per
/// phase whenever the percentage changes (at most ~100 per phase, whatever the
/// reporting rate), so the log keeps the story, not the noise.
class JobManager::Events final : public JobEvents {
 public:
  Events(JobManager* manager, std::shared_ptr<Job> job) : manager_(manager), job_(std::move(job)) {}

  void Emit(JobEvent event) override {
    {
      std::lock_guard<std::mutex> lock(progress_mu_);
      step_ = event.step;
      phase_.clear();  // a phase reported again after this event (the next level's fit) starts over
      done_ = -1;
    }
    // Meshes stored so far join the record, durably before the event is seen: a job
    // interrupted by a crash still names what it left in the store.
    if (!event.results.empty()) {
      JobRecord record;
      {
        std::lock_guard<std::mutex> lock(job_->mu);
        std::vector<JobResultMesh>& r = job_->record.results;
        r.insert(r.end(), event.results.begin(), event.results.end());
        record = job_->record;
        record.last_seq = job_->next_seq;  // this event's
      }
      if (absl::Status s = manager_->store_->PutJob(record); !s.ok())
        spdlog::warn("job {}: cannot record its results: {}", record.job_id, std::string(s.message()));
    }
    std::vector<std::function<void()>> fire;
    {
      std::lock_guard<std::mutex> lock(job_->mu);
      fire = manager_->AppendLocked(*job_, std::move(event));
    }
    for (auto& f : fire) f();
  }

  void Progress(const geomfit::Progress& p) {
    JobEvent e;
    {
      std::lock_guard<std::mutex> lock(progress_mu_);
      const int64_t percent = p.total > 0 ? p.done * 100 / p.total : p.done;
      // Same phase: a report behind the latest (threads finish out of order) is dropped.
      if (p.phase == phase_ && (p.done <= done_ || (percent == percent_ && p.done != p.total))) return;
      phase_ = std::string(p.phase);
      percent_ = percent;
      done_ = p.done;
      e.step = step_;
    }
    e.phase = std::string(p.phase);
    e.done = p.done;
    e.total = p.total;
    std::vector<std::function<void()>> fire;
    {
      std::lock_guard<std::mutex> lock(job_->mu);
      fire = manager_->AppendLocked(*job_, std::move(e));
    }
    for (auto& f : fire) f();
  }

 private:
  JobManager* manager_;
  std::shared_ptr<Job> job_;
  std::mutex progress_mu_;
  std::string phase_;
  int64_t percent_ = -1;
  int64_t done_ = -1;
  int64_t step_ = 0;
};

JobManager::JobManager(MeshStore* store, JobManagerOptions options) : store_(store), options_(options) {}

absl::StatusOr<std::unique_ptr<JobManager>> JobManager::Create(MeshStore* store, JobManagerOptions options) {
  if (options.threads < 1) return absl::InvalidArgumentError("job threads must be at least 1");
  if (options.max_jobs < 1) return absl::InvalidArgumentError("max jobs must be at least 1");
  std::unique_ptr<JobManager> m(new JobManager(store, options));
  // Jobs a previous process left unfinished cannot resume: they failed.
  std::string after;
  int interrupted = 0;
  while (true) {
    GF_ASSIGN_OR_RETURN(std::vector<JobRecord> page, store->ListJobs(after, 1000));
    if (page.empty()) break;
    after = page.back().job_id;
    for (JobRecord& r : page) {
      if (IsFinal(r.state)) continue;
      r.state = JobState::kFailed;
      r.error_code = static_cast<int>(absl::StatusCode::kAborted);
      r.error = kInterruptedByRestart;
      r.updated_unix_ms = NowUnixMs();
      r.last_seq += 1;
      GF_RETURN_IF_ERROR(store->PutJob(r));
      ++interrupted;
    }
  }
  if (interrupted > 0) spdlog::warn("{} jobs were interrupted by the restart (now FAILED)", interrupted);
  for (int i = 0; i < options.threads; ++i) m->threads_.emplace_back([p = m.get()] { p->Work(); });
  return m;
}

JobManager::~JobManager() { Shutdown(); }

std::string JobManager::NewId() {
  static thread_local std::mt19937_64 rng{std::random_device{}()};
  return absl::StrFormat("j-%013d-%06x", NowUnixMs(), rng() & 0xffffff);
}

std::vector<std::function<void()>> JobManager::AppendLocked(Job& job, JobEvent event) {
  event.seq = job.next_seq++;
  if (!event.final) event.state = job.record.state;
  event.unix_ms = NowUnixMs();
  job.array_bytes += event.ArrayBytes();
  job.record.last_seq = event.seq;
  job.events.push_back(std::move(event));
  while (job.events.size() > 1 && !job.events.front().final &&
         (static_cast<int>(job.events.size()) > options_.max_events_per_job ||
          job.array_bytes > options_.max_snapshot_bytes_per_job)) {
    job.array_bytes -= job.events.front().ArrayBytes();
    job.events.pop_front();
  }
  job.changed.notify_all();
  std::vector<std::function<void()>> fire;
  for (auto& [id, fn] : job.subscribers) fire.push_back(std::move(fn));
  job.subscribers.clear();
  return fire;
}

absl::StatusOr<JobStatus> JobManager::Start(std::string kind, std::string options, JobRunFn run) {
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_) return absl::UnavailableError("server is shutting down; start the job later");
    if (active_ >= options_.max_jobs)
      return absl::ResourceExhaustedError(absl::StrCat("too many jobs: ", active_,
                                                       " pending or running (--max-jobs ", options_.max_jobs,
                                                       "); retry later"));
    ++active_;
  }
  auto job = std::make_shared<Job>();
  job->run = std::move(run);
  JobRecord& r = job->record;
  r.job_id = NewId();
  r.kind = std::move(kind);
  r.options = std::move(options);
  r.state = JobState::kPending;
  r.created_unix_ms = r.updated_unix_ms = NowUnixMs();
  JobEvent queued;
  queued.phase = "queued";
  AppendLocked(*job, std::move(queued));  // nobody else sees the job yet
  if (absl::Status s = store_->PutJob(r); !s.ok()) {
    std::lock_guard<std::mutex> lock(mu_);
    --active_;
    return s;
  }
  JobStatus as_queued;  // as queued: a worker may run the job to its end before Start returns
  {
    std::lock_guard<std::mutex> lock(job->mu);
    as_queued = StatusOf(*job);
  }
  bool stopping;
  {
    std::lock_guard<std::mutex> lock(mu_);
    stopping = stopping_;
    jobs_[r.job_id] = job;
    if (!stopping) {
      queue_.push_back(job);
      ready_.notify_one();
    }
  }
  if (!stopping) return as_queued;
  Finish(job, JobState::kFailed, absl::AbortedError(kInterruptedByShutdown), {});
  std::lock_guard<std::mutex> lock(job->mu);
  return StatusOf(*job);
}

void JobManager::Work() {
  while (true) {
    std::shared_ptr<Job> job;
    {
      std::unique_lock<std::mutex> lock(mu_);
      ready_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (queue_.empty()) return;  // stopping
      job = std::move(queue_.front());
      queue_.pop_front();
    }
    RunJob(job);
  }
}

void JobManager::RunJob(const std::shared_ptr<Job>& job) {
  auto events = std::make_shared<Events>(this, job);
  {
    std::vector<std::function<void()>> fire;
    JobRecord record;
    {
      std::unique_lock<std::mutex> lock(job->mu);
      if (IsFinal(job->record.state)) return;
      if (job->token.IsCancelled()) {  // cancelled while a worker took it from the queue
        lock.unlock();
        Finish(job, JobState::kCancelled, absl::CancelledError("cancelled before it started"), {});
        return;
      }
      job->record.state = JobState::kRunning;
      job->record.updated_unix_ms = NowUnixMs();
      JobEvent started;
      started.phase = "started";
      fire = AppendLocked(*job, std::move(started));
      record = job->record;
    }
    for (auto& f : fire) f();
    if (absl::Status s = store_->PutJob(record); !s.ok())
      spdlog::warn("job {}: cannot record RUNNING: {}", record.job_id, std::string(s.message()));
  }
  const RunContext ctx(&job->token, options_.numeric_threads,
                       [events](const geomfit::Progress& p) { events->Progress(p); });
  absl::StatusOr<JobResult> result = job->run(ctx, events.get());
  if (result.ok()) {
    Finish(job, JobState::kSucceeded, absl::OkStatus(), *std::move(result));
    return;
  }
  bool by_client, by_shutdown;
  {
    std::lock_guard<std::mutex> lock(job->mu);
    by_client = job->cancel_requested;
    by_shutdown = job->shutdown;
  }
  if (job->token.IsCancelled() && by_shutdown && !by_client) {
    Finish(job, JobState::kFailed, absl::AbortedError(kInterruptedByShutdown), {});
  } else if (job->token.IsCancelled()) {
    Finish(job, JobState::kCancelled, absl::CancelledError("cancelled by a client"), {});
  } else {
    Finish(job, JobState::kFailed, result.status(), {});
  }
}

void JobManager::Finish(const std::shared_ptr<Job>& job, JobState state, absl::Status error, JobResult result) {
  JobRecord record;
  {
    std::lock_guard<std::mutex> lock(job->mu);
    if (IsFinal(job->record.state)) return;
    JobRecord& r = job->record;
    r.state = state;
    r.updated_unix_ms = NowUnixMs();
    r.results = state == JobState::kSucceeded ? result.results : std::vector<JobResultMesh>{};
    r.error_code = static_cast<int>(error.code());
    r.error = std::string(error.message());
    record = r;
    record.last_seq = job->next_seq;  // the final event's
  }
  // Durable before anyone sees the final event.
  if (absl::Status s = store_->PutJob(record); !s.ok())
    spdlog::warn("job {}: cannot record {}: {}", record.job_id, JobStateName(state), std::string(s.message()));
  JobEvent last;
  last.state = state;
  last.final = true;
  last.results = record.results;
  last.values = std::move(result.values);
  last.counts = std::move(result.counts);
  last.message = error.ok() ? result.message : std::string(error.message());
  last.error_code = record.error_code;
  std::vector<std::function<void()>> fire;
  {
    std::lock_guard<std::mutex> lock(job->mu);
    fire = AppendLocked(*job, std::move(last));
  }
  for (auto& f : fire) f();
  spdlog::info("job {} ({}) {}{}{}", record.job_id, record.kind, JobStateName(state), error.ok() ? "" : ": ",
               record.error);
  Retire(job);
}

void JobManager::Retire(const std::shared_ptr<Job>& job) {
  std::lock_guard<std::mutex> lock(mu_);
  --active_;
  finished_.push_back(job->record.job_id);  // the id never changes: no lock needed
  while (static_cast<int>(finished_.size()) > options_.max_finished_jobs) {
    jobs_.erase(finished_.front());
    finished_.pop_front();
  }
}

std::shared_ptr<JobManager::Job> JobManager::Find(const std::string& job_id) {
  std::lock_guard<std::mutex> lock(mu_);
  auto it = jobs_.find(job_id);
  return it == jobs_.end() ? nullptr : it->second;
}

absl::StatusOr<std::shared_ptr<JobManager::Job>> JobManager::Restore(const std::string& job_id) {
  if (auto job = Find(job_id)) return job;
  if (job_id.empty()) return absl::InvalidArgumentError("job_id: empty");
  GF_ASSIGN_OR_RETURN(JobRecord record, store_->GetJob(job_id));
  auto job = std::make_shared<Job>();
  job->events.push_back(FinalEventOf(record));
  job->next_seq = record.last_seq + 1;
  job->record = std::move(record);
  std::lock_guard<std::mutex> lock(mu_);
  auto [it, inserted] = jobs_.try_emplace(job_id, job);
  if (inserted && IsFinal(job->record.state)) {
    finished_.push_back(job_id);
    while (static_cast<int>(finished_.size()) > options_.max_finished_jobs) {
      jobs_.erase(finished_.front());
      finished_.pop_front();
    }
  }
  return it->second;
}

JobStatus JobManager::StatusOf(Job& job) {
  JobStatus s;
  s.record = job.record;
  if (!job.events.empty()) {
    s.last_seq = job.events.back().seq;
    s.latest = job.events.back();
    s.latest.arrays.clear();
  }
  return s;
}

absl::StatusOr<JobStatus> JobManager::Cancel(const std::string& job_id) {
  GF_ASSIGN_OR_RETURN(std::shared_ptr<Job> job, Restore(job_id));
  bool pending;
  {
    std::lock_guard<std::mutex> lock(job->mu);
    if (IsFinal(job->record.state)) return StatusOf(*job);
    job->cancel_requested = true;
    job->token.Cancel();
    pending = job->record.state == JobState::kPending;
  }
  bool dequeued = false;
  if (pending) {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = std::find(queue_.begin(), queue_.end(), job);
    if (it != queue_.end()) {
      queue_.erase(it);
      dequeued = true;
    }
  }
  if (dequeued) Finish(job, JobState::kCancelled, absl::CancelledError("cancelled before it started"), {});
  // A running job polls its token: give it a moment, so the answer is usually final.
  std::unique_lock<std::mutex> lock(job->mu);
  job->changed.wait_for(lock, std::chrono::milliseconds(250), [&] { return IsFinal(job->record.state); });
  return StatusOf(*job);
}

absl::StatusOr<JobStatus> JobManager::Get(const std::string& job_id) {
  GF_ASSIGN_OR_RETURN(std::shared_ptr<Job> job, Restore(job_id));
  std::lock_guard<std::mutex> lock(job->mu);
  return StatusOf(*job);
}

absl::StatusOr<std::vector<JobStatus>> JobManager::List(const std::string& after_id, int limit) {
  GF_ASSIGN_OR_RETURN(std::vector<JobRecord> records, store_->ListJobs(after_id, limit));
  std::vector<JobStatus> out;
  out.reserve(records.size());
  for (JobRecord& r : records) {
    if (auto job = Find(r.job_id)) {
      std::lock_guard<std::mutex> lock(job->mu);
      out.push_back(StatusOf(*job));
      continue;
    }
    JobStatus s;
    s.latest = FinalEventOf(r);
    s.last_seq = r.last_seq;
    s.record = std::move(r);
    out.push_back(std::move(s));
  }
  return out;
}

absl::StatusOr<JobEventBatch> JobManager::Read(const std::string& job_id, int64_t from, int max,
                                               std::function<void()> on_more, uint64_t* subscription) {
  GF_ASSIGN_OR_RETURN(std::shared_ptr<Job> job, Restore(job_id));
  std::lock_guard<std::mutex> lock(job->mu);
  JobEventBatch batch;
  const std::deque<JobEvent>& ev = job->events;
  from = std::max<int64_t>(from, 1);
  if (ev.back().final && from > ev.back().seq) {
    batch.events.push_back(ev.back());
    batch.end = true;
    return batch;
  }
  const int64_t first = ev.front().seq;  // earlier events were dropped (see the bound)
  for (size_t i = static_cast<size_t>(std::max<int64_t>(0, from - first));
       i < ev.size() && static_cast<int>(batch.events.size()) < std::max(1, max); ++i) {
    batch.events.push_back(ev[i]);
  }
  batch.end = !batch.events.empty() && batch.events.back().final;
  if (batch.events.empty() && on_more) {
    static std::atomic<uint64_t> next{1};
    const uint64_t id = next.fetch_add(1);
    job->subscribers[id] = std::move(on_more);
    if (subscription) *subscription = id;
  }
  return batch;
}

bool JobManager::Unsubscribe(const std::string& job_id, uint64_t subscription) {
  std::shared_ptr<Job> job = Find(job_id);
  if (!job) return false;
  std::lock_guard<std::mutex> lock(job->mu);
  return job->subscribers.erase(subscription) > 0;
}

absl::StatusOr<JobEventBatch> JobManager::Wait(const std::string& job_id, int64_t from, int max,
                                               const CancellationToken* cancel) {
  GF_ASSIGN_OR_RETURN(std::shared_ptr<Job> job, Restore(job_id));
  while (true) {
    GF_ASSIGN_OR_RETURN(JobEventBatch batch, Read(job_id, from, max));
    if (!batch.events.empty()) return batch;
    if (cancel) GF_RETURN_IF_ERROR(cancel->Check());
    std::unique_lock<std::mutex> lock(job->mu);
    // Tokens do not signal: poll them every 10 ms.
    job->changed.wait_for(lock, std::chrono::milliseconds(10),
                          [&] { return job->events.back().seq >= std::max<int64_t>(from, 1); });
  }
}

void JobManager::Shutdown() {
  std::deque<std::shared_ptr<Job>> queued;
  std::vector<std::shared_ptr<Job>> live;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (stopping_ && threads_.empty()) return;
    stopping_ = true;
    queued.swap(queue_);
    for (auto& [id, job] : jobs_) live.push_back(job);
  }
  for (auto& job : live) {
    std::lock_guard<std::mutex> lock(job->mu);
    if (IsFinal(job->record.state)) continue;
    job->shutdown = true;
    job->token.Cancel();
  }
  for (auto& job : queued) Finish(job, JobState::kFailed, absl::AbortedError(kInterruptedByShutdown), {});
  ready_.notify_all();
  for (std::thread& t : threads_) t.join();
  std::lock_guard<std::mutex> lock(mu_);
  threads_.clear();
}

}  // namespace geomfit::server
