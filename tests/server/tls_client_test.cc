// TLS and mTLS: the server with --tls-cert/--tls-key (and --tls-client-ca), the C++
// client with its credentials, certificates made for the test by tests/tls/make_certs.sh.
#include <unistd.h>

#include <cstdlib>
#include <filesystem>

#include <gtest/gtest.h>

#include "clients/cpp/client/client.h"
#include "server/options.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

using server::testing::InProcessServer;

/// A directory of certificates made once for this test binary.
const std::string& CertDir() {
  static const std::string* dir = [] {
    auto* d = new std::string((std::filesystem::temp_directory_path() /
                               ("geomfit_tls_" + std::to_string(::getpid()))).string());
    const std::string cmd = std::string(GEOMFIT_MAKE_CERTS) + " " + *d;
    EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
    return d;
  }();
  return *dir;
}
std::string Cert(const std::string& name) { return CertDir() + "/" + name; }

server::ServerOptions TlsOptions(bool mtls) {
  server::ServerOptions o = server::testing::LoopbackOptions();
  o.tls_cert = Cert("server.pem");
  o.tls_key = Cert("server.key");
  if (mtls) o.tls_client_ca = Cert("ca.pem");
  return o;
}

ClientOptions Options(int port) {
  ClientOptions o;
  o.target = "localhost:" + std::to_string(port);
  o.max_attempts = 1;
  o.deadline = std::chrono::seconds(20);
  return o;
}

/// Upload, download: the round trip of a mesh, or the first error.
absl::Status RoundTrip(Client& client) {
  const Mesh mesh = server::testing::TestTorus(6);
  auto info = client.Upload(mesh, "torus");
  if (!info.ok()) return info.status();
  auto back = client.Download(info->mesh_id);
  if (!back.ok()) return back.status();
  return server::testing::SameMesh(mesh, *back) ? absl::OkStatus() : absl::DataLossError("mesh differs");
}

TEST(TlsTest, ServesTlsToAClientTrustingItsCa) {
  InProcessServer server(TlsOptions(false));
  ClientOptions o = Options(server.port());
  o.tls_ca = Cert("ca.pem");
  EXPECT_TRUE(RoundTrip(*Client::Connect(o)).ok());
  o.target = "127.0.0.1:" + std::to_string(server.port());  // the IP SAN
  EXPECT_TRUE(RoundTrip(*Client::Connect(o)).ok());
}

TEST(TlsTest, RefusesPlaintextAndUntrustedClients) {
  InProcessServer server(TlsOptions(false));
  ClientOptions plain = Options(server.port());
  EXPECT_EQ(RoundTrip(*Client::Connect(plain)).code(), absl::StatusCode::kUnavailable);
  ClientOptions wrong_ca = Options(server.port());
  wrong_ca.tls_ca = Cert("other-ca.pem");
  EXPECT_EQ(RoundTrip(*Client::Connect(wrong_ca)).code(), absl::StatusCode::kUnavailable);
  // The in-process test channel is plaintext: the health probe fails too.
  EXPECT_NE(server::testing::HealthCheck(server.channel()), "SERVING");
}

TEST(TlsTest, MutualTlsRequiresAClientCertificateSignedByTheClientCa) {
  InProcessServer server(TlsOptions(true));
  ClientOptions o = Options(server.port());
  o.tls_ca = Cert("ca.pem");
  EXPECT_EQ(RoundTrip(*Client::Connect(o)).code(), absl::StatusCode::kUnavailable);  // no certificate
  o.tls_cert = Cert("client.pem");
  o.tls_key = Cert("client.key");
  EXPECT_TRUE(RoundTrip(*Client::Connect(o)).ok());
  // A certificate the client CA did not sign: the server's own is signed by the same
  // CA, so use the other CA's self-signed one.
  o.tls_cert = Cert("other-ca.pem");
  o.tls_key = Cert("other-ca.key");
  EXPECT_EQ(RoundTrip(*Client::Connect(o)).code(), absl::StatusCode::kUnavailable);
}

TEST(TlsTest, UnreadableCredentialsFailAtCreateAndInEveryCall) {
  ClientOptions o = Options(1);
  o.tls_ca = CertDir() + "/missing.pem";
  EXPECT_EQ(Client::Create(o).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(Client::Connect(o)->ListMeshes().status().code(), absl::StatusCode::kNotFound);
  o.tls_ca = "";
  o.tls_cert = Cert("client.pem");  // without its key
  EXPECT_EQ(Client::Create(o).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(TlsTest, ServerRefusesIncompleteOrMissingTlsFiles) {
  EXPECT_EQ(server::ParseServerOptions({"--tls-cert=a.pem"}).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(server::ParseServerOptions({"--tls-client-ca=ca.pem"}).status().code(),
            absl::StatusCode::kInvalidArgument);
  server::ServerOptions o = TlsOptions(false);
  o.tls_key = CertDir() + "/missing.key";
  auto s = server::Server::Start(o);
  ASSERT_FALSE(s.ok());
  EXPECT_NE(s.status().message().find("--tls-key"), std::string::npos) << s.status();
  o = TlsOptions(false);
  o.tls_key = Cert("ca.srl");  // not PEM
  EXPECT_EQ(server::Server::Start(o).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace geomfit
