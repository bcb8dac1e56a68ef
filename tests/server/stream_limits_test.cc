// Stream integrity and bounded memory of the client streams (issue 13, items 5-6):
// garbage anywhere in an upload or update stream is INVALID_ARGUMENT with nothing
// committed; streams reserve their declared size against --max-inflight-bytes when the
// header arrives; silent streams end after --stream-idle-seconds; the server's own
// accounting (GetStatistics) shows the memory returned.
#include <algorithm>
#include <functional>
#include <future>
#include <map>
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

/// A channel whose streams take at most 16 KiB ahead of the reader (no window growth):
/// a stream it does not read soon stops the server's writes.
std::shared_ptr<grpc::Channel> SmallWindowChannel(int port) {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
  args.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 16 << 10);
  return grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials(), args);
}

// A reader that takes the first chunk and stops: the download is made lazily (one chunk
// ahead), and once no write completes for the idle time the server ends the call with
// DEADLINE_EXCEEDED (sent ahead of the unread data).
// Without the watchdog the read below would wait for the client's own 60 s deadline.
TEST(StreamLimitsTest, DownloadReaderThatStopsReadingIsEnded) {
  InProcessServer server(Budgeted(0, 0.3));
  auto stored = testing::UploadMesh(server.stub(), testing::TestTorus(160), "big");
  ASSERT_TRUE(stored.ok()) << stored.status();
  v1::GeomFit::Stub stub(SmallWindowChannel(server.port()));
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
  // Stop reading until the server ended the stream (an event, not a sleep that a loaded
  // machine outlasts); the client's 60 s deadline would end it much later.
  StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 0; });
  int64_t read = 1;
  while (reader->Read(&chunk)) ++read;
  const grpc::Status s = reader->Finish();
  EXPECT_EQ(s.error_code(), Code::DEADLINE_EXCEEDED) << s.error_message() << " after " << read << " chunks";
  EXPECT_NE(s.error_message().find("--stream-idle-seconds"), std::string::npos) << s.error_message();
  EXPECT_EQ(testing::HealthCheck(server.channel()), "SERVING");
}

ServerOptions OneWorker(double idle_seconds) {
  ServerOptions o = Budgeted(0, idle_seconds);
  o.workers = 1;  // FIFO: a request sent after another runs once that one's work returned
  return o;
}

/// The bytes of every array a stream's chunks carry, concatenated per field (summaries
/// aside): equal for equal results, whatever the chunk boundaries.
template <typename Response>
std::map<std::string, std::string> Columns(const std::vector<Response>& chunks) {
  std::map<std::string, std::string> out;
  std::function<void(const google::protobuf::Message&, const std::string&)> add =
      [&](const google::protobuf::Message& m, const std::string& path) {
        const google::protobuf::Reflection* r = m.GetReflection();
        std::vector<const google::protobuf::FieldDescriptor*> fields;
        r->ListFields(m, &fields);
        for (const google::protobuf::FieldDescriptor* f : fields) {
          if (f->name() == "summary") continue;
          if (f->name() == "data" && f->type() == google::protobuf::FieldDescriptor::TYPE_BYTES) {
            out[path] += r->GetString(m, f);
          } else if (f->type() == google::protobuf::FieldDescriptor::TYPE_MESSAGE && !f->is_repeated()) {
            add(r->GetMessage(m, f), path + "." + f->name());
          }
        }
      };
  for (const Response& c : chunks) add(c, "");
  return out;
}

template <typename Response>
int64_t Largest(const std::vector<Response>& chunks) {
  int64_t largest = 0;
  for (const Response& c : chunks) largest = std::max<int64_t>(largest, c.ByteSizeLong());
  return largest;
}
template <typename Response>
int64_t Total(const std::vector<Response>& chunks) {
  int64_t total = 0;
  for (const Response& c : chunks) total += static_cast<int64_t>(c.ByteSizeLong());
  return total;
}

v1::ComputeDifferentialsRequest EveryQuantity(const std::string& mesh_id) {
  v1::ComputeDifferentialsRequest r;
  r.set_mesh_id(mesh_id);
  for (int q = v1::QUANTITY_NORMALS; q <= v1::QUANTITY_CURVATURE_TENSOR; ++q) r.add_quantities(v1::Quantity(q));
  r.set_diagnostics(true);
  r.set_chunk_rows(256);
  return r;
}

/// Reads a whole server stream.
template <typename Response, typename Request, typename Call>
grpc::Status ReadAll(Call call, const Request& request, std::vector<Response>* chunks) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto reader = call(&ctx, request);
  Response chunk;
  while (reader->Read(&chunk)) chunks->push_back(chunk);
  return reader->Finish();
}

