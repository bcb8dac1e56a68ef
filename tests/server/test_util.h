#pragma once
// Shared helpers of the server tests: meshes, an in-process server on a loopback
// port, raw stream helpers and a health probe that uses no generated code.
#include <chrono>
#include <condition_variable>
#include <functional>
#include <future>
#include <mutex>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <grpcpp/grpcpp.h>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"
#include "geomfit/v1/geomfit.grpc.pb.h"
#include "server/options.h"
#include "server/server.h"

namespace geomfit::server::testing {

Mesh TestTorus(int n = 8);
Mesh TestSphere(int n = 6);

/// Options for a throwaway loopback server (memory store, free port).
ServerOptions LoopbackOptions();
/// A loopback TCP port that was free a moment ago.
int FreePort();

/// A server in this process and a channel to it. Stops the server on destruction.
class InProcessServer {
 public:
  explicit InProcessServer(ServerOptions options = LoopbackOptions());
  ~InProcessServer();
  v1::GeomFit::Stub& stub() { return *stub_; }
  std::shared_ptr<grpc::Channel> channel() { return channel_; }
  Server& server() { return *server_; }
  int port() const { return server_->port(); }

 private:
  std::unique_ptr<Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::GeomFit::Stub> stub_;
};

std::shared_ptr<grpc::Channel> LoopbackChannel(int port, int64_t max_message_bytes = 64 << 20);

/// Sends `requests` as one UploadMesh stream; `finish_writes` false leaves the stream
/// half-open until the context is cancelled.
grpc::Status SendUpload(v1::GeomFit::Stub& stub, const std::vector<v1::UploadMeshRequest>& requests,
                        v1::MeshInfo* info);
grpc::Status SendUpdate(v1::GeomFit::Stub& stub, const std::vector<v1::UpdatePositionsRequest>& requests,
                        v1::MeshInfo* info);
absl::StatusOr<v1::MeshInfo> UploadMesh(v1::GeomFit::Stub& stub, const Mesh& mesh, const std::string& name = "",
                                        int64_t chunk_rows = 1000);
/// Reads a whole ComputeDifferentials stream.
grpc::Status Compute(v1::GeomFit::Stub& stub, const v1::ComputeDifferentialsRequest& request,
                     std::vector<v1::ComputeDifferentialsResponse>* chunks, int deadline_ms = 60000);
/// Downloads a mesh and reassembles it.
absl::StatusOr<Mesh> Download(v1::GeomFit::Stub& stub, const std::string& mesh_id);

/// StartJob with a refine spec (degree-2 fits); the error as an absl::Status.
absl::StatusOr<v1::Job> StartRefineJob(v1::GeomFit::Stub& stub, const std::string& mesh_id, int levels,
                                       int factor = 2);
/// CancelJob(job_id).
grpc::Status CancelJob(v1::GeomFit::Stub& stub, const std::string& job_id);
/// Reads WatchJob(job_id, from) into *out until the stream ends, or until `stop` returns
/// true for an event (then the call is cancelled, like a client that goes away).
grpc::Status WatchJob(v1::GeomFit::Stub& stub, const std::string& job_id, int64_t from,
                      std::vector<v1::JobEvent>* out,
                      const std::function<bool(const v1::JobEvent&)>& stop = nullptr);

/// CPU seconds of this process (an in-process server's threads; its clients only wait).
double ProcessCpuSeconds();
/// Starts `cancel` (a client cancelling a call or a job, or a server draining for
/// `delay` before it cancels what is left) on a thread of its own and returns the CPU
/// seconds this process spends from delay + 100 ms to delay + 700 ms after it began.
/// A server still computing then burns ~0.6 s per thread, one that stopped within
/// 100 ms a few ms: CPU time, not wall time, so a loaded machine cannot fake a stop's
/// delay (it can only hide part of a failure to stop).
double CpuSecondsAfterCancel(const std::function<void()>& cancel,
                             std::chrono::milliseconds delay = std::chrono::milliseconds(0));
/// What a test allows CpuSecondsAfterCancel once the server stopped: the margin absorbs
/// a loaded machine that delays a thread's last block.
inline constexpr double kStoppedCpuSeconds = 0.15;

/// grpc.health.v1 Check for `service` ("" = server), sent as raw bytes so it relies
/// on nothing but the wire format: "SERVING", "NOT_SERVING", or the error.
std::string HealthCheck(const std::shared_ptr<grpc::Channel>& channel, const std::string& service = "");

/// A pool task that holds its worker until the gate opens, and says when it started.
class Gate {
 public:
  std::function<void()> Task() {
    return [this] {
      std::unique_lock<std::mutex> lock(mu_);
      ++started_;
      changed_.notify_all();
      changed_.wait(lock, [this] { return open_; });
    };
  }
  /// Waits until `tasks` of its tasks hold their workers.
  void AwaitStart(int tasks = 1) {
    std::unique_lock<std::mutex> lock(mu_);
    changed_.wait(lock, [&] { return started_ >= tasks; });
  }
  void Open() {
    std::lock_guard<std::mutex> lock(mu_);
    open_ = true;
    changed_.notify_all();
  }

 private:
  std::mutex mu_;
  std::condition_variable changed_;
  int started_ = 0;
  bool open_ = false;
};

/// Reads the server stream `open(ctx)` (a 60 s deadline) on `*thread`, keeping its last
/// message in *last (if not null) and its status in *status. The returned future is ready once a
/// progress message of `phase` arrived, so the call is surely in that phase (an event,
/// not a sleep that a loaded machine outlasts), or once the stream ended without one.
template <typename Response, typename Open>
std::future<void> StreamInBackground(Open open, const std::string& phase, Response* last, grpc::Status* status,
                                     std::thread* thread) {
  auto started = std::make_shared<std::promise<void>>();
  std::future<void> future = started->get_future();
  *thread = std::thread([open, phase, last, status, started] {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    auto reader = open(&ctx);
    Response r;
    bool told = false;
    while (reader->Read(&r)) {
      if (!told && r.has_progress() && r.progress().phase() == phase) {
        started->set_value();
        told = true;
      }
      if (last != nullptr) *last = r;
    }
    *status = reader->Finish();
    if (!told) started->set_value();
  });
  return future;
}

/// RESOURCE_EXHAUSTED "tenant quota QUOTA reached" (QUOTA: "--quota-meshes=3").
inline bool IsQuotaError(const absl::Status& s, const std::string& quota) {
  return s.code() == absl::StatusCode::kResourceExhausted &&
         s.message().find("tenant quota " + quota + " reached") != absl::string_view::npos;
}

/// Bitwise equality of two meshes.
bool SameMesh(const Mesh& a, const Mesh& b);

}  // namespace geomfit::server::testing
