// Safe defaults: loopback listen address, bounded names and labels, ListMeshes pages
// bounded by bytes as well as by count.
#include <gtest/gtest.h>

#include "clients/cpp/client/client.h"
#include "server/options.h"
#include "server/workspace/workspace.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

using server::testing::InProcessServer;

std::unique_ptr<Client> ClientFor(int port) {
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(port);
  o.max_attempts = 1;
  return Client::Connect(o);
}

TEST(SafeDefaultsTest, ListensOnLoopbackByDefault) {
  auto o = server::ParseServerOptions({});
  ASSERT_TRUE(o.ok());
  EXPECT_EQ(o->host, "127.0.0.1");
  EXPECT_EQ(o->metrics_host, "");  // = --host
  EXPECT_TRUE(server::ServerOptions::IsLoopback("127.0.0.1"));
  EXPECT_TRUE(server::ServerOptions::IsLoopback("localhost"));
  EXPECT_TRUE(server::ServerOptions::IsLoopback("[::1]"));
  EXPECT_FALSE(server::ServerOptions::IsLoopback("0.0.0.0"));
  EXPECT_FALSE(server::ServerOptions::IsLoopback("10.1.2.3"));
}

TEST(SafeDefaultsTest, NamesAndLabelsAreBoundedWithoutEchoingThem) {
  InProcessServer server;
  auto c = ClientFor(server.port());
  const Mesh mesh = server::testing::TestTorus(5);
  const std::string long_name(server::kMaxNameBytes + 1, 'n');
  auto s = c->Upload(mesh, long_name).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(s.message().find("nnnnnnnn"), std::string::npos) << s.message().substr(0, 200);
  EXPECT_TRUE(c->Upload(mesh, std::string(server::kMaxNameBytes, 'n')).ok());
  std::map<std::string, std::string> labels;
  for (size_t i = 0; i <= server::kMaxLabels; ++i) labels["k" + std::to_string(i)] = "v";
  EXPECT_EQ(c->Upload(mesh, "x", labels).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(c->Upload(mesh, "x", {{std::string(server::kMaxLabelKeyBytes + 1, 'k'), "v"}}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(c->Upload(mesh, "x", {{"k", std::string(server::kMaxLabelValueBytes + 1, 'v')}}).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(c->ListMeshes()->size(), 1u);  // nothing else was stored
}

TEST(SafeDefaultsTest, ErrorsEchoABoundedPrefixOfClientIds) {
  InProcessServer server;
  auto c = ClientFor(server.port());
  const std::string id(4000, 'i');  // within gRPC's metadata limit (the client sends it as x-mesh-id)
  for (const absl::Status& s : {c->GetMesh(id).status(), c->GetJob(id).status()}) {
    EXPECT_EQ(s.code(), absl::StatusCode::kNotFound);
    EXPECT_LT(s.message().size(), 120u) << s.message().substr(0, 200);
  }
}

TEST(SafeDefaultsTest, ListMeshesPagesByBytes) {
  server::ServerOptions o = server::testing::LoopbackOptions();
  o.max_message_bytes = 1 << 16;  // pages of at most 32 KiB
  InProcessServer server(o);
  auto c = ClientFor(server.port());
  std::map<std::string, std::string> labels;  // ~10 KiB of labels per mesh
  for (size_t i = 0; i < server::kMaxLabels; ++i) labels["key" + std::to_string(i)] = std::string(300 - 44, 'v');
  constexpr int kMeshes = 9;
  for (int i = 0; i < kMeshes; ++i) ASSERT_TRUE(c->Upload(server::testing::TestTorus(5), "m" + std::to_string(i), labels).ok());
  v1::ListMeshesRequest request;
  request.set_page_size(1000);
  int pages = 0, listed = 0;
  while (true) {
    grpc::ClientContext ctx;
    v1::ListMeshesResponse response;
    ASSERT_TRUE(server.stub().ListMeshes(&ctx, request, &response).ok());
    ++pages;
    listed += response.meshes_size();
    EXPECT_LE(response.ByteSizeLong(), size_t{1} << 15);
    EXPECT_GT(response.meshes_size(), 0);
    if (response.next_page_token().empty()) break;
    request.set_page_token(response.next_page_token());
  }
  EXPECT_EQ(listed, kMeshes);
  EXPECT_GE(pages, 3);
  EXPECT_EQ(c->ListMeshes()->size(), static_cast<size_t>(kMeshes));  // the client follows the pages
}

}  // namespace
}  // namespace geomfit