// A ComputeDifferentials reader that opens a response of many chunks and reads none:
// the work hands every chunk over without waiting (they are encoded only when the
// transport can take one), so the stream holds at most two encoded chunks, visible in
// the server's in-flight bytes, until the client goes; the results are the same as a
// fresh computation streamed while it fits.
TEST(ServerStreamLimitsTest, ComputeReaderThatReadsNothingHoldsAtMostTwoChunks) {
  InProcessServer server(OneWorker(0));  // no watchdog: the stalled stream waits for its client
  const Mesh mesh = testing::TestTorus(100);
  auto stored = testing::UploadMesh(server.stub(), mesh, "big", 20000);
  ASSERT_TRUE(stored.ok()) << stored.status();
  const v1::ComputeDifferentialsRequest request = EveryQuantity(stored->mesh_id());
  v1::GeomFit::Stub slow(SmallWindowChannel(server.port()));
  grpc::ClientContext stalled_ctx;
  auto stalled = slow.ComputeDifferentials(&stalled_ctx, request);  // never read
  StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 1; });  // queued first
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  const grpc::Status read = testing::Compute(server.stub(), request, &chunks);
  ASSERT_TRUE(read.ok()) << read.error_message();
  const int64_t largest = Largest(chunks), total = Total(chunks);
  ASSERT_GT(total, 2 << 20) << "the response must outgrow the transport's windows";
  ASSERT_GE(total, 40 * largest);
  const v1::Statistics s = Stats(server.stub());
  EXPECT_EQ(s.open_streams(), 1);
  EXPECT_GT(s.inflight_bytes(), 0) << "the chunk waiting for the reader is counted";
  EXPECT_LE(s.inflight_bytes(), 2 * largest) << "of a " << total << "-byte response";
  stalled_ctx.TryCancel();
  const v1::Statistics after =
      StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 0; });
  EXPECT_EQ(after.inflight_bytes(), 0);
  EXPECT_EQ(stalled->Finish().error_code(), Code::CANCELLED);

  // Identical results: this server's (from the cached arrays) and a fresh one's (chunks
  // made while the fit fills the arrays).
  InProcessServer fresh(OneWorker(0));
  auto again = testing::UploadMesh(fresh.stub(), mesh, "big", 20000);
  ASSERT_TRUE(again.ok()) << again.status();
  std::vector<v1::ComputeDifferentialsResponse> streamed;
  ASSERT_TRUE(testing::Compute(fresh.stub(), EveryQuantity(again->mesh_id()), &streamed).ok());
  const auto columns = Columns(chunks);
  EXPECT_EQ(columns.size(), 12u);  // 8 quantities, 4 diagnostics
  EXPECT_EQ(columns.at(".normals").size(), 24u * mesh.NumVertices());
  EXPECT_TRUE(columns == Columns(streamed));
}

// The same reader with --stream-idle-seconds: once its write has waited that long the
// server ends the call with DEADLINE_EXCEEDED and the accounting is back to zero.
TEST(ServerStreamLimitsTest, ComputeReaderThatReadsNothingIsEndedAtTheIdleTimeout) {
  InProcessServer server(OneWorker(0.3));
  auto stored = testing::UploadMesh(server.stub(), testing::TestTorus(100), "big", 20000);
  ASSERT_TRUE(stored.ok()) << stored.status();
  v1::GeomFit::Stub slow(SmallWindowChannel(server.port()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto stalled = slow.ComputeDifferentials(&ctx, EveryQuantity(stored->mesh_id()));
  StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 1; });
  const v1::Statistics s =
      StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 0; });
  EXPECT_EQ(s.inflight_bytes(), 0);
  v1::ComputeDifferentialsResponse chunk;
  while (stalled->Read(&chunk)) {
  }
  const grpc::Status status = stalled->Finish();
  EXPECT_EQ(status.error_code(), Code::DEADLINE_EXCEEDED) << status.error_message();
  EXPECT_NE(status.error_message().find("--stream-idle-seconds"), std::string::npos) << status.error_message();
  EXPECT_EQ(testing::HealthCheck(server.channel()), "SERVING");
}

v1::ProjectPointsRequest FacePoints(const std::string& mesh_id, const Mesh& mesh, int per_face) {
  v1::ProjectPointsRequest r;
  r.set_mesh_id(mesh_id);
  r.set_chunk_rows(1000);
  const int64_t n = mesh.NumFaces() * per_face;
  std::vector<int32_t> faces(n);
  std::vector<double> natural(2 * n);
  for (int64_t i = 0; i < n; ++i) {
    faces[i] = static_cast<int32_t>(i / per_face);
    natural[2 * i] = 0.1 + 0.6 * (i % per_face) / per_face;
    natural[2 * i + 1] = 0.2;
  }
  wire::EncodeInts(faces.data(), n, 0, r.mutable_faces());
  wire::EncodeDoubles(natural.data(), n, 2, r.mutable_natural());
  return r;
}

