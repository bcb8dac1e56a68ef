// k-rings and half rings (2.1, Table 2.1, Fig 2.2) and adaptive growth.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdlib>
#include <map>
#include <set>
#include <vector>

#include <gtest/gtest.h>

#include "core/fitting/neighborhood.h"
#include "core/fitting/noise.h"
#include "core/surfaces/analytic.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

// An n x n planar grid; triangles all split the same way (valence 6) or quads.
Mesh PlanarGrid(int n, bool quads) {
  Mesh m;
  m.positions.resize((n + 1) * (n + 1), 3);
  for (int j = 0; j <= n; ++j)
    for (int i = 0; i <= n; ++i) m.positions.row(j * (n + 1) + i) << i, j, 0;
  m.faces.Mutable().resize(n * n * (quads ? 1 : 2), 4);
  int f = 0;
  for (int j = 0; j < n; ++j)
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 2, d = a + n + 1;
      if (quads) {
        m.faces.Mutable().row(f++) << a, b, c, d;
      } else {
        m.faces.Mutable().row(f++) << a, b, c, -1;
        m.faces.Mutable().row(f++) << a, c, d, -1;
      }
    }
  return m;
}

int StencilSize(const Mesh& m, int v, double rings) {
  const Topology t = BuildTopology(m).value();
  RingSpec spec;
  spec.rings = rings;
  spec.adaptive = false;
  spec.max_rings = rings;
  spec.max_points = kMaxStencil;
  return BuildNeighborhoods(t, m, spec, 1).Size(v);
}

TEST(NeighborhoodTest, TriangleRingSizesMatchTable21) {
  const Mesh m = PlanarGrid(12, false);
  const int centre = 6 * 13 + 6;
  // Table 2.1: (d+1)/2 rings hold 7, 13, 19, 31, 37, 55 points for d = 1..6.
  const double rings[] = {1, 1.5, 2, 2.5, 3, 3.5};
  const int expected[] = {7, 13, 19, 31, 37, 55};
  for (int i = 0; i < 6; ++i) EXPECT_EQ(StencilSize(m, centre, rings[i]), expected[i]) << rings[i];
}

TEST(NeighborhoodTest, QuadRingSizesFollowFig22) {
  const Mesh m = PlanarGrid(12, true);
  const int centre = 6 * 13 + 6;
  EXPECT_EQ(StencilSize(m, centre, 1), 5);     // edge neighbours
  EXPECT_EQ(StencilSize(m, centre, 1.5), 9);   // the four incident quads
  EXPECT_EQ(StencilSize(m, centre, 2), 13);    // |i| + |j| <= 2
  EXPECT_EQ(StencilSize(m, centre, 2.5), 21);  // 5 x 5 without corners
}

TEST(NeighborhoodTest, StencilsStartAtTheVertexAndHaveNoDuplicates) {
  GeneratorOptions g;
  g.n = 10;
  const Mesh m = GenerateBumpMesh(g);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 4;
  const Neighborhoods nb = BuildNeighborhoods(t, m, RingSpecFor(o), 2);
  for (int v = 0; v < m.NumVertices(); ++v) {
    ASSERT_EQ(nb.Points(v)[0], v);
    std::set<int> unique(nb.Points(v), nb.Points(v) + nb.Size(v));
    ASSERT_EQ(static_cast<int>(unique.size()), nb.Size(v));
  }
}

TEST(NeighborhoodTest, AdaptiveGrowthReachesMinimumAndBoundaryGrowsFurther) {
  GeneratorOptions g;
  g.n = 16;
  const Mesh m = GenerateBumpMesh(g);
  const Topology t = BuildTopology(m).value();
  for (int d = 1; d <= 6; ++d) {
    FitOptions o;
    o.degree = d;
    const RingSpec spec = RingSpecFor(o);
    EXPECT_EQ(spec.min_points, static_cast<int>(std::ceil((d <= 2 ? 2.0 : 1.5) * NumCoefficients(d))));
    const Neighborhoods nb = BuildNeighborhoods(t, m, spec, 1);
    for (int v = 0; v < m.NumVertices(); ++v) {
      const int want = t.is_boundary[v] ? spec.min_points_boundary : spec.min_points;
      ASSERT_GE(nb.Size(v), want) << "vertex " << v << " degree " << d << " rings " << nb.rings[v];
      ASSERT_LE(nb.Size(v), spec.max_points);
      ASSERT_GE(nb.rings[v], spec.rings);
    }
    // Corner vertex 0 needs more rings than the start.
    EXPECT_GT(nb.rings[0], spec.rings) << "degree " << d;
  }
}

