// JobManager without gRPC: lifecycle, event log (resume from any seq, bound,
// subscriptions, progress), cancellation, limits, shutdown and restart recovery, and
// the job records of both stores.
#include "server/jobs/job_manager.h"

#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <future>
#include <thread>

#include <gtest/gtest.h>

#include "server/mesh_store.h"

namespace geomfit::server {
namespace {

/// A run function that emits `steps` events, then succeeds with one result mesh.
JobRunFn Steps(int steps) {
  return [steps](const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
    for (int i = 1; i <= steps; ++i) {
      if (absl::Status s = ctx.Check(); !s.ok()) return s;
      JobEvent e;
      e.step = i;
      e.phase = "step";
      e.values["residual"] = 1.0 / i;
      e.counts["vertices"] = 10 * i;
      events->Emit(std::move(e));
    }
    JobResult r;
    r.results.push_back({"m-result", 1});
    r.values["area"] = 4.5;
    r.message = "done";
    return r;
  };
}

/// A run function that emits one event, then polls its context until `release` is set
/// or it is cancelled (returning the context's status, having stored nothing).
JobRunFn Blocking(std::atomic<bool>* release, std::atomic<int>* calls = nullptr) {
  return [release, calls](const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
    if (calls) ++*calls;
    JobEvent e;
    e.phase = "waiting";
    events->Emit(std::move(e));
    while (!release->load()) {
      if (absl::Status s = ctx.Check(); !s.ok()) return s;
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
    return JobResult{};
  };
}

/// Every event of a job, waiting for its final one.
std::vector<JobEvent> AllEvents(JobManager& m, const std::string& id) {
  std::vector<JobEvent> out;
  int64_t next = 1;
  while (true) {
    absl::StatusOr<JobEventBatch> b = m.Wait(id, next, 100);
    EXPECT_TRUE(b.ok()) << b.status();
    if (!b.ok()) return out;
    for (JobEvent& e : b->events) {
      next = e.seq + 1;
      out.push_back(std::move(e));
    }
    if (b->end) return out;
  }
}

/// Waits for an event of `phase` (the run function got there).
void WaitForPhase(JobManager& m, const std::string& id, const std::string& phase) {
  int64_t next = 1;
  while (true) {
    absl::StatusOr<JobEventBatch> b = m.Wait(id, next, 100);
    ASSERT_TRUE(b.ok()) << b.status();
    for (const JobEvent& e : b->events) {
      if (e.phase == phase) return;
      next = e.seq + 1;
    }
    ASSERT_FALSE(b->end) << "job ended before phase " << phase;
  }
}

std::unique_ptr<JobManager> NewManager(MeshStore* store, JobManagerOptions o = {}) {
  absl::StatusOr<std::unique_ptr<JobManager>> m = JobManager::Create(store, o);
  EXPECT_TRUE(m.ok()) << m.status();
  return std::move(m).value();
}

TEST(JobManagerTest, LifecycleEventsAndDurableRecord) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  absl::StatusOr<JobStatus> started = m->Start("test", std::string("opt\0ions", 8), Steps(3));
  ASSERT_TRUE(started.ok()) << started.status();
  const std::string id = started->record.job_id;
  EXPECT_EQ(id.rfind("j-", 0), 0u);
  EXPECT_EQ(started->record.kind, "test");
  EXPECT_EQ(started->last_seq, 1);

  const std::vector<JobEvent> events = AllEvents(*m, id);
  // queued (PENDING), started (RUNNING), 3 steps (RUNNING), final (SUCCEEDED).
  ASSERT_EQ(events.size(), 6u);
  for (size_t i = 0; i < events.size(); ++i) EXPECT_EQ(events[i].seq, static_cast<int64_t>(i + 1));
  EXPECT_EQ(events[0].state, JobState::kPending);
  EXPECT_EQ(events[1].state, JobState::kRunning);
  EXPECT_EQ(events[3].step, 2);
  EXPECT_DOUBLE_EQ(events[3].values.at("residual"), 0.5);
  EXPECT_EQ(events[4].counts.at("vertices"), 30);
  const JobEvent& last = events.back();
  EXPECT_TRUE(last.final);
  EXPECT_EQ(last.state, JobState::kSucceeded);
  ASSERT_EQ(last.results.size(), 1u);
  EXPECT_EQ(last.results[0].mesh_id, "m-result");
  EXPECT_DOUBLE_EQ(last.values.at("area"), 4.5);
  EXPECT_EQ(last.message, "done");

  absl::StatusOr<JobRecord> record = store->GetJob(id);
  ASSERT_TRUE(record.ok()) << record.status();
  EXPECT_EQ(record->state, JobState::kSucceeded);
  EXPECT_EQ(record->options, std::string("opt\0ions", 8));
  EXPECT_EQ(record->results, last.results);
  EXPECT_EQ(record->last_seq, 6);
  EXPECT_GE(record->updated_unix_ms, record->created_unix_ms);

  absl::StatusOr<JobStatus> got = m->Get(id);
  ASSERT_TRUE(got.ok());
  EXPECT_EQ(got->record.state, JobState::kSucceeded);
  EXPECT_EQ(got->last_seq, 6);
  EXPECT_TRUE(got->latest.final);
  EXPECT_TRUE(absl::IsNotFound(m->Get("j-nope").status()));
  EXPECT_TRUE(absl::IsNotFound(m->Cancel("j-nope").status()));
  EXPECT_TRUE(absl::IsNotFound(m->Read("j-nope", 1, 10).status()));
}

TEST(JobManagerTest, ReadFromAnySeqGetsExactlyTheRest) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  const std::string id = m->Start("test", "", Steps(5))->record.job_id;
  const std::vector<JobEvent> all = AllEvents(*m, id);
  ASSERT_EQ(all.size(), 8u);
  for (int64_t k = 1; k <= 8; ++k) {
    absl::StatusOr<JobEventBatch> b = m->Read(id, k, 100);
    ASSERT_TRUE(b.ok());
    ASSERT_EQ(b->events.size(), static_cast<size_t>(9 - k)) << "from " << k;
    EXPECT_EQ(b->events.front().seq, k);
    EXPECT_TRUE(b->end);
  }
  // Past the final event: the final event again (a resuming watcher learns the outcome).
  absl::StatusOr<JobEventBatch> past = m->Read(id, 42, 100);
  ASSERT_TRUE(past.ok());
  ASSERT_EQ(past->events.size(), 1u);
  EXPECT_EQ(past->events[0].seq, 8);
  EXPECT_TRUE(past->end);
  // At most `max` per read.
  absl::StatusOr<JobEventBatch> two = m->Read(id, 3, 2);
  ASSERT_EQ(two->events.size(), 2u);
  EXPECT_EQ(two->events[1].seq, 4);
  EXPECT_FALSE(two->end);
}

TEST(JobManagerTest, CancelRunningJobEndsCancelledAndRunStops) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  std::atomic<bool> release{false};
  const std::string id = m->Start("test", "", Blocking(&release))->record.job_id;
  WaitForPhase(*m, id, "waiting");
  EXPECT_EQ(m->Get(id)->record.state, JobState::kRunning);
  absl::StatusOr<JobStatus> cancelled = m->Cancel(id);
  ASSERT_TRUE(cancelled.ok());
  const std::vector<JobEvent> events = AllEvents(*m, id);
  ASSERT_FALSE(events.empty());
  EXPECT_EQ(events.back().state, JobState::kCancelled);
  EXPECT_EQ(events.back().error_code, static_cast<int>(absl::StatusCode::kCancelled));
  EXPECT_TRUE(events.back().results.empty());
  EXPECT_EQ(store->GetJob(id)->state, JobState::kCancelled);
  // Cancelling a finished job changes nothing.
  EXPECT_EQ(m->Cancel(id)->record.state, JobState::kCancelled);
}

