#pragma once
#include <vector>

#include "absl/status/statusor.h"
#include "core/reconstruction/surface.h"

namespace geomfit {

/// The order-k lattice of every face (4.2): triangle nodes at natural coordinates
/// (i/k, j/k) with i + j <= k, quad nodes at (i/k, j/k) in [0, 1]^2. Mesh vertices keep
/// their ids; edge nodes are shared by the faces of an edge and numbered once (4.2.1
/// steps 1-2); interior nodes belong to one face. New node n has id #V + n.
struct FaceLattices {
  int order = 1;
  std::vector<FacePoint> new_nodes;     ///< where each new node lies (first face seen)
  std::vector<int32_t> offsets, nodes;  ///< per face, node ids by lattice index
  /// Lattice index of (i, j): triangles row by row over j, quads (k+1) i-major rows.
  static int Index(bool triangle, int k, int i, int j) {
    return triangle ? j * (k + 1) - j * (j - 1) / 2 + i : j * (k + 1) + i;
  }
};
FaceLattices BuildFaceLattices(const Mesh& mesh, const Topology& topo, int order);

/// Quadratic or cubic elements (4.2.1): #V + new nodes on the reconstructed surface, and
/// each face's nodes in VTK / gmsh Lagrange order: corners, then every edge's nodes
/// from its first to its second corner, then interior nodes.
struct HighOrderMesh {
  int order = 2;
  Positions nodes;
  std::vector<int32_t> offsets, elements;  ///< element f: elements[offsets[f] .. offsets[f+1])
};
absl::StatusOr<HighOrderMesh> MakeHighOrderMesh(const ReconstructedSurface& surface, const Topology& topo,
                                                int order, const RunContext& ctx = {});

/// Uniform refinement (4.2.2): every face split into factor^2 faces (factor 2: triangle
/// and quad 1 -> 4; 3: 1 -> 9), new vertices on the reconstructed surface.
absl::StatusOr<Mesh> RefineMesh(const ReconstructedSurface& surface, const Topology& topo, int factor,
                                const RunContext& ctx = {});

}  // namespace geomfit