TEST(NeighborhoodTest, MaxPointsStopsAtTheLastCompleteRing) {
  const Mesh m = PlanarGrid(12, false);
  const Topology t = BuildTopology(m).value();
  RingSpec spec;
  spec.rings = 1;
  spec.min_points = 1000;  // always wants more
  spec.max_rings = 6;
  spec.max_points = 40;
  const Neighborhoods nb = BuildNeighborhoods(t, m, spec, 1);
  const int centre = 6 * 13 + 6;
  EXPECT_EQ(nb.Size(centre), 37);  // 3-ring; the 3.5-ring (55) would exceed 40
  EXPECT_EQ(nb.rings[centre], 3.0f);
}

TEST(NeighborhoodTest, IdenticalForAnyThreadCount) {
  GeneratorOptions g;
  g.n = 20;
  const Mesh m = GenerateTorusMesh(g);
  const Topology t = BuildTopology(m).value();
  FitOptions o;
  o.degree = 3;
  const Neighborhoods a = BuildNeighborhoods(t, m, RingSpecFor(o), 1);
  for (int threads : {2, 3, 7}) {
    const Neighborhoods b = BuildNeighborhoods(t, m, RingSpecFor(o), threads);
    EXPECT_EQ(a.offsets, b.offsets);
    EXPECT_EQ(a.indices, b.indices);
  }
}

// BuildNeighborhoods' `faces_read` hook: called once, after which the growth reads
// neither the faces nor the topology's rows (FitSurfaceOnce frees them there): emptied
// in the hook, the stencils are the same (a read of an emptied row would crash or
// change them), for a relabelled torus (the CLI's) and 1 or 2 threads.
TEST(NeighborhoodTest, FacesAndRowsAreNotReadAfterTheHook) {
  GeneratorOptions g;
  g.n = 40;
  const Mesh generated = GenerateTorusMesh(g);
  const Mesh shuffled = testing_util::ShuffleVertices(generated, 5, nullptr);
  LocalityRelabelling r = RelabelForLocality(shuffled).value();
  const Topology topo = BuildTopology(r).value();
  for (int degree : {2, 4})
    for (int threads : {1, 2}) {
      FitOptions o;
      o.degree = degree;
      const Neighborhoods want = BuildNeighborhoods(topo, r.mesh, RingSpecFor(o), threads);
      Mesh mesh = r.mesh;
      Topology t = topo;
      int calls = 0;
      const Neighborhoods got = BuildNeighborhoods(t, mesh, RingSpecFor(o), threads, [&] {
        ++calls;
        mesh.faces = SharedFaces();
        t.vf_offsets.clear(), t.vf_faces.clear(), t.vv_offsets.clear(), t.vv.clear();
        t.vf_offsets.shrink_to_fit(), t.vf_faces.shrink_to_fit(), t.vv_offsets.shrink_to_fit(), t.vv.shrink_to_fit();
      });
      EXPECT_EQ(calls, 1);
      EXPECT_EQ(mesh.NumFaces(), 0);
      EXPECT_EQ(got.offsets, want.offsets) << "degree " << degree << ", threads " << threads;
      EXPECT_EQ(got.indices, want.indices) << "degree " << degree << ", threads " << threads;
      EXPECT_EQ(got.rings, want.rings);
    }
}

// One block grown in vertex order is kept where it was grown (a copy would land above
// it: fresh pages in a CLI run): its capacity is the reserve's, larger than its size (a
// copy's is its size). On fan rows at degree 2 (stencils from 1.5 rings) the reserve is
// 1 + 2n points a vertex (2 rings below min_points, +10%): within 1/8 of the size (a
// reserve too small doubles: ~2x the size).
TEST(NeighborhoodTest, FanStencilsStayWhereTheyAreGrown) {
  GeneratorOptions g;
  g.n = 40;
  for (const Mesh& generated : {GenerateTorusMesh(g), GenerateBumpMesh(g)}) {
    const Mesh shuffled = testing_util::ShuffleVertices(generated, 5, nullptr);
    const LocalityRelabelling r = RelabelForLocality(shuffled).value();
    const Topology topo = BuildTopology(r).value();
    ASSERT_TRUE(topo.fan_rows);
    FitOptions o;
    o.degree = 2;
    const Neighborhoods nb = BuildNeighborhoods(topo, r.mesh, RingSpecFor(o), 1);
    const size_t size = nb.indices.size();
    EXPECT_GT(nb.indices.capacity(), size);
    EXPECT_LE(nb.indices.capacity(), size + size / 8);
    // The same stencils as grown in two blocks (copied to vertex order).
    const Neighborhoods two = BuildNeighborhoods(topo, r.mesh, RingSpecFor(o), 2);
    EXPECT_EQ(nb.offsets, two.offsets);
    EXPECT_EQ(nb.indices, two.indices);
    // The span path (degree 4: 2 rings) keeps its one block too, spare capacity and all.
    o.degree = 4;
    const Neighborhoods spans = BuildNeighborhoods(topo, r.mesh, RingSpecFor(o), 1);
    EXPECT_GT(spans.indices.capacity(), spans.indices.size());
    EXPECT_EQ(spans.indices, BuildNeighborhoods(topo, r.mesh, RingSpecFor(o), 2).indices);
  }
}