TEST(JobManagerTest, CancelPendingJobNeverRunsIt) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());  // one job thread
  std::atomic<bool> release{false};
  std::atomic<int> calls{0};
  const std::string first = m->Start("test", "", Blocking(&release))->record.job_id;
  WaitForPhase(*m, first, "waiting");
  const std::string second = m->Start("test", "", Blocking(&release, &calls))->record.job_id;
  EXPECT_EQ(m->Get(second)->record.state, JobState::kPending);
  absl::StatusOr<JobStatus> c = m->Cancel(second);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->record.state, JobState::kCancelled);
  release = true;
  EXPECT_EQ(AllEvents(*m, first).back().state, JobState::kSucceeded);
  const std::vector<JobEvent> events = AllEvents(*m, second);
  ASSERT_EQ(events.size(), 2u);  // queued, cancelled
  EXPECT_EQ(events[1].state, JobState::kCancelled);
  EXPECT_EQ(calls.load(), 0);
}

TEST(JobManagerTest, MaxJobsCountsPendingAndRunning) {
  auto store = NewMemoryStore();
  JobManagerOptions o;
  o.threads = 1;
  o.max_jobs = 2;
  auto m = NewManager(store.get(), o);
  std::atomic<bool> release{false};
  const std::string a = m->Start("test", "", Blocking(&release))->record.job_id;
  const std::string b = m->Start("test", "", Blocking(&release))->record.job_id;
  absl::StatusOr<JobStatus> c = m->Start("test", "", Steps(1));
  EXPECT_EQ(c.status().code(), absl::StatusCode::kResourceExhausted) << c.status();
  EXPECT_NE(c.status().message().find("--max-jobs"), std::string::npos);
  release = true;
  AllEvents(*m, a);
  AllEvents(*m, b);
  EXPECT_TRUE(m->Start("test", "", Steps(1)).ok());  // room again
}

