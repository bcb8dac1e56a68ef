#pragma once
#include <cstdint>
#include <functional>
#include <vector>

#include "core/fitting/fit_inputs.h"
#include "core/fitting/options.h"
#include "core/mesh/topology.h"

namespace geomfit {

/// The stencils again in a work order (a permutation of the vertices), renumbered by it:
/// the k-th vertex visited is order[k], its points are
/// points[offsets[k] .. offsets[k+1]) given by their positions in the order (rank[p] for
/// vertex p), so a loop in this order reads its stencils sequentially and the points'
/// data from an array copied in this order, without an index lookup per point.
struct OrderedStencils {
  std::vector<int32_t> order, rank, offsets, points;

  bool empty() const { return order.empty(); }
  size_t Bytes() const { return 4 * (order.size() + rank.size() + offsets.size() + points.size()); }
};

/// Per-vertex stencils in CSR form: points of vertex v are
/// indices[offsets[v] .. offsets[v+1]), the vertex itself first, then ring by ring.
struct Neighborhoods {
  std::vector<int32_t> offsets;
  std::vector<int32_t> indices;
  std::vector<float> rings;  ///< ring size reached per vertex (1, 1.5, ...)
  /// The same stencils in Topology::locality_order (empty when the topology has none):
  /// the order FitSurface fits in.
  OrderedStencils ordered;
  /// Normals and point records of the geometries fitted over these stencils (FitSurface
  /// fills it on first use; records in `ordered`'s order).
  FitInputCache fit_inputs;

  int Size(int v) const { return offsets[v + 1] - offsets[v]; }
  const int32_t* Points(int v) const { return indices.data() + offsets[v]; }
  /// The stencils alone (without fit_inputs).
  size_t StencilBytes() const { return 4 * (offsets.size() + indices.size() + rings.size()) + ordered.Bytes(); }
  size_t Bytes() const { return StencilBytes() + fit_inputs.Bytes(); }
};

/// `nb`'s stencils in `order` (a permutation of its vertices), OrderedStencils' layout.
OrderedStencils OrderStencils(const Neighborhoods& nb, std::vector<int32_t> order, int num_threads = 0);

/// Ring growth rule (2.1). For triangles: the (k+1)-ring adds the 1-ring of every
/// k-ring vertex; the half ring k+0.5 adds the vertices of faces sharing an edge
/// with the k-ring faces. For quads (Fig 2.2): the k-ring adds edge neighbours; the
/// half ring adds the vertices of faces incident on an edge between two k-ring
/// vertices. Both definitions are the same rule on edges, which we use for mixed
/// meshes too.
struct RingSpec {
  double rings = 1.5;          ///< starting ring (half steps)
  bool adaptive = true;
  int min_points = 9;          ///< interior vertices grow until this many points
  int min_points_boundary = 12;  ///< boundary vertices grow until this many points
  double max_rings = 8;
  int max_points = 120;
  /// Near-duplicate points (the higher-numbered end of a triangle's shortest edge when it is
  /// below 0.1 x the triangle's longest: marching-cubes meshes) do not count towards
  /// min_points, so stencils holding them grow further. Opt-in (RingSpecFor leaves it off):
  /// on marching-cubes meshes it raises the degree-2 max-norm orders but costs 5-10% of the
  /// L2 errors and some degree-5 cells (bench/README.md, `mclinf`).
  bool count_near_duplicates = false;
};

/// RingSpec for a fit: start at options.StartRings(), grow to factor x #coefficients.
RingSpec RingSpecFor(const FitOptions& options);

/// Computes every vertex's stencil (parallel; identical for any thread count).
/// `faces_read`, if given, is called (from the calling thread) once the faces and the
/// topology's rows have been read (after the spans, or after the growth where it steps on
/// fan rows): from then on only topo.num_vertices, is_boundary and
/// locality_order are, so the caller may free mesh.faces and the other rows (a one-off
/// fit's memory: FitSurfaceOnce).
Neighborhoods BuildNeighborhoods(const Topology& topo, const Mesh& mesh, const RingSpec& spec,
                                 int num_threads = 0, const std::function<void()>& faces_read = nullptr);

/// The stencils of `vertices` alone: row i (nb.Points(i)) is vertices[i]'s stencil, equal to
/// BuildNeighborhoods' (points, order, ring); no `ordered`. Costs the few stencils, not the
/// mesh's (the noise test's sample: EstimateNoise).
Neighborhoods BuildNeighborhoodsOf(const Topology& topo, const Mesh& mesh, const RingSpec& spec,
                                   const std::vector<int32_t>& vertices, int num_threads = 0);

}  // namespace geomfit