// A mesh numbered at random (here 27,648 vertices, far from local) is grown in
// breadth-first order: the stencils must be those of the same mesh in its generated
// (local) order, relabelled, for any thread count.
TEST(NeighborhoodTest, ShuffledNumberingGivesTheRelabelledStencils) {
  GeneratorOptions g;
  g.n = 96;
  const Mesh m = GenerateTorusMesh(g);
  std::vector<int32_t> perm;
  const Mesh s = testing_util::ShuffleVertices(m, 3, &perm);
  const Topology tm = BuildTopology(m).value(), ts = BuildTopology(s).value();
  int64_t gap = 0;  // above kLocalIndexGap (4096) on average: the breadth-first path
  for (int v = 0; v < ts.num_vertices; ++v)
    for (int j = 0; j < ts.NumNeighbors(v); ++j) gap += std::abs(v - ts.Neighbors(v)[j]);
  ASSERT_GT(gap / static_cast<int64_t>(ts.vv.size()), 4096);
  for (int degree : {2, 4}) {
    FitOptions o;
    o.degree = degree;
    const Neighborhoods a = BuildNeighborhoods(tm, m, RingSpecFor(o), 1);
    const Neighborhoods b = BuildNeighborhoods(ts, s, RingSpecFor(o), 1);
    const Neighborhoods b2 = BuildNeighborhoods(ts, s, RingSpecFor(o), 2);
    EXPECT_EQ(b.offsets, b2.offsets);
    EXPECT_EQ(b.indices, b2.indices);
    int mismatches = 0;
    for (int v = 0; v < m.NumVertices(); ++v) {
      const int w = perm[v];
      std::vector<int32_t> want;
      for (int i = 0; i < a.Size(v); ++i) want.push_back(perm[a.Points(v)[i]]);
      std::vector<int32_t> got(b.Points(w), b.Points(w) + b.Size(w));
      mismatches += got.empty() || got[0] != w || b.rings[w] != a.rings[v];
      std::sort(want.begin(), want.end());
      std::sort(got.begin(), got.end());
      mismatches += got != want;
    }
    EXPECT_EQ(mismatches, 0) << "degree " << degree;
  }
}

// The stencils in the topology's locality order (what FitSurface streams): vertex
// order[k]'s stencil at position k, every point given by its rank in the order, for
// the shuffled torus (breadth-first order) and 1 or 2 threads; OrderStencils of any
// permutation gives the same layout for it.
TEST(NeighborhoodTest, OrderedStencilsAreTheStencilsRenumberedByTheOrder) {
  GeneratorOptions g;
  g.n = 24;
  const Mesh s = testing_util::ShuffleVertices(GenerateTorusMesh(g), 5);
  const Topology t = BuildTopology(s).value();
  ASSERT_EQ(static_cast<int>(t.locality_order.size()), s.NumVertices());
  FitOptions o;
  o.degree = 4;
  for (int threads : {1, 2}) {
    const Neighborhoods nb = BuildNeighborhoods(t, s, RingSpecFor(o), threads);
    const OrderedStencils& os = nb.ordered;
    ASSERT_EQ(os.order, t.locality_order);
    ASSERT_EQ(os.offsets.size(), nb.offsets.size());
    ASSERT_EQ(os.points.size(), nb.indices.size());
    for (int k = 0; k < s.NumVertices(); ++k) {
      const int v = os.order[k];
      ASSERT_EQ(os.rank[v], k);
      ASSERT_EQ(os.offsets[k + 1] - os.offsets[k], nb.Size(v));
      for (int i = 0; i < nb.Size(v); ++i) ASSERT_EQ(os.order[os.points[os.offsets[k] + i]], nb.Points(v)[i]);
    }
    std::vector<int32_t> reversed(t.locality_order.rbegin(), t.locality_order.rend());
    const OrderedStencils r = OrderStencils(nb, reversed, threads);
    const int nv = s.NumVertices();
    for (int k = 0; k < nv; ++k) {
      ASSERT_EQ(r.offsets[k + 1] - r.offsets[k], os.offsets[nv - k] - os.offsets[nv - k - 1]);
      for (int i = 0; i < r.offsets[k + 1] - r.offsets[k]; ++i)
        ASSERT_EQ(r.points[r.offsets[k] + i], nv - 1 - os.points[os.offsets[nv - 1 - k] + i]);
    }
  }
}