TEST(JobManagerTest, ResultsOfEventsAreRecordedAtOnceAndDroppedOnFailure) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  std::atomic<bool> release{false};
  const std::string id =
      m->Start("test", "", [&](const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
         JobEvent e;
         e.phase = "stored";
         e.results.push_back({"m-level1", 1});
         events->Emit(std::move(e));
         while (!release) {
           if (absl::Status s = ctx.Check(); !s.ok()) return s;
           std::this_thread::sleep_for(std::chrono::milliseconds(1));
         }
         return absl::InternalError("level 2 failed");  // (a real run deletes level 1 first)
       })->record.job_id;
  WaitForPhase(*m, id, "stored");
  EXPECT_EQ(store->GetJob(id)->results, (std::vector<JobResultMesh>{{"m-level1", 1}}));
  EXPECT_EQ(m->Get(id)->record.results.size(), 1u);
  release = true;
  EXPECT_EQ(AllEvents(*m, id).back().state, JobState::kFailed);
  EXPECT_TRUE(store->GetJob(id)->results.empty());
}

TEST(JobManagerTest, FailedRunKeepsItsError) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  const std::string id =
      m->Start("test", "", [](const RunContext&, JobEvents*) -> absl::StatusOr<JobResult> {
         return absl::InvalidArgumentError("refine.levels: 0 is out of range");
       })->record.job_id;
  const JobEvent last = AllEvents(*m, id).back();
  EXPECT_EQ(last.state, JobState::kFailed);
  EXPECT_EQ(last.error_code, static_cast<int>(absl::StatusCode::kInvalidArgument));
  EXPECT_EQ(last.message, "refine.levels: 0 is out of range");
  absl::StatusOr<JobRecord> r = store->GetJob(id);
  EXPECT_EQ(r->state, JobState::kFailed);
  EXPECT_EQ(r->error, "refine.levels: 0 is out of range");
}

TEST(JobManagerTest, EventLogIsBoundedButKeepsTheFinalEvent) {
  auto store = NewMemoryStore();
  JobManagerOptions o;
  o.max_events_per_job = 5;
  auto m = NewManager(store.get(), o);
  const std::string id = m->Start("test", "", Steps(20))->record.job_id;  // 23 events
  JobEventBatch b;
  do {
    b = *m->Wait(id, 1, 100);
  } while (!b.end);
  ASSERT_EQ(b.events.size(), 5u);
  EXPECT_EQ(b.events.front().seq, 19);  // from a dropped seq: the oldest kept
  EXPECT_EQ(b.events.back().seq, 23);
  EXPECT_TRUE(b.events.back().final);

  // Snapshot bytes: each 1000-double array is 8000 bytes; 20000 bytes keep two.
  JobManagerOptions p;
  p.max_snapshot_bytes_per_job = 20000;
  auto n = NewManager(store.get(), p);
  const std::string s = n->Start("test", "", [](const RunContext&, JobEvents* ev) -> absl::StatusOr<JobResult> {
                           for (int i = 1; i <= 4; ++i) {
                             JobEvent e;
                             e.step = i;
                             e.arrays.push_back({"x", {1000}, std::vector<double>(1000, i)});
                             ev->Emit(std::move(e));
                           }
                           return JobResult{};
                         })->record.job_id;
  AllEvents(*n, s);  // reads while the job runs; read again once it ended
  std::vector<JobEvent> kept = n->Read(s, 1, 100)->events;
  ASSERT_EQ(kept.size(), 3u);  // steps 3, 4 and the final event
  EXPECT_EQ(kept[0].step, 3);
  EXPECT_DOUBLE_EQ(kept[1].arrays[0].data[999], 4.0);
}

