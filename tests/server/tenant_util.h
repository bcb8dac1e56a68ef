#pragma once
// Helpers of the tenant tests (--auth-tokens): two tenants' tokens, a token file, and
// C++ clients that send a token.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "clients/cpp/client/client.h"
#include "tests/server/test_util.h"

namespace geomfit::server::testing {

inline constexpr char kTokenA[] = "token-of-tenant-a-0123456789";  ///< tenant "alpha"
inline constexpr char kTokenB[] = "token-of-tenant-b-0123456789";  ///< tenant "beta"

/// Writes `text` to a file named after `name` and the process in the temp directory.
inline std::string WriteTempFile(const std::string& name, const std::string& text) {
  const std::string path =
      (std::filesystem::temp_directory_path() / (name + "_" + std::to_string(::getpid()))).string();
  std::ofstream(path) << text;
  return path;
}

/// kTokenA -> alpha, kTokenB -> beta.
inline std::string TokenFile() {
  return WriteTempFile("geomfit_tokens", std::string("# token tenant\n") + kTokenA + " alpha\n" + kTokenB + "  beta\n");
}

/// A loopback server with TokenFile's tenants.
inline ServerOptions TenantOptions() {
  ServerOptions o = LoopbackOptions();
  o.auth_tokens = TokenFile();
  return o;
}

/// chunk_rows 50: uploads and updates of the test meshes stream in several messages;
/// 0: an update is one SetPositions message.
inline std::unique_ptr<Client> ClientWith(int port, const std::string& token, int64_t chunk_rows = 50) {
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(port);
  o.max_attempts = 1;
  o.token = token;
  if (chunk_rows > 0) o.chunk_rows = chunk_rows;
  return Client::Connect(o);
}

}  // namespace geomfit::server::testing
