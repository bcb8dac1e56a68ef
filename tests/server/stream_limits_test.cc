// Stream integrity and bounded memory of the client streams (issue 13, items 5-6):
// garbage anywhere in an upload or update stream is INVALID_ARGUMENT with nothing
// committed; streams reserve their declared size against --max-inflight-bytes when the
// header arrives; silent streams end after --stream-idle-seconds; the server's own
// accounting (GetStatistics) shows the memory returned.
#include <future>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/generic/generic_stub.h>
#include <gtest/gtest.h>

#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;
using Code = grpc::StatusCode;

constexpr const char* kUpload = "/geomfit.v1.GeomFit/UploadMesh";
constexpr const char* kUpdate = "/geomfit.v1.GeomFit/UpdatePositions";
/// Field 2, length-delimited, 100 bytes announced, 3 present: no message parses it.
const std::string kGarbage("\x12\x64" "abc", 5);

/// A client stream of raw messages over the generic API. `Send` writes some messages
/// (false once the server has ended the call); `Finish` half-closes, cancels, or just
/// waits for the server to end the call, and returns the status.
class RawStream {
 public:
  RawStream(const std::shared_ptr<grpc::Channel>& channel, const char* method) : stub_(channel) {
    ctx_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    call_ = stub_.PrepareCall(&ctx_, method, &cq_);
    call_->StartCall(Tag(1));
    Wait();
  }
  ~RawStream() {
    cq_.Shutdown();
    void* tag;
    bool ok;
    while (cq_.Next(&tag, &ok)) {
    }
  }

  bool Send(const std::vector<std::string>& messages) {
    for (const std::string& m : messages) {
      grpc::Slice slice(m);
      grpc::ByteBuffer buffer(&slice, 1);
      call_->Write(buffer, Tag(2));
      if (!Wait()) return false;
    }
    return true;
  }

  enum End { kHalfClose, kCancel, kAwait };
  grpc::Status Finish(End end = kHalfClose) {
    if (end == kCancel) ctx_.TryCancel();
    if (end == kHalfClose) {
      call_->WritesDone(Tag(3));
      Wait();
    }
    grpc::ByteBuffer out;
    call_->Read(&out, Tag(4));
    if (Wait()) {
      std::vector<grpc::Slice> slices;
      (void)out.Dump(&slices);
      std::string bytes;
      for (const grpc::Slice& s : slices) bytes.append(reinterpret_cast<const char*>(s.begin()), s.size());
      (void)response.ParseFromString(bytes);
    }
    grpc::Status status;
    call_->Finish(&status, Tag(5));
    Wait();
    return status;
  }

  v1::MeshInfo response;

 private:
  static void* Tag(intptr_t i) { return reinterpret_cast<void*>(i); }
  bool Wait() {
    void* tag;
    bool ok = false;
    EXPECT_TRUE(cq_.Next(&tag, &ok));
    return ok;
  }

  grpc::GenericStub stub_;
  grpc::CompletionQueue cq_;
  grpc::ClientContext ctx_;
  std::unique_ptr<grpc::GenericClientAsyncReaderWriter> call_;
};

template <typename Message>
std::vector<std::string> Serialized(const std::vector<Message>& messages) {
  std::vector<std::string> out;
  for (const Message& m : messages) out.push_back(m.SerializeAsString());
  return out;
}

/// `messages` with kGarbage inserted at `at` (at == size: appended).
std::vector<std::string> WithGarbage(std::vector<std::string> messages, size_t at) {
  messages.insert(messages.begin() + static_cast<std::ptrdiff_t>(at), kGarbage);
  return messages;
}

v1::Statistics Stats(v1::GeomFit::Stub& stub) {
  grpc::ClientContext ctx;
  v1::Statistics s;
  EXPECT_TRUE(stub.GetStatistics(&ctx, v1::GetStatisticsRequest(), &s).ok());
  return s;
}

int ListedMeshes(v1::GeomFit::Stub& stub) {
  grpc::ClientContext ctx;
  v1::ListMeshesResponse list;
  EXPECT_TRUE(stub.ListMeshes(&ctx, v1::ListMeshesRequest(), &list).ok());
  return list.meshes_size();
}

v1::MeshInfo Info(v1::GeomFit::Stub& stub, const std::string& id) {
  grpc::ClientContext ctx;
  v1::GetMeshRequest get;
  get.set_mesh_id(id);
  v1::MeshInfo info;
  EXPECT_TRUE(stub.GetMesh(&ctx, get, &info).ok());
  return info;
}