TEST(JobManagerTest, SubscriptionFiresOnceOnTheNextEvent) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  std::atomic<bool> release{false};
  const std::string id = m->Start("test", "", Blocking(&release))->record.job_id;
  WaitForPhase(*m, id, "waiting");
  const int64_t next = m->Get(id)->last_seq + 1;
  std::atomic<int> fired{0};
  std::promise<void> called;
  uint64_t sub = 0;
  absl::StatusOr<JobEventBatch> b = m->Read(
      id, next, 10,
      [&] {
        ++fired;
        called.set_value();
      },
      &sub);
  ASSERT_TRUE(b.ok());
  EXPECT_TRUE(b->events.empty());
  EXPECT_NE(sub, 0u);
  // A second subscription, withdrawn before anything happens, never fires.
  std::atomic<int> withdrawn{0};
  uint64_t sub2 = 0;
  m->Read(id, next, 10, [&] { ++withdrawn; }, &sub2).IgnoreError();
  EXPECT_TRUE(m->Unsubscribe(id, sub2));
  release = true;
  AllEvents(*m, id);
  called.get_future().wait();  // fired after the event is appended, outside the lock
  EXPECT_EQ(fired.load(), 1);
  EXPECT_EQ(withdrawn.load(), 0);
  EXPECT_FALSE(m->Unsubscribe(id, sub));  // already fired
}

TEST(JobManagerTest, ProgressReportsBecomeThrottledEvents) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  const std::string id = m->Start("test", "", [](const RunContext& ctx, JobEvents*) -> absl::StatusOr<JobResult> {
                           for (int i = 0; i <= 10000; ++i) ctx.Report("fit", i, 10000);
                           return JobResult{};
                         })->record.job_id;
  int fit = 0;
  bool complete = false;
  for (const JobEvent& e : AllEvents(*m, id)) {
    if (e.phase != "fit") continue;
    ++fit;
    EXPECT_EQ(e.total, 10000);
    complete = complete || e.done == 10000;
  }
  EXPECT_EQ(fit, 101);  // one per percent, 0..100
  EXPECT_TRUE(complete);
}

TEST(JobManagerTest, ProgressBehindTheLatestIsDropped) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  const std::string id = m->Start("test", "", [](const RunContext& ctx, JobEvents* events) -> absl::StatusOr<JobResult> {
                           // Threads of a parallel loop report out of order.
                           for (int64_t done : {10, 30, 20, 100, 90}) ctx.Report("fit", done, 100);
                           JobEvent level;  // the next step fits again: its reports start over
                           level.step = 2;
                           level.phase = "refine";
                           events->Emit(level);
                           for (int64_t done : {50, 40, 100}) ctx.Report("fit", done, 100);
                           return JobResult{};
                         })->record.job_id;
  std::vector<int64_t> done;
  for (const JobEvent& e : AllEvents(*m, id))
    if (e.phase == "fit") done.push_back(e.done);
  EXPECT_EQ(done, (std::vector<int64_t>{10, 30, 100, 50, 100}));
}

TEST(JobManagerTest, WaitHonoursItsToken) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  std::atomic<bool> release{false};
  const std::string id = m->Start("test", "", Blocking(&release))->record.job_id;
  CancellationToken token;
  token.Cancel();
  EXPECT_TRUE(absl::IsCancelled(m->Wait(id, 100, 10, &token).status()));
  release = true;
  AllEvents(*m, id);
}

TEST(JobManagerTest, ShutdownInterruptsRunningAndPendingJobs) {
  auto store = NewMemoryStore();
  auto m = NewManager(store.get());
  std::atomic<bool> release{false};
  const std::string running = m->Start("test", "", Blocking(&release))->record.job_id;
  WaitForPhase(*m, running, "waiting");
  const std::string pending = m->Start("test", "", Blocking(&release))->record.job_id;
  m->Shutdown();
  for (const std::string& id : {running, pending}) {
    absl::StatusOr<JobRecord> r = store->GetJob(id);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->state, JobState::kFailed) << id;
    EXPECT_EQ(r->error, "interrupted by server shutdown");
  }
  EXPECT_TRUE(absl::IsUnavailable(m->Start("test", "", Steps(1)).status()));
}