// The ring rule (2.1) stated plainly on the mesh's face rows, as a reference for the
// stencil order: the k -> k + 0.5 step adds, for each layer-k point a in stencil order
// and each face of a (topo.VertexFaces order), the face's corners in row order when
// the corner after or before a in the row is in the k-ring; the k + 0.5 -> k + 1 step
// adds the edge neighbours of layer k. Growth stops as BuildNeighborhoods documents.
// The near-duplicate rule of the growth: of a triangle whose shortest edge is below 0.1 x
// its longest, the higher-numbered end of that edge does not count towards min_points.
std::vector<uint8_t> NearDuplicateFlags(const Mesh& m) {
  std::vector<uint8_t> flags(m.NumVertices(), 0);
  for (int f = 0; f < m.NumFaces(); ++f) {
    if (m.FaceSize(f) != 3) continue;
    int shortest = 0;
    double e2[3];
    for (int c = 0; c < 3; ++c) {
      e2[c] = (m.positions.row(m.faces(f, (c + 1) % 3)) - m.positions.row(m.faces(f, c))).squaredNorm();
      if (e2[c] < e2[shortest]) shortest = c;
    }
    if (e2[shortest] < 0.01 * std::max({e2[0], e2[1], e2[2]}))
      flags[std::max(m.faces(f, shortest), m.faces(f, (shortest + 1) % 3))] = 1;
  }
  return flags;
}

// `near`: NearDuplicateFlags(m), read with spec.count_near_duplicates.
std::vector<int32_t> PlainStencil(const Topology& t, const Mesh& m, int v, const RingSpec& spec,
                                  const std::vector<uint8_t>& near, float* ring) {
  const auto distinct = [&](const std::vector<int32_t>& s) {
    size_t n = 0;
    for (int32_t x : s) n += !(spec.count_near_duplicates && near[x]);
    return n;
  };
  std::vector<int32_t> out{v};
  std::map<int32_t, int> level{{v, 0}};
  const auto add = [&](int32_t x, int l) {
    if (level.emplace(x, l).second) out.push_back(x);
  };
  const auto in = [&](int32_t x, int l) { return level.count(x) && level[x] <= l; };
  size_t layer_begin = 0, layer_end = 1;
  int steps = 0;
  const int start = static_cast<int>(std::lround(2 * spec.rings));
  const int max_steps = std::max(start, static_cast<int>(std::lround(2 * spec.max_rings)));
  const size_t want = t.is_boundary[v] ? spec.min_points_boundary : spec.min_points;
  while (steps < max_steps) {
    const bool required = steps < start;
    if (!required && (!spec.adaptive || distinct(out) >= want)) break;
    const size_t before = out.size();
    const int k2 = steps - steps % 2;
    if (steps % 2 == 0 && steps > 0) {
      for (size_t i = layer_begin; i < layer_end; ++i) {
        const int32_t a = out[i];
        for (int j = 0; j < t.NumVertexFaces(a); ++j) {
          const int f = t.VertexFaces(a)[j], n = m.FaceSize(f);
          int c = 0;
          while (m.faces(f, c) != a) ++c;
          if (in(m.faces(f, (c + 1) % n), k2) || in(m.faces(f, (c + n - 1) % n), k2))
            for (int q = 0; q < n; ++q) add(m.faces(f, q), k2 + 1);
        }
      }
    } else if (steps % 2 == 1) {
      for (size_t i = layer_begin; i < layer_end; ++i)
        for (int j = 0; j < t.NumNeighbors(out[i]); ++j) add(t.Neighbors(out[i])[j], k2 + 2);
      layer_begin = layer_end;
      layer_end = out.size();
    }
    ++steps;
    if (out.size() > static_cast<size_t>(spec.max_points)) {
      if (required && before == 1) {
        out.resize(spec.max_points);
      } else {
        out.resize(before);
        --steps;
      }
      break;
    }
    if (out.size() == before && steps % 2 == 0) break;
  }
  *ring = 0.5f * steps;
  return out;
}

