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
  /// vertex -> vertices sharing an edge, sorted: vv[vv_offsets[v] .. vv_offsets[v+1])
  /// (BuildTopology of a LocalityRelabelling: in its RowOrder instead).
  std::vector<int32_t> vv_offsets, vv;
  std::vector<uint8_t> is_boundary;  ///< 1 for vertices on a boundary edge
  std::vector<uint8_t> is_isolated;  ///< 1 for vertices in no face (allowed, flagged)
  /// Every vertex once, in breadth-first order over the edges: a work order with
  /// neighbours close together (cache locality on meshes numbered in any order). Loops
  /// may visit vertices in this order; outputs stay indexed by vertex. Empty for a
  /// LocalityRelabelling's topology (its numbering is such an order).
  std::vector<int32_t> locality_order;
  /// Vertex -> the source mesh's vertex, when the caller sets it (LocalityRelabelling::
  /// vertex_source; the CLI's `--noise auto`): EstimateNoise then samples by source index,
  /// the same vertices as on the source mesh. Empty otherwise.
  std::vector<int32_t> vertex_source;
  int num_boundary_edges = 0;
  int num_isolated = 0;
  /// True when every vf row lists its faces in increasing face index (BuildTopology of a
  /// mesh); false for BuildTopology of a LocalityRelabelling, whose rows follow the
  /// source's face order or the fan's (RowOrder). Face-by-face passes that accumulate per vertex match per-fan
  /// passes only in the first case.
  bool vertex_faces_ascending = true;
  /// True when each vertex's vf and vv rows are in fan order (BuildTopology of a
  /// RowOrder::kRotational relabelling): face j's corner at v has the spokes vv[j] (the
  /// corner after v) and vv[j + 1] (before v), with vv[k] read as vv[0] in a closed fan.
  bool fan_rows = false;

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
/// `num_threads` as ResolveThreads (0: all); large meshes only are split.
absl::Status ValidateGeometry(const Mesh& mesh, int num_threads = 0);

/// BuildTopology + ValidateGeometry.
absl::StatusOr<Topology> ValidateMesh(const Mesh& mesh, int num_threads = 0);

/// The order of a LocalityRelabelling's face rows and of its topology's rows.
enum class RowOrder {
  /// The source's order: face rows keep their source rotation; each vertex's neighbours
  /// by source vertex index, its incident faces by source face index. Per-vertex work
  /// (stencils, vertex normals) then performs the source's operations in the source's
  /// order: results equal the source's bit for bit.
  kSource,
  /// One geometric pattern at every vertex and face, as a generated mesh's numbering
  /// gives: each face row rotated to start at its corner furthest along kRowDirection;
  /// each vertex's faces in fan order (as they follow each other around it, by the
  /// faces' orientation), its neighbours as the fan's spokes, a closed fan starting at
  /// the spoke nearest kRowDirection, an open one at its boundary edge. Ring growth's
  /// branches then predict as well as on a generated mesh, whatever the source's
  /// numbering (bench/README.md, "Issue 15, sixth round"). Stencils hold the source's
  /// point sets in another order: results equal the source's to round-off, not bit for
  /// bit. Linear in the mesh size.
  kRotational,
};

/// The direction of RowOrder::kRotational: fixed, generic (parallel to no axis, so an
/// axis-aligned plane or a surface of revolution about an axis has it along its normal
/// at isolated points at most).
inline constexpr double kRowDirection[3] = {0.8, 0.5, 0.33};

/// A mesh relabelled for memory locality: vertices in spatial (Morton) order, faces
/// ordered by their lowest new vertex (ties in source order), each face row a rotation
/// of its source row (per `order`). Work over it reads nearby memory wherever the
/// source's numbering put its vertices and faces (a mesher's output is often scattered).
struct LocalityRelabelling {
  Mesh mesh;                           ///< the relabelled mesh
  std::vector<int32_t> vertex_source;  ///< relabelled vertex -> source vertex
  std::vector<int32_t> face_source;    ///< relabelled face -> source face
  RowOrder order = RowOrder::kRotational;  ///< of the face rows here, of BuildTopology's rows
};

/// Mean index distance along edges up to which a numbering counts as local: the data of
/// neighbouring vertices then lie within a few hundred kB of each other.
inline constexpr int64_t kLocalIndexGap = 4096;

/// Whether `gap_sum`, a sum of |a - b| over `edges` edges (a, b), has a mean of at most
/// kLocalIndexGap: the one test behind both HasLocalNumbering.
inline bool IsLocalIndexGap(int64_t gap_sum, int64_t edges) { return gap_sum <= kLocalIndexGap * edges; }

/// Whether the mean |a - b| over the edges (a, b) of the face rows is at most
/// kLocalIndexGap (generators number locally; some meshers scatter their numbering).
bool HasLocalNumbering(const Mesh& mesh);

/// The same over the topology's edges (each row entry once).
bool HasLocalNumbering(const Topology& topo);

/// Relabels `mesh`, its face rows in `order`. INVALID_ARGUMENT for an empty mesh or a
/// vertex index out of range (no message worth showing: validate the source for that).
absl::StatusOr<LocalityRelabelling> RelabelForLocality(const Mesh& mesh, RowOrder order = RowOrder::kRotational);

/// Topology of a relabelled mesh with its rows in `relabelled.order` (the relabelled
/// mesh's own BuildTopology sorts them by relabelled index instead), built vertex by
/// vertex from each fan, with no half-edge sort. Fails exactly when
/// BuildTopology(source) fails, with a message naming relabelled indices (and for
/// edges and fans the kind of error only): report BuildTopology(source)'s instead.
/// Its locality_order is empty: the relabelled numbering is one already (loops over it
/// run in vertex order).
absl::StatusOr<Topology> BuildTopology(const LocalityRelabelling& relabelled);

}  // namespace geomfit
