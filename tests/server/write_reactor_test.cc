// WriteReactor's backpressure (issue 13, item 5): work that pushes encoded chunks
// (ChunkSink::Push) faster than the reader takes them waits while two are held, and
// wakes, drops what it holds and returns when the reader goes, when the idle watchdog
// ends the stream, and when the server shuts down. The reactor is served by a test
// service whose work pushes big chunks; the accounting read is StreamLimits' own.
#include <atomic>
#include <chrono>
#include <memory>
#include <thread>

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include "server/request_stats.h"
#include "server/rpc/reactors.h"
#include "server/rpc/service.h"
#include "server/rpc/stream_limits.h"
#include "server/thread_pool.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using Code = grpc::StatusCode;
using Response = v1::ComputeDifferentialsResponse;

constexpr int kChunks = 400;
constexpr int kChunkBytes = 64 << 10;

/// Polls `pred` (a state of the server or of the work) until it holds; fails after many polls.
template <typename Pred>
bool Eventually(Pred pred) {
  for (int i = 0; i < 4000; ++i) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  return false;
}

/// A Service (for the reactor's admission, accounting and logging) whose
/// ComputeDifferentials pushes kChunks eager chunks of kChunkBytes; `linger`: the work
/// then runs on, polling its token, until the token trips (the call is over).
class PushingService final : public v1::GeomFit::CallbackService {
 public:
  explicit PushingService(double idle_seconds, bool linger = false)
      : limits_(0, std::chrono::milliseconds(static_cast<int64_t>(idle_seconds * 1e3))),
        pool_(1, 8),
        service_(nullptr, &pool_, &pool_, &stats_),
        linger_(linger) {
    service_.SetStreamLimits(&limits_);
  }

  grpc::ServerWriteReactor<Response>* ComputeDifferentials(grpc::CallbackServerContext* ctx,
                                                           const v1::ComputeDifferentialsRequest* request) override {
    return new WriteReactor<Response>(&service_, ctx, &pool_, {"Pushing", ""}, request,
                                      [this](const CancellationToken& cancel, ChunkSink<Response>* sink) {
                                        for (int i = 0; i < kChunks && !cancel.IsCancelled(); ++i) {
                                          Response chunk;
                                          chunk.set_vertex_offset(i);
                                          chunk.mutable_normals()->set_data(std::string(kChunkBytes, 'x'));
                                          sink->Push(std::move(chunk), i + 1 == kChunks);
                                          pushed_.fetch_add(1);
                                        }
                                        if (linger_) tripped_.store(Eventually([&] { return cancel.IsCancelled(); }));
                                        returned_.store(true);
                                        return cancel.Check();
                                      });
  }

  StreamLimits& limits() { return limits_; }
  int pushed() const { return pushed_.load(); }
  bool returned() const { return returned_.load(); }
  bool tripped() const { return tripped_.load(); }
  void StopPool() { pool_.Stop(); }

 private:
  RequestStats stats_;
  StreamLimits limits_;
  ThreadPool pool_;
  server::Service service_;
  std::atomic<int> pushed_{0};
  std::atomic<bool> returned_{false};
  const bool linger_;
  std::atomic<bool> tripped_{false};
};

/// The test service on a loopback port, and a stub whose streams take at most 16 KiB
/// ahead of the reader.
class Harness {
 public:
  explicit Harness(double idle_seconds, bool linger = false) : service_(idle_seconds, linger) {
    grpc::ServerBuilder builder;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    builder.RegisterService(&service_);
    server_ = builder.BuildAndStart();
    grpc::ChannelArguments args;
    args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
    args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 << 10);
    stub_ = v1::GeomFit::NewStub(
        grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port_), grpc::InsecureChannelCredentials(), args));
  }
  ~Harness() { Shutdown(); }
  void Shutdown() {
    if (server_ == nullptr) return;
    server_->Shutdown(std::chrono::system_clock::now());
    service_.StopPool();
    server_->Wait();
    server_.reset();
  }

  PushingService& service() { return service_; }
  v1::GeomFit::Stub& stub() { return *stub_; }

 private:
  PushingService service_;
  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::GeomFit::Stub> stub_;
};