// Point order included, on a mixed mesh: quads and triangles, face rows starting at
// every corner, boundary, numbered at random (the breadth-first growth order).
TEST(NeighborhoodTest, StencilsEqualThePlainRingRuleInOrderOnAMixedMesh) {
  const Mesh grid = PlanarGrid(40, true);
  Mesh mixed;
  mixed.positions = grid.positions;
  std::vector<std::array<int32_t, 4>> rows;
  for (int f = 0; f < grid.NumFaces(); ++f) {
    const int32_t a = grid.faces(f, 0), b = grid.faces(f, 1), c = grid.faces(f, 2), d = grid.faces(f, 3);
    if (f % 3 == 0) {
      rows.push_back({a, b, c, -1});
      rows.push_back({a, c, d, -1});
    } else {
      rows.push_back({a, b, c, d});
    }
  }
  mixed.faces.Mutable().resize(rows.size(), 4);
  for (size_t f = 0; f < rows.size(); ++f) {
    const int n = rows[f][3] < 0 ? 3 : 4, r = static_cast<int>(f % n);  // rotate the row
    for (int q = 0; q < 4; ++q) mixed.faces.Mutable()(f, q) = q < n ? rows[f][(q + r) % n] : -1;
  }
  const Mesh m = testing_util::ShuffleVertices(mixed, 7);
  const Topology t = BuildTopology(m).value();
  ASSERT_TRUE(t.has_quads);
  std::vector<RingSpec> specs;
  for (int degree : {1, 2, 4, 6}) {
    FitOptions o;
    o.degree = degree;
    specs.push_back(RingSpecFor(o));
  }
  RingSpec capped = specs.back();
  capped.max_points = 30;
  specs.push_back(capped);
  for (size_t k = 0; k < specs.size(); ++k) {
    const Neighborhoods nb = BuildNeighborhoods(t, m, specs[k], 2);
    const std::vector<uint8_t> near = NearDuplicateFlags(m);
    int mismatches = 0;
    for (int v = 0; v < m.NumVertices(); ++v) {
      float ring = 0;
      const std::vector<int32_t> want = PlainStencil(t, m, v, specs[k], near, &ring);
      mismatches += std::vector<int32_t>(nb.Points(v), nb.Points(v) + nb.Size(v)) != want || nb.rings[v] != ring;
    }
    EXPECT_EQ(mismatches, 0) << "spec " << k;
  }
}

// The same on the topology of a LocalityRelabelling (rows in fan or source order, no
// locality_order: grown in vertex order with no test of the numbering), triangles and
// the mixed mesh, open and closed, 1 and 2 threads.
TEST(NeighborhoodTest, RelabelledTopologyStencilsEqualThePlainRingRuleInOrder) {
  GeneratorOptions g;
  g.n = 16;
  GeneratorOptions q = g;
  q.quads = true;
  const Mesh meshes[] = {testing_util::ShuffleVertices(GenerateTorusMesh(g), 3),
                         testing_util::ShuffleVertices(GenerateOpenCylinderMesh(g), 4),
                         testing_util::ShuffleVertices(GenerateBumpMesh(q), 5)};
  int checked = 0;
  for (const Mesh& source : meshes)
    for (RowOrder order : {RowOrder::kRotational, RowOrder::kSource}) {
      const LocalityRelabelling r = RelabelForLocality(source, order).value();
      const Topology t = BuildTopology(r).value();
      ASSERT_TRUE(t.locality_order.empty());
      for (int degree : {2, 4}) {
        FitOptions o;
        o.degree = degree;
        const RingSpec spec = RingSpecFor(o);
        for (int threads : {1, 2}) {
          const Neighborhoods nb = BuildNeighborhoods(t, r.mesh, spec, threads);
          const std::vector<uint8_t> near = NearDuplicateFlags(r.mesh);
          int mismatches = 0;
          for (int v = 0; v < r.mesh.NumVertices(); ++v, ++checked) {
            float ring = 0;
            const std::vector<int32_t> want = PlainStencil(t, r.mesh, v, spec, near, &ring);
            mismatches +=
                std::vector<int32_t>(nb.Points(v), nb.Points(v) + nb.Size(v)) != want || nb.rings[v] != ring;
          }
          EXPECT_EQ(mismatches, 0) << "degree " << degree << ", threads " << threads;
        }
      }
    }
  EXPECT_GT(checked, 10000);
}

