#pragma once
// Work that outlives one request: a job is a kind name, an options blob (opaque here)
// and a run function. Jobs run on the manager's own bounded executor, so a ten-minute
// job never holds a request thread; each has an append-only event log that watchers
// read from any seq (and wait on), and a durable record in the MeshStore. No protobuf
// or gRPC types: server/job_handlers.* translate.
//
// Memory bound: a job's log keeps at most `max_events_per_job` events and
// `max_snapshot_bytes_per_job` bytes of snapshot arrays (the oldest events go first;
// the final event is never dropped); the logs of at most `max_finished_jobs` finished
// jobs stay in memory (the oldest finished go first; their records stay in the store
// and a watcher then gets the final event rebuilt from the record). So the logs hold
// at most (max_jobs + max_finished_jobs) x (max_events_per_job events +
// max_snapshot_bytes_per_job) with the defaults 80 x (4096 events + 16 MiB).
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "core/util/cancel.h"
#include "core/util/run_context.h"
#include "server/jobs/job_record.h"

namespace geomfit::server {

class MeshStore;

/// A named array of a snapshot (row-major float64), e.g. positions #V x 3.
struct JobArray {
  std::string name;
  std::vector<int64_t> shape;
  std::vector<double> data;
};

/// One entry of a job's event log.
struct JobEvent {
  int64_t seq = 0;        ///< 1, 2, ... per job (set by the log)
  JobState state = JobState::kRunning;  ///< set by the log
  int64_t unix_ms = 0;    ///< when it was appended (set by the log)
  int64_t step = 0;       ///< the job's step (refine: the level)
  double time = 0;        ///< simulated time t of time-stepped jobs
  std::string phase;      ///< what the step is doing ("fit", "refine", "store")
  int64_t done = 0, total = 0;            ///< progress within the phase (total 0: unknown)
  std::map<std::string, double> values;   ///< named numbers: residual, area, volume, ...
  std::map<std::string, int64_t> counts;  ///< named counts: vertices, faces, ...
  std::string message;
  std::vector<JobArray> arrays;           ///< optional snapshot
  std::vector<JobResultMesh> results;     ///< meshes stored (on the final event: all of them)
  int error_code = 0;                     ///< final event of a FAILED / CANCELLED job
  bool final = false;                     ///< the job's last event

  int64_t ArrayBytes() const;
};

/// What a successful run returns; it becomes the final event and the record's results.
struct JobResult {
  std::vector<JobResultMesh> results;
  std::map<std::string, double> values;
  std::map<std::string, int64_t> counts;
  std::string message;
};

/// A run function's channel to its log: appends RUNNING events.
class JobEvents {
 public:
  virtual ~JobEvents() = default;
  /// Appends `event` (seq, state and unix_ms are set here). Thread-safe.
  virtual void Emit(JobEvent event) = 0;
};

/// The work of a job: polls ctx (its token is the job's cancellation) and returns the
/// results, or an error. A cancelled run returns ctx.Check()'s status; a cancelled or
/// failed run must leave nothing stored. Events that carry results (meshes stored so far)
/// add them to the job's record at once, so a job interrupted by a crash names them.
using JobRunFn = std::function<absl::StatusOr<JobResult>(const RunContext&, JobEvents*)>;

struct JobManagerOptions {
  int threads = 1;             ///< jobs running at once (--job-threads)
  int max_jobs = 16;           ///< pending + running beyond which Start is RESOURCE_EXHAUSTED (--max-jobs)
  int numeric_threads = 0;     ///< RunContext threads of a job; 0 = all cores
  int max_events_per_job = 4096;
  int64_t max_snapshot_bytes_per_job = int64_t{16} << 20;
  int max_finished_jobs = 64;  ///< finished jobs whose logs stay in memory
};

/// A job's record with its live log position.
struct JobStatus {
  JobRecord record;
  int64_t last_seq = 0;  ///< seq of the latest event (0: none)
  JobEvent latest;       ///< the latest event, without arrays (seq 0 when none)
};

/// Events of one read: `events` in seq order; `end` when the last one is final.
struct JobEventBatch {
  std::vector<JobEvent> events;
  bool end = false;
};

class JobManager {
 public:
  /// Reads the store's records: jobs left PENDING or RUNNING by a previous process are
  /// rewritten as FAILED ("interrupted by restart"). Starts the job threads.
  static absl::StatusOr<std::unique_ptr<JobManager>> Create(MeshStore* store, JobManagerOptions options);
  ~JobManager();  ///< Shutdown()
  JobManager(const JobManager&) = delete;
  JobManager& operator=(const JobManager&) = delete;

