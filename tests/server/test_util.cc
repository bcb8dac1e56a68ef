#include "tests/server/test_util.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <future>
#include <thread>

#include <grpcpp/generic/generic_stub.h>
#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include "core/surfaces/analytic.h"
#include "proto/wire.h"

namespace geomfit::server::testing {

Mesh TestTorus(int n) {
  GeneratorOptions o;
  o.n = n;
  return GenerateTorusMesh(o);
}

Mesh TestSphere(int n) {
  GeneratorOptions o;
  o.n = n;
  return GenerateSphereMesh(o);
}

int FreePort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr));
  socklen_t len = sizeof(addr);
  getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  close(fd);
  return ntohs(addr.sin_port);
}

ServerOptions LoopbackOptions() {
  ServerOptions o;
  o.host = "127.0.0.1";
  o.port = 0;
  o.store = "memory";
  o.cache_bytes = 256 << 20;
  o.workers = 2;
  o.threads = 1;
  o.drain_seconds = 2;
  o.log_level = "warn";
  return o;
}

std::shared_ptr<grpc::Channel> LoopbackChannel(int port, int64_t max_message_bytes) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(static_cast<int>(max_message_bytes));
  args.SetMaxSendMessageSize(static_cast<int>(max_message_bytes));
  return grpc::CreateCustomChannel("127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials(), args);
}

InProcessServer::InProcessServer(ServerOptions options) {
  spdlog::set_level(spdlog::level::from_str(options.log_level));
  auto s = Server::Start(options);
  EXPECT_TRUE(s.ok()) << s.status();
  server_ = std::move(*s);
  channel_ = LoopbackChannel(server_->port());
  stub_ = v1::GeomFit::NewStub(channel_);
}

InProcessServer::~InProcessServer() { server_->Shutdown(1); }

template <typename Request>
static grpc::Status SendStream(
    std::unique_ptr<grpc::ClientWriter<Request>> (v1::GeomFit::Stub::*start)(grpc::ClientContext*, v1::MeshInfo*),
    v1::GeomFit::Stub& stub, const std::vector<Request>& requests, v1::MeshInfo* info) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
  auto writer = (stub.*start)(&ctx, info);
  for (const Request& r : requests)
    if (!writer->Write(r)) break;
  writer->WritesDone();
  return writer->Finish();
}

grpc::Status SendUpload(v1::GeomFit::Stub& stub, const std::vector<v1::UploadMeshRequest>& requests,
                        v1::MeshInfo* info) {
  return SendStream<v1::UploadMeshRequest>(&v1::GeomFit::Stub::UploadMesh, stub, requests, info);
}

grpc::Status SendUpdate(v1::GeomFit::Stub& stub, const std::vector<v1::UpdatePositionsRequest>& requests,
                        v1::MeshInfo* info) {
  return SendStream<v1::UpdatePositionsRequest>(&v1::GeomFit::Stub::UpdatePositions, stub, requests, info);
}

absl::StatusOr<v1::MeshInfo> UploadMesh(v1::GeomFit::Stub& stub, const Mesh& mesh, const std::string& name,
                                        int64_t chunk_rows) {
  v1::MeshHeader header;
  header.set_name(name);
  v1::MeshInfo info;
  grpc::Status s = SendUpload(stub, wire::UploadChunks(mesh, header, chunk_rows), &info);
  if (!s.ok()) return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
  return info;
}

grpc::Status Compute(v1::GeomFit::Stub& stub, const v1::ComputeDifferentialsRequest& request,
                     std::vector<v1::ComputeDifferentialsResponse>* chunks, int deadline_ms) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::milliseconds(deadline_ms));
  auto reader = stub.ComputeDifferentials(&ctx, request);
  v1::ComputeDifferentialsResponse r;
  while (reader->Read(&r)) chunks->push_back(r);
  return reader->Finish();
}

absl::StatusOr<Mesh> Download(v1::GeomFit::Stub& stub, const std::string& mesh_id) {
  grpc::ClientContext ctx;
  v1::DownloadMeshRequest request;
  request.set_mesh_id(mesh_id);
  request.set_chunk_rows(777);
  auto reader = stub.DownloadMesh(&ctx, request);
  v1::DownloadMeshResponse r;
  std::vector<double> positions;
  std::vector<int32_t> faces;
  while (reader->Read(&r)) {
    if (r.has_positions()) {
      const std::string& d = r.positions().positions().data();
      const size_t old = positions.size();
      positions.resize(old + d.size() / 8);
      std::memcpy(positions.data() + old, d.data(), d.size());
    } else if (r.has_faces()) {
      const std::string& d = r.faces().faces().data();
      const size_t old = faces.size();
      faces.resize(old + d.size() / 4);
      std::memcpy(faces.data() + old, d.data(), d.size());
    }
  }
  grpc::Status s = reader->Finish();
  if (!s.ok()) return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
  Mesh m;
  m.positions = Eigen::Map<Positions>(positions.data(), static_cast<int64_t>(positions.size() / 3), 3);
  m.faces = Eigen::Map<Faces>(faces.data(), static_cast<int64_t>(faces.size() / 4), 4);
  return m;
}