// Meshes on which a 1.5-ring is and is not a plain polygon walk (BuildNeighborhoods'
// fan steps, and where they must leave it to the general steps): irregular valences
// 4-8, a tube so thin that 1-rings have chords, a Delaunay sphere, boundaries, holes
// with isolated vertices, a triangle that bounds no face (a chord in three 1-rings),
// valence-3 vertices (triangles split at their centroid),
// valence 3 and 4 everywhere, quads and quads mixed with triangles.
std::vector<Mesh> FanTestMeshes() {
  using testing_util::MakeMesh;
  std::vector<Mesh> out;
  GeneratorOptions g;
  g.n = 10;
  out.push_back(GenerateTorusMesh(g));
  for (int n : {3, 4}) {
    GeneratorOptions thin = g;
    thin.n = n;
    out.push_back(GenerateTorusMesh(thin));
  }
  out.push_back(GenerateDelaunaySphereMesh(400, 0.3));
  out.push_back(GenerateOpenCylinderMesh(g));
  out.push_back(GenerateHemisphereMesh(g));
  {  // holes: the faces around every 41st vertex removed (the vertex left isolated)
    const Mesh torus = GenerateTorusMesh(g);
    std::vector<std::vector<int>> rows;
    for (int f = 0; f < torus.NumFaces(); ++f) {
      std::vector<int> row;
      bool keep = true;
      for (int c = 0; c < torus.FaceSize(f); ++c) row.push_back(torus.faces(f, c)), keep &= torus.faces(f, c) % 41 != 0;
      if (keep) rows.push_back(row);
    }
    std::vector<std::array<double, 3>> verts;
    for (int v = 0; v < torus.NumVertices(); ++v)
      verts.push_back({torus.positions(v, 0), torus.positions(v, 1), torus.positions(v, 2)});
    out.push_back(MakeMesh(verts, rows));
  }
  {  // every fifth triangle split at its centroid: valence-3 vertices
    GeneratorOptions coarse = g;
    coarse.n = 8;
    const Mesh torus = GenerateTorusMesh(coarse);
    std::vector<std::array<double, 3>> verts;
    for (int v = 0; v < torus.NumVertices(); ++v)
      verts.push_back({torus.positions(v, 0), torus.positions(v, 1), torus.positions(v, 2)});
    std::vector<std::vector<int>> rows;
    for (int f = 0; f < torus.NumFaces(); ++f) {
      const int a = torus.faces(f, 0), b = torus.faces(f, 1), c = torus.faces(f, 2);
      if (f % 5) {
        rows.push_back({a, b, c});
        continue;
      }
      const int x = static_cast<int>(verts.size());
      std::array<double, 3> centre{};
      for (int k = 0; k < 3; ++k) centre[k] = (verts[a][k] + verts[b][k] + verts[c][k]) / 3;
      verts.push_back(centre);
      rows.push_back({a, b, x}), rows.push_back({b, c, x}), rows.push_back({c, a, x});
    }
    out.push_back(MakeMesh(verts, rows));
  }
  {  // two spheres, a face taken out of each, glued along its edges: a triangle (a, b, c)
     // that bounds no face, so b and c are adjacent without being consecutive around a
    const Mesh sphere = GenerateDelaunaySphereMesh(300, 0.3);
    const int nv = sphere.NumVertices(), a = sphere.faces(0, 0), b = sphere.faces(0, 1), c = sphere.faces(0, 2);
    std::vector<std::array<double, 3>> verts;
    for (int copy = 0; copy < 2; ++copy)
      for (int v = 0; v < nv; ++v)
        verts.push_back({sphere.positions(v, 0) + 3 * copy, sphere.positions(v, 1), sphere.positions(v, 2)});
    const auto second = [&](int v) { return v == a ? a : v == b ? c : v == c ? b : v + nv; };
    std::vector<std::vector<int>> rows;
    for (int f = 1; f < sphere.NumFaces(); ++f) {
      rows.push_back({sphere.faces(f, 0), sphere.faces(f, 1), sphere.faces(f, 2)});
      rows.push_back({second(sphere.faces(f, 0)), second(sphere.faces(f, 1)), second(sphere.faces(f, 2))});
    }
    out.push_back(MakeMesh(verts, rows));  // the second copy's a, b, c left isolated
  }
  out.push_back(MakeMesh({{1, 1, 1}, {1, -1, -1}, {-1, 1, -1}, {-1, -1, 1}},
                         {{0, 1, 2}, {0, 3, 1}, {0, 2, 3}, {1, 3, 2}}));  // tetrahedron
  out.push_back(MakeMesh({{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}},
                         {{0, 2, 4}, {2, 1, 4}, {1, 3, 4}, {3, 0, 4}, {2, 0, 5}, {1, 2, 5}, {3, 1, 5}, {0, 3, 5}}));
  GeneratorOptions q = g;
  q.quads = true;
  const Mesh quads = GenerateTorusMesh(q);
  out.push_back(quads);
  Mesh mixed = quads;  // every third quad split in two triangles
  std::vector<std::vector<int>> rows;
  for (int f = 0; f < quads.NumFaces(); ++f) {
    const int a = quads.faces(f, 0), b = quads.faces(f, 1), c = quads.faces(f, 2), d = quads.faces(f, 3);
    if (f % 3 == 0)
      rows.push_back({a, b, c}), rows.push_back({a, c, d});
    else
      rows.push_back({a, b, c, d});
  }
  std::vector<std::array<double, 3>> verts;
  for (int v = 0; v < quads.NumVertices(); ++v)
    verts.push_back({quads.positions(v, 0), quads.positions(v, 1), quads.positions(v, 2)});
  out.push_back(testing_util::MakeMesh(verts, rows));
  return out;
}

