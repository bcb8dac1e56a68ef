#pragma once
// Tenant namespaces of mesh ids. With --auth-tokens, tenant T's mesh X is stored as
// "T/X": the service scopes every `mesh_id` of a request on the way in and strips the
// prefix from every `mesh_id` of a response on the way out, so the engine and the
// store keep one flat id space and a tenant can neither name nor list another's
// meshes. Without a token file the tenant is "" and ids are unchanged.
#include <string>

#include <google/protobuf/message.h>

#include "absl/strings/string_view.h"
#include "server/workspace/workspace.h"

namespace geomfit::server {

/// Who made a call: produced once per call by Service::Admit, passed to the work.
struct CallContext {
  std::string tenant;  ///< "" in single-tenant mode
};

/// Prefixes every string field named mesh_id, at any depth.
void ScopeIds(absl::string_view tenant, google::protobuf::Message* message);
/// Strips the tenant prefix from every mesh_id, at any depth.
void UnscopeIds(absl::string_view tenant, google::protobuf::Message* message);
/// True if the stored id belongs to `tenant`.
bool Owns(absl::string_view tenant, absl::string_view scoped_id);

}  // namespace geomfit::server
