// Prometheus exposition on --metrics-port.
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <gtest/gtest.h>

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
        "geomfit_cache_evictions_total{tier=\"fitting\"} 0", "geomfit_store_meshes 1"}) {
    EXPECT_NE(body.find(want), std::string::npos) << "missing '" << want << "' in:\n" << body;
  }
}

}  // namespace
}  // namespace geomfit::server