TEST(JobManagerTest, RestartFailsInterruptedJobsAndKeepsFinishedOnes) {
  auto store = NewMemoryStore();
  std::string done;
  {
    auto m = NewManager(store.get());
    done = m->Start("test", "", Steps(2))->record.job_id;
    AllEvents(*m, done);
  }
  // A job a crashed process left RUNNING, after 7 events, having stored one mesh.
  JobRecord crashed;
  crashed.job_id = "j-0000000000001-000000";
  crashed.kind = "test";
  crashed.state = JobState::kRunning;
  crashed.last_seq = 7;
  crashed.results = {{"m-partial", 1}};
  ASSERT_TRUE(store->PutJob(crashed).ok());

  auto m = NewManager(store.get());
  absl::StatusOr<JobStatus> c = m->Get(crashed.job_id);
  ASSERT_TRUE(c.ok()) << c.status();
  EXPECT_EQ(c->record.state, JobState::kFailed);
  EXPECT_EQ(c->record.error, "interrupted by restart");
  EXPECT_EQ(c->record.results, crashed.results);  // what it left in the store
  EXPECT_EQ(c->last_seq, 8);
  absl::StatusOr<JobEventBatch> b = m->Read(crashed.job_id, 3, 10);  // its log is gone: the final event
  ASSERT_EQ(b->events.size(), 1u);
  EXPECT_EQ(b->events[0].seq, 8);
  EXPECT_EQ(b->events[0].state, JobState::kFailed);
  EXPECT_EQ(b->events[0].message, "interrupted by restart");
  EXPECT_TRUE(b->end);

  absl::StatusOr<std::vector<JobStatus>> all = m->List("", 100);
  ASSERT_TRUE(all.ok());
  ASSERT_EQ(all->size(), 2u);
  EXPECT_EQ((*all)[0].record.job_id, crashed.job_id);  // ids sort by creation time
  EXPECT_EQ((*all)[1].record.job_id, done);
  EXPECT_EQ((*all)[1].record.state, JobState::kSucceeded);
  EXPECT_EQ((*all)[1].record.results, (std::vector<JobResultMesh>{{"m-result", 1}}));
  EXPECT_TRUE((*all)[1].latest.final);
}

TEST(JobStoreTest, SqliteKeepsJobRecordsAcrossReopen) {
  const std::string dir =
      (std::filesystem::temp_directory_path() / ("geomfit_jobstore_" + std::to_string(getpid()))).string();
  std::filesystem::remove_all(dir);
  JobRecord r;
  r.job_id = "j-1";
  r.kind = "refine";
  r.options = std::string("\x01\x00\xff", 3);
  r.state = JobState::kSucceeded;
  r.created_unix_ms = 5;
  r.updated_unix_ms = 9;
  r.results = {{"m-a", 1}, {"m-b", 3}};
  r.error_code = 0;
  r.last_seq = 12;
  {
    auto store = OpenSqliteStore(dir);
    ASSERT_TRUE(store.ok()) << store.status();
    ASSERT_TRUE((*store)->PutJob(r).ok());
    JobRecord f = r;
    f.job_id = "j-2";
    f.state = JobState::kFailed;
    f.results.clear();
    f.error_code = 10;
    f.error = "interrupted by restart";
    ASSERT_TRUE((*store)->PutJob(f).ok());
    r.last_seq = 13;  // replaced
    ASSERT_TRUE((*store)->PutJob(r).ok());
  }
  auto store = OpenSqliteStore(dir);
  ASSERT_TRUE(store.ok());
  absl::StatusOr<JobRecord> got = (*store)->GetJob("j-1");
  ASSERT_TRUE(got.ok()) << got.status();
  EXPECT_EQ(got->kind, "refine");
  EXPECT_EQ(got->options, r.options);
  EXPECT_EQ(got->state, JobState::kSucceeded);
  EXPECT_EQ(got->created_unix_ms, 5);
  EXPECT_EQ(got->updated_unix_ms, 9);
  EXPECT_EQ(got->results, r.results);
  EXPECT_EQ(got->last_seq, 13);
  absl::StatusOr<std::vector<JobRecord>> list = (*store)->ListJobs("j-1", 10);
  ASSERT_EQ(list->size(), 1u);
  EXPECT_EQ((*list)[0].error, "interrupted by restart");
  EXPECT_EQ((*list)[0].error_code, 10);
  EXPECT_TRUE(absl::IsNotFound((*store)->GetJob("j-3").status()));
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace geomfit::server
