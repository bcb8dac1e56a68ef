#include "server/auth.h"

#include <fstream>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "core/util/status_macros.h"

namespace geomfit::server {
namespace {

/// Equality in time depending only on the lengths of a and b.
bool ConstantTimeEqual(absl::string_view a, absl::string_view b) {
  const size_t n = std::max(a.size(), b.size());
  unsigned diff = a.size() == b.size() ? 0u : 1u;
  for (size_t i = 0; i < n; ++i) {
    const unsigned char x = i < a.size() ? static_cast<unsigned char>(a[i]) : 0;
    const unsigned char y = i < b.size() ? static_cast<unsigned char>(b[i]) : 0;
    diff |= static_cast<unsigned>(x ^ y);
  }
  return diff == 0;
}

}  // namespace

bool ValidTenant(absl::string_view tenant) {
  if (tenant.empty() || tenant.size() > 64) return false;
  for (char c : tenant) {
    if (!absl::ascii_isalnum(static_cast<unsigned char>(c)) && c != '.' && c != '_' && c != '-') return false;
  }
  return true;
}

absl::StatusOr<TokenTable::Entries> TokenTable::Parse(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("--auth-tokens: cannot read ", path));
  Entries entries;
  std::string line;
  for (int n = 1; std::getline(in, line); ++n) {
    const absl::string_view text = absl::StripAsciiWhitespace(line);
    if (text.empty() || text[0] == '#') continue;
    std::vector<absl::string_view> parts = absl::StrSplit(text, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (parts.size() != 2) return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": expected TOKEN TENANT"));
    if (parts[0].size() < 16)
      return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": token shorter than 16 characters"));
    if (!ValidTenant(parts[1]))
      return absl::InvalidArgumentError(absl::StrCat(path, ":", n, ": tenant must be 1..64 of [A-Za-z0-9._-]"));
    entries.emplace_back(std::string(parts[0]), std::string(parts[1]));
  }
  if (entries.empty()) return absl::InvalidArgumentError(absl::StrCat("--auth-tokens: ", path, " names no token"));
  return entries;
}

absl::StatusOr<std::unique_ptr<TokenTable>> TokenTable::Load(const std::string& path) {
  auto table = std::unique_ptr<TokenTable>(new TokenTable());
  table->path_ = path;
  GF_RETURN_IF_ERROR(table->Reload());
  return table;
}

absl::Status TokenTable::Reload() {
  GF_ASSIGN_OR_RETURN(Entries entries, Parse(path_));
  auto shared = std::make_shared<const Entries>(std::move(entries));
  std::lock_guard<std::mutex> lock(mu_);
  entries_ = std::move(shared);
  return absl::OkStatus();
}

size_t TokenTable::size() const {
  std::lock_guard<std::mutex> lock(mu_);
  return entries_->size();
}

std::optional<std::string> TokenTable::TenantOf(absl::string_view token) const {
  std::shared_ptr<const Entries> entries;
  {
    std::lock_guard<std::mutex> lock(mu_);
    entries = entries_;
  }
  std::optional<std::string> tenant;
  for (const auto& [t, name] : *entries) {  // no early exit
    if (ConstantTimeEqual(token, t) && !tenant.has_value()) tenant = name;
  }
  return tenant;
}

absl::StatusOr<std::string> Authenticate(const TokenTable& tokens, absl::string_view authorization) {
  constexpr absl::string_view kBearer = "Bearer ";
  if (!absl::StartsWith(authorization, kBearer)) {
    return absl::UnauthenticatedError("missing 'authorization: Bearer TOKEN' metadata");
  }
  std::optional<std::string> tenant = tokens.TenantOf(authorization.substr(kBearer.size()));
  if (!tenant.has_value()) return absl::UnauthenticatedError("invalid token");
  return *tenant;
}

}  // namespace geomfit::server
