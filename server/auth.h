#pragma once
// Bearer-token authentication: the --auth-tokens file maps tokens to tenants.
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"

namespace geomfit::server {

/// Tenant names: 1..64 of [A-Za-z0-9._-] (they prefix stored ids, see tenancy.h).
bool ValidTenant(absl::string_view tenant);

/// The tokens of an --auth-tokens file: one `TOKEN TENANT` per line, `#` comments and
/// blank lines ignored. Thread-safe; Reload swaps the table atomically (SIGHUP).
class TokenTable {
 public:
  /// Reads `path`; errors name the line.
  static absl::StatusOr<std::unique_ptr<TokenTable>> Load(const std::string& path);
  /// Re-reads the file; on error the old table stays in force.
  absl::Status Reload();
  /// The tenant of `token`, compared in constant time against every entry (the time
  /// depends on the table, not on where or whether the token matches).
  std::optional<std::string> TenantOf(absl::string_view token) const;
  size_t size() const;

 private:
  using Entries = std::vector<std::pair<std::string, std::string>>;
  static absl::StatusOr<Entries> Parse(const std::string& path);
  std::string path_;
  mutable std::mutex mu_;
  std::shared_ptr<const Entries> entries_;
};

/// The tenant of an `authorization` metadata value ("Bearer TOKEN"), or UNAUTHENTICATED.
absl::StatusOr<std::string> Authenticate(const TokenTable& tokens, absl::string_view authorization);

}  // namespace geomfit::server