// The default ring specs of degrees 1-6, in order.
std::vector<RingSpec> DefaultSpecsOfDegrees1To6() {
  std::vector<RingSpec> specs;
  for (int degree = 1; degree <= 6; ++degree) {
    FitOptions o;
    o.degree = degree;
    specs.push_back(RingSpecFor(o));
  }
  return specs;
}

// Stencils (points, order and ring) equal the plain ring rule on FanTestMeshes shuffled,
// relabelled with rotational rows (the fan steps' case) and source rows, and as they
// are (plain BuildTopology), for degrees 1-6 and specs that stop at or around 1.5 rings
// (max_points below and at a valence-6 1.5-ring's 13, starting at 1 or 2 rings), with 1
// and 2 threads.
TEST(NeighborhoodTest, FanStepsEqualThePlainRingRuleWhereverTheyApplyOrNot) {
  std::vector<RingSpec> specs = DefaultSpecsOfDegrees1To6();
  RingSpec s = specs[1];
  for (int max_points : {7, 11, 12, 13, 14}) s.max_points = max_points, specs.push_back(s);
  s = specs[1];
  s.adaptive = false;
  for (double rings : {1.0, 1.5, 2.0}) s.rings = s.max_rings = rings, specs.push_back(s);
  for (int d : {1, 3}) s = specs[d], s.count_near_duplicates = true, specs.push_back(s);  // degrees 2, 4
  int checked = 0, mesh_index = 0;
  for (const Mesh& plain : FanTestMeshes()) {
    const Mesh source = testing_util::ShuffleVertices(plain, 11 + mesh_index++);
    for (int variant = 0; variant < 3; ++variant) {
      LocalityRelabelling r;
      if (variant < 2) r = RelabelForLocality(source, variant ? RowOrder::kSource : RowOrder::kRotational).value();
      const Mesh& m = variant < 2 ? r.mesh : source;
      absl::StatusOr<Topology> t = variant < 2 ? BuildTopology(r) : BuildTopology(source);
      ASSERT_TRUE(t.ok()) << "mesh " << mesh_index - 1 << ": " << t.status();
      for (size_t k = 0; k < specs.size(); ++k) {
        // Two threads (slow to start on a busy machine) for degrees 2, 4 and 6 with rotational rows.
        const int threads = variant == 0 && k % 2 == 1 && k < 6 ? 2 : 1;
        const Neighborhoods one = BuildNeighborhoods(*t, m, specs[k], 1), two = BuildNeighborhoods(*t, m, specs[k], threads);
        const std::vector<uint8_t> near = NearDuplicateFlags(m);
        int mismatches = 0;
        for (int v = 0; v < m.NumVertices(); ++v, ++checked) {
          float ring = 0;
          const std::vector<int32_t> want = PlainStencil(*t, m, v, specs[k], near, &ring);
          for (const Neighborhoods* nb : {&one, &two})
            mismatches += std::vector<int32_t>(nb->Points(v), nb->Points(v) + nb->Size(v)) != want || nb->rings[v] != ring;
        }
        EXPECT_EQ(mismatches, 0) << "mesh " << mesh_index - 1 << ", variant " << variant << ", spec " << k;
      }
    }
  }
  EXPECT_GT(checked, 100000);
}