  /// Records a PENDING job (durably) and queues it; returns it as queued (PENDING, last_seq 1)
  /// even if a worker has already run it; RESOURCE_EXHAUSTED beyond max_jobs,
  /// UNAVAILABLE after Shutdown.
  absl::StatusOr<JobStatus> Start(std::string kind, std::string options, JobRunFn run);
  /// A pending job ends CANCELLED at once; a running one once its run function sees its
  /// token (then it has stored nothing). A finished job is returned unchanged.
  absl::StatusOr<JobStatus> Cancel(const std::string& job_id);
  absl::StatusOr<JobStatus> Get(const std::string& job_id);
  /// Up to `limit` jobs with id > after_id in id order (= creation order).
  absl::StatusOr<std::vector<JobStatus>> List(const std::string& after_id, int limit);

  /// Events with seq >= from (at most `max`). When there are none yet and the job is not
  /// finished, `on_more` (if given) is registered to be called once, from the appending
  /// thread and without locks held, when the next event is appended; *subscription then
  /// names it for Unsubscribe. A finished job read past its final event returns the
  /// final event (a watcher resuming after a restart learns the outcome).
  absl::StatusOr<JobEventBatch> Read(const std::string& job_id, int64_t from, int max,
                                     std::function<void()> on_more = nullptr, uint64_t* subscription = nullptr);
  /// false when the callback already fired (or is firing): it then runs (ran) once.
  bool Unsubscribe(const std::string& job_id, uint64_t subscription);
  /// Blocks until events with seq >= from exist (returns them), or `cancel` trips.
  absl::StatusOr<JobEventBatch> Wait(const std::string& job_id, int64_t from, int max,
                                     const CancellationToken* cancel = nullptr);

  /// Cancels every job: pending and running ones end FAILED ("interrupted by server
  /// shutdown"); waits for the run functions to return, then joins. Idempotent.
  void Shutdown();

  const JobManagerOptions& options() const { return options_; }

 private:
  struct Job;
  class Events;
  JobManager(MeshStore* store, JobManagerOptions options);
  void Work();
  void RunJob(const std::shared_ptr<Job>& job);
  /// Appends under job->mu; returns the callbacks to fire (after unlocking).
  std::vector<std::function<void()>> AppendLocked(Job& job, JobEvent event);
  /// Final state: appends the final event and writes the record.
  void Finish(const std::shared_ptr<Job>& job, JobState state, absl::Status error, JobResult result);
  std::shared_ptr<Job> Find(const std::string& job_id);
  /// A finished job no longer in memory, rebuilt from its record (its final event only).
  absl::StatusOr<std::shared_ptr<Job>> Restore(const std::string& job_id);
  JobStatus StatusOf(Job& job);
  void Retire(const std::shared_ptr<Job>& job);
  std::string NewId();

  MeshStore* store_;
  const JobManagerOptions options_;
  std::mutex mu_;  ///< guards the maps, queue and counters; taken before a Job's mu, never after
  std::condition_variable ready_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;  ///< in memory: live and recently finished
  std::deque<std::shared_ptr<Job>> queue_;
  std::deque<std::string> finished_;  ///< finished job ids in memory, oldest first
  int active_ = 0;                    ///< pending + running
  bool stopping_ = false;
  uint64_t next_subscription_ = 1;
  std::vector<std::thread> threads_;
};

}  // namespace geomfit::server
