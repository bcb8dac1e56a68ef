#pragma once
// Transport security of the server: gRPC credentials from the --tls-* PEM files.
// The metrics port stays plaintext: Debian 12's civetweb (under prometheus-cpp)
// looks up SSL_get_peer_certificate, which OpenSSL 3 no longer exports, and its
// worker crashes on a null function pointer after the first TLS handshake.
#include <memory>
#include <string>

#include <grpcpp/security/server_credentials.h>

#include "absl/status/statusor.h"
#include "server/options.h"

namespace geomfit::server {

/// Reads a whole file; errors name the flag and the path.
absl::StatusOr<std::string> ReadPemFile(const std::string& flag, const std::string& path);

/// Insecure credentials without --tls-cert; TLS with it; with --tls-client-ca the
/// server requires and verifies a client certificate (mTLS).
absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> ServerCredentialsFor(const ServerOptions& options);

}  // namespace geomfit::server
