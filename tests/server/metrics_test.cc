// Prometheus exposition on --metrics-port.
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>

#include <gtest/gtest.h>

#include "geomfit/version.h"
#include "server/metrics.h"

#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::FreePort;

/// GET http://127.0.0.1:port/metrics (the body, or "" on failure).
std::string Scrape(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(port));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  timeval tv{5, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  std::string out;
  if (connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0) {
    const std::string req = "GET /metrics HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n";
    if (write(fd, req.data(), req.size()) == static_cast<ssize_t>(req.size())) {
      char buf[4096];
      for (ssize_t n; (n = read(fd, buf, sizeof(buf))) > 0;) out.append(buf, static_cast<size_t>(n));
    }
  }
  close(fd);
  return out;
}

TEST(MetricsTest, ExposesRequestsCacheAndStore) {
  ServerOptions o = testing::LoopbackOptions();
  o.metrics_port = FreePort();
  testing::InProcessServer server(o);
  auto info = testing::UploadMesh(server.stub(), testing::TestTorus());
  ASSERT_TRUE(info.ok());
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(info->mesh_id());
  std::vector<v1::ComputeDifferentialsResponse> chunks;
  ASSERT_TRUE(testing::Compute(server.stub(), request, &chunks).ok());
  grpc::ClientContext ctx;
  v1::GetMeshRequest get;
  get.set_mesh_id("m-missing");
  v1::MeshInfo out;
  EXPECT_FALSE(server.stub().GetMesh(&ctx, get, &out).ok());

  const std::string body = Scrape(o.metrics_port);
  for (const char* want :
       {"geomfit_requests_total{method=\"UploadMesh\",code=\"OK\"} 1",
        "geomfit_requests_total{method=\"GetMesh\",code=\"NOT_FOUND\"} 1",
        "geomfit_request_duration_seconds_count{method=\"ComputeDifferentials\"} 1",
        "geomfit_request_duration_seconds_bucket{method=\"ComputeDifferentials\",le=\"+Inf\"} 1",
        "geomfit_cache_misses_total{tier=\"fitting\"} 2", "geomfit_cache_bytes{tier=\"geometry\"}",
        "geomfit_cache_evictions_total{tier=\"fitting\"} 0", "geomfit_store_meshes 1",
        // Buckets beyond 30 s, up to 10 min.
        "geomfit_request_duration_seconds_bucket{method=\"ComputeDifferentials\",le=\"60\"} 1",
        "geomfit_request_duration_seconds_bucket{method=\"ComputeDifferentials\",le=\"600\"} 1",
        "# TYPE process_cpu_seconds_total counter", "process_resident_memory_bytes ", "process_open_fds ",
        "process_max_fds ", "process_start_time_seconds ", "process_virtual_memory_bytes "}) {
    EXPECT_NE(body.find(want), std::string::npos) << "missing '" << want << "' in:\n" << body;
  }
}

TEST(MetricsTest, BuildInfoNamesVersionAndRevision) {
  ServerOptions o = testing::LoopbackOptions();
  o.metrics_port = FreePort();
  testing::InProcessServer server(o);
  const std::string body = Scrape(o.metrics_port);
  const std::string want = std::string("geomfit_build_info{version=\"") + kVersion + "\",revision=\"" + kRevision + "\"} 1";
  EXPECT_NE(body.find(want), std::string::npos) << "missing '" << want << "' in:\n" << body;
}

TEST(MetricsTest, ProcessStatsReadProcSelf) {
  const ProcessStats before = ReadProcessStats();
  EXPECT_GT(before.resident_bytes, 1 << 20);
  EXPECT_GE(before.virtual_bytes, before.resident_bytes);
  EXPECT_GE(before.open_fds, 3);  // stdin, stdout, stderr at least
  EXPECT_GE(before.max_fds, before.open_fds);
  const double now = std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  EXPECT_LE(before.start_time_seconds, now + 1);
  EXPECT_GT(before.start_time_seconds, now - 24 * 3600) << "this test process started today";
  // Three more descriptors are counted exactly; burning CPU shows in cpu_seconds.
  int fds[3];
  for (int& fd : fds) fd = open("/dev/null", O_RDONLY);
  volatile double x = 0;
  for (int i = 0; i < 30'000'000; ++i) x = x + 1e-9 * i;
  const ProcessStats after = ReadProcessStats();
  for (int fd : fds) close(fd);
  EXPECT_EQ(after.open_fds, before.open_fds + 3);
  EXPECT_GT(after.cpu_seconds, before.cpu_seconds);
  EXPECT_EQ(after.start_time_seconds, before.start_time_seconds);
}

}  // namespace
}  // namespace geomfit::server