void ExpectGarbageRejected(const grpc::Status& s, size_t at, const char* type) {
  EXPECT_EQ(s.error_code(), Code::INVALID_ARGUMENT) << s.error_message();
  const std::string expected = "message " + std::to_string(at + 1) + " of the stream is not a valid " + type;
  EXPECT_NE(s.error_message().find(expected), std::string::npos) << s.error_message();
}

TEST(StreamIntegrityTest, GarbageAnywhereInAnUploadCommitsNothing) {
  InProcessServer server;
  const Mesh mesh = testing::TestTorus(6);
  const std::vector<std::string> valid = Serialized(wire::UploadChunks(mesh, v1::MeshHeader(), 20));
  ASSERT_GE(valid.size(), 4u);
  // Start, middle, just before the end, and after the last valid message (the stream
  // is complete then: the old reader took the garbage for its end and stored it).
  for (const size_t at : {size_t{0}, valid.size() / 2, valid.size() - 1, valid.size()}) {
    SCOPED_TRACE("garbage at message " + std::to_string(at + 1));
    RawStream stream(server.channel(), kUpload);
    stream.Send(WithGarbage(valid, at));
    ExpectGarbageRejected(stream.Finish(), at, "geomfit.v1.UploadMeshRequest");
    EXPECT_EQ(ListedMeshes(server.stub()), 0);
    const v1::Statistics stats = Stats(server.stub());
    EXPECT_EQ(stats.stored_meshes(), 0);
    EXPECT_EQ(stats.inflight_bytes(), 0);
    EXPECT_EQ(stats.open_streams(), 0);
  }
  // The same stream without garbage is stored, over the same raw path.
  RawStream stream(server.channel(), kUpload);
  ASSERT_TRUE(stream.Send(valid));
  const grpc::Status s = stream.Finish();
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(stream.response.num_vertices(), mesh.NumVertices());
  EXPECT_EQ(ListedMeshes(server.stub()), 1);
}

TEST(StreamIntegrityTest, GarbageAnywhereInAnUpdateLeavesTheRevision) {
  InProcessServer server;
  const Mesh mesh = testing::TestTorus(6);
  auto stored = testing::UploadMesh(server.stub(), mesh, "target");
  ASSERT_TRUE(stored.ok()) << stored.status();
  v1::UpdateHeader header;
  header.set_mesh_id(stored->mesh_id());
  const Positions moved = mesh.positions * 2.0;
  const std::vector<std::string> valid = Serialized(wire::UpdateChunks(moved, header, 20));
  ASSERT_GE(valid.size(), 4u);
  for (const size_t at : {size_t{0}, valid.size() / 2, valid.size() - 1, valid.size()}) {
    SCOPED_TRACE("garbage at message " + std::to_string(at + 1));
    RawStream stream(server.channel(), kUpdate);
    stream.Send(WithGarbage(valid, at));
    ExpectGarbageRejected(stream.Finish(), at, "geomfit.v1.UpdatePositionsRequest");
    EXPECT_EQ(Info(server.stub(), stored->mesh_id()).revision(), 1);
    auto now = testing::Download(server.stub(), stored->mesh_id());
    ASSERT_TRUE(now.ok()) << now.status();
    EXPECT_TRUE(testing::SameMesh(*now, mesh));
    EXPECT_EQ(Stats(server.stub()).inflight_bytes(), 0);
  }
  RawStream stream(server.channel(), kUpdate);
  ASSERT_TRUE(stream.Send(valid));
  const grpc::Status s = stream.Finish();
  ASSERT_TRUE(s.ok()) << s.error_message();
  EXPECT_EQ(stream.response.revision(), 2);
}

// gRPC 1.51's callback API answers a unary request that does not parse itself, before
// any service code runs: UNIMPLEMENTED with an empty message (README, Security). What
// the server guarantees: an error, and nothing changed.
TEST(StreamIntegrityTest, UnparseableUnaryRequestIsAnErrorAndChangesNothing) {
  InProcessServer server;
  const Mesh mesh = testing::TestTorus(6);
  auto stored = testing::UploadMesh(server.stub(), mesh, "target");
  ASSERT_TRUE(stored.ok()) << stored.status();
  grpc::Slice slice(kGarbage);
  grpc::ByteBuffer in(&slice, 1), out;
  grpc::GenericStub stub(server.channel());
  grpc::ClientContext ctx;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&ctx, "/geomfit.v1.GeomFit/SetPositions", grpc::StubOptions(), &in, &out,
                 [&done](grpc::Status s) { done.set_value(s); });
  const grpc::Status s = done.get_future().get();
  EXPECT_EQ(s.error_code(), Code::UNIMPLEMENTED) << s.error_message();
  EXPECT_EQ(Info(server.stub(), stored->mesh_id()).revision(), 1);
  EXPECT_EQ(testing::HealthCheck(server.channel()), "SERVING");
}

