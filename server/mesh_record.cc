#include "server/mesh_record.h"

namespace geomfit::server {

v1::MeshInfo ToProto(const MeshRecord& r) {
  v1::MeshInfo p;
  p.set_mesh_id(r.mesh_id);
  p.set_revision(r.revision);
  p.set_num_vertices(r.num_vertices);
  p.set_num_faces(r.num_faces);
  p.set_face_kind(static_cast<v1::FaceKind>(r.face_kind));
  p.set_name(r.name);
  p.mutable_labels()->insert(r.labels.begin(), r.labels.end());
  if (r.has_bounds) {
    for (int i = 0; i < 3; ++i) {
      p.mutable_bounding_box()->add_min(r.min[i]);
      p.mutable_bounding_box()->add_max(r.max[i]);
    }
  }
  p.set_content_hash(r.content_hash);
  p.set_created_unix_ms(r.created_unix_ms);
  p.set_updated_unix_ms(r.updated_unix_ms);
  p.set_num_boundary_edges(r.num_boundary_edges);
  p.set_num_isolated_vertices(r.num_isolated_vertices);
  return p;
}

MeshRecord FromProto(const v1::MeshInfo& p) {
  MeshRecord r;
  r.mesh_id = p.mesh_id();
  r.revision = p.revision();
  r.num_vertices = p.num_vertices();
  r.num_faces = p.num_faces();
  r.face_kind = static_cast<FaceKind>(p.face_kind());
  r.name = p.name();
  r.labels.insert(p.labels().begin(), p.labels().end());
  r.has_bounds = p.bounding_box().min_size() == 3 && p.bounding_box().max_size() == 3;
  for (int i = 0; r.has_bounds && i < 3; ++i) {
    r.min[i] = p.bounding_box().min(i);
    r.max[i] = p.bounding_box().max(i);
  }
  r.content_hash = p.content_hash();
  r.created_unix_ms = p.created_unix_ms();
  r.updated_unix_ms = p.updated_unix_ms();
  r.num_boundary_edges = p.num_boundary_edges();
  r.num_isolated_vertices = p.num_isolated_vertices();
  return r;
}

}  // namespace geomfit::server