std::string HealthCheck(const std::shared_ptr<grpc::Channel>& channel, const std::string& service) {
  // HealthCheckRequest { string service = 1; }
  std::string request;
  if (!service.empty()) {
    request.push_back(0x0a);
    request.push_back(static_cast<char>(service.size()));
    request += service;
  }
  grpc::Slice slice(request);
  grpc::ByteBuffer in(&slice, 1), out;
  grpc::GenericStub stub(channel);
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  std::promise<grpc::Status> done;
  stub.UnaryCall(&ctx, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &in, &out,
                 [&done](grpc::Status s) { done.set_value(s); });
  grpc::Status s = done.get_future().get();
  if (!s.ok()) return "error " + std::to_string(s.error_code()) + ": " + s.error_message();
  std::vector<grpc::Slice> slices;
  (void)out.Dump(&slices);
  std::string bytes;
  for (const grpc::Slice& sl : slices) bytes.append(reinterpret_cast<const char*>(sl.begin()), sl.size());
  // HealthCheckResponse { ServingStatus status = 1; } SERVING = 1, NOT_SERVING = 2
  if (bytes == std::string("\x08\x01", 2)) return "SERVING";
  if (bytes == std::string("\x08\x02", 2)) return "NOT_SERVING";
  return "unexpected response of " + std::to_string(bytes.size()) + " bytes";
}

bool SameMesh(const Mesh& a, const Mesh& b) {
  return a.positions.rows() == b.positions.rows() && a.faces.rows() == b.faces.rows() &&
         std::memcmp(a.positions.data(), b.positions.data(), sizeof(double) * a.positions.size()) == 0 &&
         std::memcmp(a.faces.data(), b.faces.data(), sizeof(int32_t) * a.faces.size()) == 0;
}

absl::StatusOr<v1::Job> StartRefineJob(v1::GeomFit::Stub& stub, const std::string& mesh_id, int levels,
                                       int factor) {
  v1::StartJobRequest request;
  v1::RefineJob* spec = request.mutable_refine();
  spec->set_mesh_id(mesh_id);
  spec->set_levels(levels);
  spec->set_factor(factor);
  spec->mutable_options()->mutable_fit()->set_degree(2);
  grpc::ClientContext ctx;
  v1::Job job;
  const grpc::Status s = stub.StartJob(&ctx, request, &job);
  if (!s.ok()) return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
  return job;
}

grpc::Status CancelJob(v1::GeomFit::Stub& stub, const std::string& job_id) {
  grpc::ClientContext ctx;
  v1::CancelJobRequest request;
  request.set_job_id(job_id);
  v1::Job job;
  return stub.CancelJob(&ctx, request, &job);
}

grpc::Status WatchJob(v1::GeomFit::Stub& stub, const std::string& job_id, int64_t from,
                      std::vector<v1::JobEvent>* out, const std::function<bool(const v1::JobEvent&)>& stop) {
  grpc::ClientContext ctx;
  v1::WatchJobRequest request;
  request.set_job_id(job_id);
  request.set_from_event(from);
  auto reader = stub.WatchJob(&ctx, request);
  v1::JobEvent e;
  while (reader->Read(&e)) {
    out->push_back(e);
    if (stop && stop(e)) {
      ctx.TryCancel();
      break;
    }
  }
  return reader->Finish();
}

double ProcessCpuSeconds() {
  timespec t;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

double CpuSecondsAfterCancel(const std::function<void()>& cancel, std::chrono::milliseconds delay) {
  const auto start = std::chrono::steady_clock::now() + delay;
  std::thread canceller(cancel);  // a CancelJob waits for the job's end: not in the window's start
  std::this_thread::sleep_until(start + std::chrono::milliseconds(100));
  const double cpu0 = ProcessCpuSeconds();
  std::this_thread::sleep_until(start + std::chrono::milliseconds(700));
  const double cpu = ProcessCpuSeconds() - cpu0;
  canceller.join();
  return cpu;
}

}  // namespace geomfit::server::testing