ServerOptions Budgeted(int64_t budget, double idle_seconds) {
  ServerOptions o = testing::LoopbackOptions();
  o.max_inflight_bytes = budget;
  o.stream_idle_seconds = idle_seconds;
  return o;
}

std::string Header(int64_t vertices, int64_t faces) {
  v1::UploadMeshRequest r;
  r.mutable_header()->set_num_vertices(vertices);
  r.mutable_header()->set_num_faces(faces);
  return r.SerializeAsString();
}

/// Polls the server's accounting until `pred` holds (the header is processed after the
/// client's write completes); fails after many polls.
template <typename Pred>
v1::Statistics StatsWhen(v1::GeomFit::Stub& stub, Pred pred) {
  v1::Statistics s;
  for (int i = 0; i < 2000; ++i) {
    s = Stats(stub);
    if (pred(s)) return s;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
  ADD_FAILURE() << "accounting never reached the state: " << s.ShortDebugString();
  return s;
}

TEST(StreamLimitsTest, FlagsAndDefaults) {
  auto d = ParseServerOptions({"--cache-bytes", "64M"});
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->stream_idle_seconds, 30);
  EXPECT_EQ(d->InflightBudget(), 32 << 20) << "default: half of --cache-bytes";
  auto o = ParseServerOptions({"--max-inflight-bytes", "8M", "--stream-idle-seconds", "2.5"});
  ASSERT_TRUE(o.ok()) << o.status();
  EXPECT_EQ(o->InflightBudget(), 8 << 20);
  EXPECT_EQ(o->stream_idle_seconds, 2.5);
  auto bad = ParseServerOptions({"--stream-idle-seconds", "-1"});
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("stream-idle-seconds"), std::string::npos) << bad.status();
}

TEST(StreamLimitsTest, HeaderReservesTheDeclaredSizeAgainstTheBudget) {
  // 5000 vertices + 10000 faces declare 2 x (24 x 5000 + 16 x 10000) = 560000 bytes.
  constexpr int64_t kDeclared = 560000;
  InProcessServer server(Budgeted(1'000'000, 0));
  EXPECT_EQ(Stats(server.stub()).inflight_budget_bytes(), 1'000'000);
  {
    RawStream too_big(server.channel(), kUpload);
    too_big.Send({Header(10000, 20000)});
    const grpc::Status s = too_big.Finish();
    EXPECT_EQ(s.error_code(), Code::RESOURCE_EXHAUSTED) << s.error_message();
    EXPECT_NE(s.error_message().find("--max-inflight-bytes"), std::string::npos) << s.error_message();
  }
  RawStream held(server.channel(), kUpload);
  ASSERT_TRUE(held.Send({Header(5000, 10000)}));
  v1::Statistics s = StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.inflight_bytes() > 0; });
  EXPECT_EQ(s.inflight_bytes(), kDeclared);
  EXPECT_EQ(s.open_streams(), 1);
  {
    RawStream second(server.channel(), kUpload);
    second.Send({Header(5000, 10000)});
    const grpc::Status refused = second.Finish();
    EXPECT_EQ(refused.error_code(), Code::RESOURCE_EXHAUSTED) << refused.error_message();
  }
  EXPECT_EQ(Stats(server.stub()).inflight_bytes(), kDeclared);
  EXPECT_EQ(held.Finish(RawStream::kCancel).error_code(), Code::CANCELLED);
  s = StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 0; });
  EXPECT_EQ(s.inflight_bytes(), 0);
  // The budget is free again: a real upload goes through, and gives it back.
  auto stored = testing::UploadMesh(server.stub(), testing::TestTorus(6), "after");
  ASSERT_TRUE(stored.ok()) << stored.status();
  s = Stats(server.stub());
  EXPECT_EQ(s.inflight_bytes(), 0);
  EXPECT_EQ(s.open_streams(), 0);
}

