#pragma once
#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"

namespace geomfit {

/// Connectivity of a validated mesh; depends on faces only, so moving vertices never
/// invalidates it. Adjacency is stored compactly (CSR).
struct Topology {
  int num_vertices = 0;
  int num_faces = 0;
  bool has_quads = false;
  /// vertex -> incident faces: vf_faces[vf_offsets[v] .. vf_offsets[v+1]).
  std::vector<int32_t> vf_offsets, vf_faces;
  /// vertex -> vertices sharing an edge, sorted: vv[vv_offsets[v] .. vv_offsets[v+1]).
  std::vector<int32_t> vv_offsets, vv;
  std::vector<uint8_t> is_boundary;  ///< 1 for vertices on a boundary edge
  std::vector<uint8_t> is_isolated;  ///< 1 for vertices in no face (allowed, flagged)
  /// Every vertex once, in breadth-first order over the edges: a work order with
  /// neighbours close together (cache locality on meshes numbered in any order). Loops
  /// may visit vertices in this order; outputs stay indexed by vertex.
  std::vector<int32_t> locality_order;
  int num_boundary_edges = 0;
  int num_isolated = 0;

  int NumVertexFaces(int v) const { return vf_offsets[v + 1] - vf_offsets[v]; }
  const int32_t* VertexFaces(int v) const { return vf_faces.data() + vf_offsets[v]; }
  int NumNeighbors(int v) const { return vv_offsets[v + 1] - vv_offsets[v]; }
  const int32_t* Neighbors(int v) const { return vv.data() + vv_offsets[v]; }
  size_t Bytes() const;
};

/// Validates the connectivity and builds the topology. Errors (INVALID_ARGUMENT) name
/// the offending face, edge or vertex: empty mesh, index out of range or negative,
/// repeated vertex in a face, an edge shared by more than two faces, inconsistent
/// orientation across an edge, a non-manifold vertex (faces around it form more than
/// one fan).
absl::StatusOr<Topology> BuildTopology(const Mesh& mesh);

/// Validates positions against faces: finite coordinates, no zero-area face.
/// Separate from BuildTopology because positions change every time step.
absl::Status ValidateGeometry(const Mesh& mesh);

/// BuildTopology + ValidateGeometry.
absl::StatusOr<Topology> ValidateMesh(const Mesh& mesh);

}  // namespace geomfit
