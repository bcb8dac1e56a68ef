#pragma once
#include <cstddef>
#include <cstdint>
#include <map>
#include <string>

#include "core/mesh/mesh.h"

namespace geomfit {

/// A stable (across processes and machines) 128-bit content hash for mesh identity
/// and idempotent uploads. Not cryptographic.
class ContentHash {
 public:
  void Add(const void* data, size_t bytes);
  void AddString(const std::string& s) {
    const uint64_t n = s.size();
    Add(&n, sizeof(n));
    Add(s.data(), s.size());
  }
  /// 32 lowercase hex digits.
  std::string Hex() const;

 private:
  uint64_t a_ = 0x9e3779b97f4a7c15ULL, b_ = 0xc2b2ae3d27d4eb4fULL, length_ = 0;
};

/// The content hash of an upload, from which the server names the mesh: over the
/// counts, faces (#F x 4, -1 padded), positions, name and labels (in key order). Clients
/// compute it too, to know a mesh's id before uploading it (the routing key of
/// deploy/router); geomfit.mesh_id_of in Python mirrors it bit for bit.
std::string MeshContentHash(const Mesh& mesh, const std::string& name,
                            const std::map<std::string, std::string>& labels);
/// The mesh id of content with hash `content_hash`: "m-" + its first 20 hex digits.
std::string MeshIdOf(const std::string& content_hash);

}  // namespace geomfit