TEST(StreamLimitsTest, UpdateReservesItsMeshSizeAndRefusesExtraRows) {
  InProcessServer server(Budgeted(1'000'000, 0));
  const Mesh mesh = testing::TestTorus(6);
  auto stored = testing::UploadMesh(server.stub(), mesh, "target");
  ASSERT_TRUE(stored.ok()) << stored.status();
  v1::UpdatePositionsRequest header;
  header.mutable_header()->set_mesh_id(stored->mesh_id());
  RawStream held(server.channel(), kUpdate);
  ASSERT_TRUE(held.Send({header.SerializeAsString()}));
  const v1::Statistics s = StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.inflight_bytes() > 0; });
  EXPECT_EQ(s.inflight_bytes(), 2 * 24 * mesh.NumVertices());
  // One row more than the mesh has is refused when it arrives.
  Positions extra(mesh.NumVertices() + 1, 3);
  extra.setZero();
  std::vector<std::string> rows = Serialized(wire::UpdateChunks(extra, v1::UpdateHeader(), 1000));
  rows.erase(rows.begin());  // its header
  held.Send(rows);
  const grpc::Status refused = held.Finish();
  EXPECT_EQ(refused.error_code(), Code::INVALID_ARGUMENT) << refused.error_message();
  EXPECT_NE(refused.error_message().find("exceed the declared count"), std::string::npos) << refused.error_message();
  EXPECT_EQ(Stats(server.stub()).inflight_bytes(), 0);
  EXPECT_EQ(Info(server.stub(), stored->mesh_id()).revision(), 1);
}

TEST(StreamLimitsTest, StalledStreamsEndAtTheIdleTimeoutAndReturnTheirMemory) {
  InProcessServer server(Budgeted(0, 0.3));
  std::vector<std::unique_ptr<RawStream>> stalled;
  for (int i = 0; i < 3; ++i) {
    stalled.push_back(std::make_unique<RawStream>(server.channel(), kUpload));
    ASSERT_TRUE(stalled.back()->Send({Header(100000, 200000)}));  // then silence
  }
  for (auto& stream : stalled) {
    // No half-close: the call ends only when the server ends it (or at the client's
    // 60 s deadline, whose message differs).
    const grpc::Status s = stream->Finish(RawStream::kAwait);
    EXPECT_EQ(s.error_code(), Code::DEADLINE_EXCEEDED) << s.error_message();
    EXPECT_NE(s.error_message().find("--stream-idle-seconds"), std::string::npos) << s.error_message();
  }
  const v1::Statistics s = Stats(server.stub());
  EXPECT_EQ(s.inflight_bytes(), 0);
  EXPECT_EQ(s.open_streams(), 0);
  EXPECT_EQ(s.stored_meshes(), 0);
}

// A reader that takes the first chunk and stops: the download is made lazily (one chunk
// ahead), and once no write completes for the idle time the server ends the call with
// DEADLINE_EXCEEDED (sent ahead of the unread data).
// Without the watchdog the read below would wait for the client's own 60 s deadline.
TEST(StreamLimitsTest, DownloadReaderThatStopsReadingIsEnded) {
  InProcessServer server(Budgeted(0, 0.3));
  auto stored = testing::UploadMesh(server.stub(), testing::TestTorus(160), "big");
  ASSERT_TRUE(stored.ok()) << stored.status();
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 << 10);
  auto channel = grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(server.port()),
                                           grpc::InsecureChannelCredentials(), args);
  v1::GeomFit::Stub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  v1::DownloadMeshRequest request;
  request.set_mesh_id(stored->mesh_id());
  request.set_chunk_rows(64);
  auto reader = stub.DownloadMesh(&ctx, request);
  v1::DownloadMeshResponse chunk;
  ASSERT_TRUE(reader->Read(&chunk));
  ASSERT_TRUE(chunk.has_info());
  ASSERT_GT(chunk.info().num_vertices() * 24, 1 << 20) << "the mesh must outgrow the transport's windows";
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));  // stop reading
  int64_t read = 1;
  while (reader->Read(&chunk)) ++read;
  const grpc::Status s = reader->Finish();
  EXPECT_EQ(s.error_code(), Code::DEADLINE_EXCEEDED) << s.error_message() << " after " << read << " chunks";
  EXPECT_NE(s.error_message().find("--stream-idle-seconds"), std::string::npos) << s.error_message();
  EXPECT_EQ(testing::HealthCheck(server.channel()), "SERVING");
}

}  // namespace
}  // namespace geomfit::server