/// The work is blocked in Push: it stays at the same chunk over many polls of a
/// stalled reader while two chunks are held.
void ExpectBlockedAtTwoChunks(PushingService& s) {
  ASSERT_TRUE(Eventually([&] { return s.limits().reserved_bytes() >= 2 * kChunkBytes; }));
  const int pushed = s.pushed();
  for (int i = 0; i < 20; ++i) {
    EXPECT_LE(s.limits().reserved_bytes(), 2 * (kChunkBytes + 64));
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  EXPECT_EQ(s.pushed(), pushed);
  EXPECT_LT(pushed, 10) << "of " << kChunks << " chunks";
  EXPECT_FALSE(s.returned());
  EXPECT_EQ(s.limits().open_streams(), 1);
}

TEST(WriteReactorTest, ReaderThatGoesAwayWakesTheBlockedWork) {
  Harness h(0);
  grpc::ClientContext ctx;
  auto reader = h.stub().ComputeDifferentials(&ctx, v1::ComputeDifferentialsRequest());
  ExpectBlockedAtTwoChunks(h.service());
  ctx.TryCancel();
  EXPECT_TRUE(Eventually([&] { return h.service().returned(); }));
  EXPECT_EQ(reader->Finish().error_code(), Code::CANCELLED);
  EXPECT_TRUE(Eventually([&] { return h.service().limits().open_streams() == 0; }));
  EXPECT_EQ(h.service().limits().reserved_bytes(), 0);
  EXPECT_LT(h.service().pushed(), kChunks);
}

TEST(WriteReactorTest, IdleTimeoutWakesTheBlockedWork) {
  Harness h(0.3);
  grpc::ClientContext ctx;
  auto reader = h.stub().ComputeDifferentials(&ctx, v1::ComputeDifferentialsRequest());
  EXPECT_TRUE(Eventually([&] { return h.service().returned(); }));
  EXPECT_TRUE(Eventually([&] { return h.service().limits().open_streams() == 0; }));
  EXPECT_EQ(h.service().limits().reserved_bytes(), 0);
  Response chunk;
  while (reader->Read(&chunk)) {
  }
  const grpc::Status s = reader->Finish();
  EXPECT_EQ(s.error_code(), Code::DEADLINE_EXCEEDED) << s.error_message();
  EXPECT_NE(s.error_message().find("--stream-idle-seconds"), std::string::npos) << s.error_message();
  EXPECT_LT(h.service().pushed(), kChunks);
}

TEST(WriteReactorTest, ShutdownWakesTheBlockedWork) {
  Harness h(0);
  grpc::ClientContext ctx;
  auto reader = h.stub().ComputeDifferentials(&ctx, v1::ComputeDifferentialsRequest());
  ExpectBlockedAtTwoChunks(h.service());
  h.Shutdown();  // returns only once the reactor is done: the work woke
  EXPECT_TRUE(h.service().returned());
  EXPECT_EQ(h.service().limits().open_streams(), 0);
  EXPECT_EQ(h.service().limits().reserved_bytes(), 0);
  Response chunk;
  while (reader->Read(&chunk)) {
  }
  EXPECT_FALSE(reader->Finish().ok());
}

TEST(WriteReactorTest, ReaderThatReadsGetsEveryChunkInOrder) {
  Harness h(0);
  grpc::ClientContext ctx;
  auto reader = h.stub().ComputeDifferentials(&ctx, v1::ComputeDifferentialsRequest());
  Response chunk;
  int read = 0;
  while (reader->Read(&chunk)) {
    EXPECT_EQ(chunk.vertex_offset(), read);
    EXPECT_EQ(chunk.normals().data().size(), static_cast<size_t>(kChunkBytes));
    ++read;
  }
  EXPECT_TRUE(reader->Finish().ok());
  EXPECT_EQ(read, kChunks);
  EXPECT_TRUE(Eventually([&] { return h.service().limits().open_streams() == 0; }));
  EXPECT_EQ(h.service().limits().reserved_bytes(), 0);
}

// The work may run on after its last chunk went out with OK, past OnDone, when gRPC
// frees the call's context: its token then trips (OnDone) without touching the context.
// (The token used to poll the freed context: a crash under load right after the last
// Push, made certain here by polling across OnDone.)
TEST(WriteReactorTest, WorkThatRunsOnAfterItsLastChunkSeesTheCallEnd) {
  Harness h(0, /*linger=*/true);
  grpc::ClientContext ctx;
  auto reader = h.stub().ComputeDifferentials(&ctx, v1::ComputeDifferentialsRequest());
  Response chunk;
  int read = 0;
  while (reader->Read(&chunk)) ++read;
  EXPECT_TRUE(reader->Finish().ok());
  EXPECT_EQ(read, kChunks);
  ASSERT_TRUE(Eventually([&] { return h.service().returned(); }));
  EXPECT_TRUE(h.service().tripped());
  EXPECT_EQ(h.service().limits().open_streams(), 0);
  EXPECT_EQ(h.service().limits().reserved_bytes(), 0);
}

}  // namespace
}  // namespace geomfit::server