// BuildNeighborhoodsOf (a few vertices' stencils: the noise test's sample) gives those
// vertices' rows of BuildNeighborhoods (points, order, ring), with FanSteps where the
// rows are fans and start further out (2.5 rings) and the general steps elsewhere:
// FanTestMeshes shuffled, relabelled with rotational and source rows and as they are,
// every third vertex in reverse order, degrees 1-6 and the noise test's spec, 1 and 2 threads.
TEST(NeighborhoodTest, StencilsOfAFewVerticesEqualTheirRowsOfAllStencils) {
  std::vector<RingSpec> specs = DefaultSpecsOfDegrees1To6();
  specs.push_back(NoiseStencilSpec());
  RingSpec near = specs[1];
  near.count_near_duplicates = true;  // flags tested as met (the glued spheres have some)
  specs.push_back(near);
  int checked = 0, fan_meshes = 0, mesh_index = 0;
  for (const Mesh& plain : FanTestMeshes()) {
    const Mesh source = testing_util::ShuffleVertices(plain, 23 + mesh_index++);
    for (int variant = 0; variant < 3; ++variant) {
      LocalityRelabelling r;
      if (variant < 2) r = RelabelForLocality(source, variant ? RowOrder::kSource : RowOrder::kRotational).value();
      const Mesh& m = variant < 2 ? r.mesh : source;
      const Topology t = (variant < 2 ? BuildTopology(r) : BuildTopology(source)).value();
      fan_meshes += t.fan_rows && !t.has_quads;
      std::vector<int32_t> some;
      for (int v = m.NumVertices() - 1; v >= 0; v -= 3) some.push_back(v);
      for (size_t k = 0; k < specs.size(); ++k) {
        const Neighborhoods all = BuildNeighborhoods(t, m, specs[k], 1);
        for (int threads : {1, 2}) {
          const Neighborhoods few = BuildNeighborhoodsOf(t, m, specs[k], some, threads);
          ASSERT_EQ(few.offsets.size(), some.size() + 1);
          int mismatches = 0;
          for (size_t i = 0; i < some.size(); ++i, ++checked) {
            const int v = some[i];
            mismatches += std::vector<int32_t>(few.Points(i), few.Points(i) + few.Size(i)) !=
                              std::vector<int32_t>(all.Points(v), all.Points(v) + all.Size(v)) ||
                          few.rings[i] != all.rings[v];
          }
          EXPECT_EQ(mismatches, 0) << "mesh " << mesh_index - 1 << ", variant " << variant << ", spec " << k;
        }
      }
    }
  }
  EXPECT_GT(fan_meshes, 3);
  EXPECT_GT(checked, 20000);
}

// RingSpec::count_near_duplicates (marching-cubes meshes): of a triangle whose shortest edge
// is below 0.1 x its longest, the higher-numbered end of that edge is not counted towards
// min_points, so stencils holding such pairs grow until they have enough distinct points;
// off (the default), or without such points, the plain stencils; BuildNeighborhoodsOf gives
// the same rows.
TEST(NeighborhoodTest, NearDuplicatePointsDoNotCountTowardsTheMinimum) {
  const int n = 12;
  const Mesh plain = PlanarGrid(n, false);
  Mesh m = plain;
  std::vector<uint8_t> flagged(m.NumVertices(), 0);
  for (int j = 2; j < n - 1; j += 2)
    for (int i = 2; i < n - 1; i += 2) {  // vertex a + 1 moves to 0.05 from a: edge ratio ~0.05
      const int a = j * (n + 1) + i;
      m.positions.row(a + 1) = m.positions.row(a) + Eigen::RowVector3d(0.05, 0, 0);
      flagged[a + 1] = 1;
    }
  ASSERT_EQ(NearDuplicateFlags(m), flagged);
  const Topology t = BuildTopology(m).value(), tp = BuildTopology(plain).value();
  for (int d : {2, 4}) {
    FitOptions o;
    o.degree = d;
    RingSpec spec = RingSpecFor(o);
    const Neighborhoods np = BuildNeighborhoods(tp, plain, spec, 1), off = BuildNeighborhoods(t, m, spec, 1);
    EXPECT_EQ(off.indices, np.indices) << "degree " << d;  // off: the plain grid's stencils
    spec.count_near_duplicates = true;
    const Neighborhoods nb = BuildNeighborhoods(t, m, spec, 1);
    int grown = 0;
    std::vector<int32_t> all;
    for (int v = 0; v < m.NumVertices(); ++v) {
      all.push_back(v);
      int distinct = 0;
      for (int k = 0; k < nb.Size(v); ++k) distinct += !flagged[nb.Points(v)[k]];
      const bool has_flagged = distinct < nb.Size(v);
      if (!t.is_boundary[v] && nb.rings[v] < spec.max_rings) ASSERT_GE(distinct, spec.min_points) << "vertex " << v;
      // The plain grid's stencil where no flagged point joined; a larger one where one did.
      if (!has_flagged) EXPECT_EQ(nb.Size(v), np.Size(v)) << "vertex " << v << " degree " << d;
      grown += nb.Size(v) > np.Size(v);
    }
    EXPECT_GT(grown, 0) << "degree " << d;
    for (int threads : {1, 2}) {
      const Neighborhoods few = BuildNeighborhoodsOf(t, m, spec, all, threads);
      for (int v = 0; v < m.NumVertices(); ++v)
        ASSERT_EQ(std::vector<int32_t>(few.Points(v), few.Points(v) + few.Size(v)),
                  std::vector<int32_t>(nb.Points(v), nb.Points(v) + nb.Size(v)))
            << "vertex " << v << " degree " << d << " threads " << threads;
    }
  }
}

}  // namespace
}  // namespace geomfit
