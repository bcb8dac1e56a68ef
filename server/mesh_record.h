#pragma once
// MeshRecord <-> v1::MeshInfo: the wire form, and the SQLite store's durable form (kept
// as the serialized message so data directories of earlier versions stay readable).
#include "geomfit/v1/geomfit.pb.h"
#include "server/mesh_store.h"

namespace geomfit::server {

v1::MeshInfo ToProto(const MeshRecord& record);
MeshRecord FromProto(const v1::MeshInfo& info);

}  // namespace geomfit::server