// ProjectPoints computes every point first, then hands its chunks over lazily: a reader
// that reads nothing holds the points and at most two encoded chunks.
TEST(ServerStreamLimitsTest, ProjectPointsReaderThatReadsNothingHoldsAtMostTwoChunks) {
  InProcessServer server(OneWorker(0));
  const Mesh mesh = testing::TestTorus(40);
  auto stored = testing::UploadMesh(server.stub(), mesh, "surface", 20000);
  ASSERT_TRUE(stored.ok()) << stored.status();
  const v1::ProjectPointsRequest request = FacePoints(stored->mesh_id(), mesh, 12);
  v1::GeomFit::Stub slow(SmallWindowChannel(server.port()));
  grpc::ClientContext stalled_ctx;
  auto stalled = slow.ProjectPoints(&stalled_ctx, request);
  StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 1; });
  std::vector<v1::ProjectPointsResponse> chunks;
  const grpc::Status read = ReadAll<v1::ProjectPointsResponse>(
      [&](grpc::ClientContext* ctx, const v1::ProjectPointsRequest& r) { return server.stub().ProjectPoints(ctx, r); },
      request, &chunks);
  ASSERT_TRUE(read.ok()) << read.error_message();
  const int64_t largest = Largest(chunks), total = Total(chunks);
  ASSERT_GT(total, 2 << 20) << "the response must outgrow the transport's windows";
  const v1::Statistics s = Stats(server.stub());
  EXPECT_EQ(s.open_streams(), 1);
  EXPECT_GT(s.inflight_bytes(), 0);
  EXPECT_LE(s.inflight_bytes(), 2 * largest) << "of a " << total << "-byte response";
  stalled_ctx.TryCancel();
  const v1::Statistics after =
      StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 0; });
  EXPECT_EQ(after.inflight_bytes(), 0);
  // Every point, in order, once.
  const auto columns = Columns(chunks);
  EXPECT_EQ(columns.at(".positions").size(), 24u * 12 * mesh.NumFaces());
  int64_t next = 0;
  for (const v1::ProjectPointsResponse& c : chunks) {
    EXPECT_EQ(c.offset(), next);
    next += c.faces().shape_size() > 0 ? c.faces().shape(0) : 0;
  }
  EXPECT_EQ(next, 12 * mesh.NumFaces());
}

// A watcher that stops reading a job's events (a finished flow's, replayed from the
// first, with positions in every event) is ended with DEADLINE_EXCEEDED once an event
// has waited for --stream-idle-seconds; what it held is released.
TEST(ServerStreamLimitsTest, WatcherThatStopsReadingIsEndedAtTheIdleTimeout) {
  InProcessServer server(Budgeted(0, 0.3));
  auto stored = testing::UploadMesh(server.stub(), testing::TestSphere(12), "sphere");
  ASSERT_TRUE(stored.ok()) << stored.status();
  v1::FlowJob spec;
  spec.set_mesh_id(stored->mesh_id());
  spec.set_kind("mcf");
  spec.set_scheme("semi_implicit");
  spec.set_dt(1e-4);
  spec.set_steps(60);
  spec.set_snapshot_every(1);
  spec.set_send_positions(true);
  v1::Job job;
  {
    grpc::ClientContext ctx;
    const grpc::Status started = server.stub().StartFlow(&ctx, spec, &job);
    ASSERT_TRUE(started.ok()) << started.error_message();
  }
  std::vector<v1::JobEvent> events;  // a reader that reads: the whole log
  ASSERT_TRUE(testing::WatchJob(server.stub(), job.job_id(), 0, &events).ok());
  ASSERT_TRUE(!events.empty() && events.back().final());
  ASSERT_GT(Total(events), 1 << 20) << "the events must outgrow the transport's windows";
  EXPECT_EQ(Stats(server.stub()).open_streams(), 0);

  v1::GeomFit::Stub slow(SmallWindowChannel(server.port()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  v1::WatchJobRequest watch;
  watch.set_job_id(job.job_id());
  auto stalled = slow.WatchJob(&ctx, watch);  // never read until the server ended it
  StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 1 && s.inflight_bytes() > 0; });
  const v1::Statistics s =
      StatsWhen(server.stub(), [](const v1::Statistics& s) { return s.open_streams() == 0; });
  EXPECT_EQ(s.inflight_bytes(), 0);
  v1::JobEvent event;
  int64_t read = 0;
  while (stalled->Read(&event)) ++read;
  const grpc::Status status = stalled->Finish();
  EXPECT_EQ(status.error_code(), Code::DEADLINE_EXCEEDED) << status.error_message() << " after " << read;
  EXPECT_NE(status.error_message().find("--stream-idle-seconds"), std::string::npos) << status.error_message();
  EXPECT_LT(read, static_cast<int64_t>(events.size()));
}

}  // namespace
}  // namespace geomfit::server
