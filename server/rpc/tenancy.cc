#include "server/rpc/tenancy.h"

#include <functional>

#include <google/protobuf/descriptor.h>
#include <google/protobuf/reflection.h>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"

namespace geomfit::server {
namespace {

using google::protobuf::FieldDescriptor;
using google::protobuf::Message;

/// Applies `fn` to every string field named mesh_id of `m` and its submessages.
void ForEachMeshId(Message* m, const std::function<void(std::string*)>& fn) {
  const google::protobuf::Descriptor* d = m->GetDescriptor();
  const google::protobuf::Reflection* r = m->GetReflection();
  for (int i = 0; i < d->field_count(); ++i) {
    const FieldDescriptor* f = d->field(i);
    if (f->type() == FieldDescriptor::TYPE_STRING && f->name() == "mesh_id" && !f->is_repeated()) {
      std::string v = r->GetString(*m, f);
      fn(&v);
      r->SetString(m, f, std::move(v));
    } else if (f->type() == FieldDescriptor::TYPE_MESSAGE) {
      if (f->is_map()) continue;
      if (f->is_repeated()) {
        for (int k = 0; k < r->FieldSize(*m, f); ++k) ForEachMeshId(r->MutableRepeatedMessage(m, f, k), fn);
      } else if (r->HasField(*m, f)) {
        ForEachMeshId(r->MutableMessage(m, f), fn);
      }
    }
  }
}

}  // namespace

void ScopeIds(absl::string_view tenant, Message* message) {
  if (tenant.empty()) return;
  const std::string prefix = TenantPrefix(tenant);
  ForEachMeshId(message, [&](std::string* id) {
    if (!id->empty()) *id = prefix + *id;
  });
}

void UnscopeIds(absl::string_view tenant, Message* message) {
  if (tenant.empty()) return;
  const std::string prefix = TenantPrefix(tenant);
  ForEachMeshId(message, [&](std::string* id) {
    if (absl::StartsWith(*id, prefix)) id->erase(0, prefix.size());
  });
}

bool Owns(absl::string_view tenant, absl::string_view scoped_id) {
  return tenant.empty() ? scoped_id.find('/') == absl::string_view::npos
                        : absl::StartsWith(scoped_id, TenantPrefix(tenant));
}

}  // namespace geomfit::server
