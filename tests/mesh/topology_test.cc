#include "core/mesh/topology.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

#include "absl/strings/str_cat.h"
#include "core/surfaces/analytic.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;

using testing_util::MakeMesh;
using testing_util::ShuffleVertices;

Mesh Tetrahedron() {
  return MakeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}},
                  {{0, 2, 1}, {0, 1, 3}, {0, 3, 2}, {1, 2, 3}});
}

Mesh Square() {  // two triangles, open
  return MakeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}}, {{0, 1, 2}, {0, 2, 3}});
}

Mesh Cube() {  // six outward quads, closed
  return MakeMesh(
      {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 1}, {1, 1, 1}, {0, 1, 1}},
      {{0, 3, 2, 1}, {4, 5, 6, 7}, {0, 1, 5, 4}, {1, 2, 6, 5}, {2, 3, 7, 6}, {3, 0, 4, 7}});
}

/// The CSR row of vertex v as a vector.
std::vector<int32_t> Neighbors(const Topology& t, int v) {
  return std::vector<int32_t>(t.Neighbors(v), t.Neighbors(v) + t.NumNeighbors(v));
}
std::vector<int32_t> VertexFaces(const Topology& t, int v) {
  return std::vector<int32_t>(t.VertexFaces(v), t.VertexFaces(v) + t.NumVertexFaces(v));
}

/// Expects INVALID_ARGUMENT with a message containing every one of `words`.
void ExpectInvalid(const absl::Status& s, const std::vector<std::string>& words) {
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  for (const std::string& w : words) EXPECT_THAT(std::string(s.message()), HasSubstr(w));
}

TEST(TopologyTest, ClosedTetrahedron) {
  auto t = ValidateMesh(Tetrahedron());
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_EQ(t->num_vertices, 4);
  EXPECT_EQ(t->num_faces, 4);
  EXPECT_FALSE(t->has_quads);
  EXPECT_EQ(t->num_boundary_edges, 0);
  EXPECT_EQ(t->num_isolated, 0);
  EXPECT_THAT(t->is_boundary, ElementsAre(0, 0, 0, 0));
  EXPECT_THAT(Neighbors(*t, 0), ElementsAre(1, 2, 3));
  EXPECT_THAT(Neighbors(*t, 1), ElementsAre(0, 2, 3));
  EXPECT_THAT(Neighbors(*t, 2), ElementsAre(0, 1, 3));
  EXPECT_THAT(Neighbors(*t, 3), ElementsAre(0, 1, 2));
  EXPECT_THAT(VertexFaces(*t, 0), ElementsAre(0, 1, 2));
  EXPECT_THAT(VertexFaces(*t, 1), ElementsAre(0, 1, 3));
  EXPECT_THAT(VertexFaces(*t, 2), ElementsAre(0, 2, 3));
  EXPECT_THAT(VertexFaces(*t, 3), ElementsAre(1, 2, 3));
  EXPECT_GT(t->Bytes(), sizeof(Topology));
}

TEST(TopologyTest, OpenSquareHasFourBoundaryVertices) {
  auto t = ValidateMesh(Square());
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_EQ(t->num_boundary_edges, 4);
  EXPECT_THAT(t->is_boundary, ElementsAre(1, 1, 1, 1));
  EXPECT_THAT(t->is_isolated, ElementsAre(0, 0, 0, 0));
  EXPECT_THAT(Neighbors(*t, 0), ElementsAre(1, 2, 3));
  EXPECT_THAT(Neighbors(*t, 1), ElementsAre(0, 2));
  EXPECT_THAT(Neighbors(*t, 2), ElementsAre(0, 1, 3));
  EXPECT_THAT(Neighbors(*t, 3), ElementsAre(0, 2));
  EXPECT_THAT(VertexFaces(*t, 0), ElementsAre(0, 1));
  EXPECT_THAT(VertexFaces(*t, 1), ElementsAre(0));
  EXPECT_THAT(VertexFaces(*t, 2), ElementsAre(0, 1));
  EXPECT_THAT(VertexFaces(*t, 3), ElementsAre(1));
}

TEST(TopologyTest, QuadStrip) {
  // 0-1-2 on y = 0, 3-4-5 on y = 1; two quads.
  const Mesh m = MakeMesh({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 1, 0}, {1, 1, 0}, {2, 1, 0}},
                          {{0, 1, 4, 3}, {1, 2, 5, 4}});
  auto t = ValidateMesh(m);
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_TRUE(t->has_quads);
  EXPECT_EQ(t->num_boundary_edges, 6);
  EXPECT_THAT(t->is_boundary, ElementsAre(1, 1, 1, 1, 1, 1));
  EXPECT_THAT(Neighbors(*t, 0), ElementsAre(1, 3));
  EXPECT_THAT(Neighbors(*t, 1), ElementsAre(0, 2, 4));
  EXPECT_THAT(Neighbors(*t, 4), ElementsAre(1, 3, 5));
  EXPECT_THAT(Neighbors(*t, 5), ElementsAre(2, 4));
  EXPECT_THAT(VertexFaces(*t, 1), ElementsAre(0, 1));
  EXPECT_THAT(VertexFaces(*t, 3), ElementsAre(0));
}

TEST(TopologyTest, ClosedCubeOfQuads) {
  auto t = ValidateMesh(Cube());
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_TRUE(t->has_quads);
  EXPECT_EQ(t->num_boundary_edges, 0);
  for (int v = 0; v < 8; ++v) {
    EXPECT_EQ(t->NumNeighbors(v), 3) << v;
    EXPECT_EQ(t->NumVertexFaces(v), 3) << v;
    EXPECT_EQ(t->is_boundary[v], 0) << v;
  }
  EXPECT_THAT(Neighbors(*t, 0), ElementsAre(1, 3, 4));
  EXPECT_THAT(Neighbors(*t, 6), ElementsAre(2, 5, 7));
}

TEST(TopologyTest, MixedTrianglesAndQuads) {
  const Mesh m = MakeMesh({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 1, 0}, {1, 1, 0}, {2, 1, 0}},
                          {{0, 1, 4, 3}, {1, 2, 5}, {1, 5, 4}});
  auto t = ValidateMesh(m);
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_TRUE(t->has_quads);
  EXPECT_EQ(t->num_boundary_edges, 6);
  EXPECT_THAT(Neighbors(*t, 1), ElementsAre(0, 2, 4, 5));
  EXPECT_THAT(Neighbors(*t, 5), ElementsAre(1, 2, 4));
  EXPECT_THAT(VertexFaces(*t, 1), ElementsAre(0, 1, 2));
  EXPECT_THAT(VertexFaces(*t, 5), ElementsAre(1, 2));
  EXPECT_THAT(t->is_boundary, ElementsAre(1, 1, 1, 1, 1, 1));
}

// An external mesher's vertex order: the topology of the relabelled mesh is the
// relabelling of the topology (rows sorted, faces in face order, same flags).
TEST(TopologyTest, ShuffledVerticesGiveTheRelabelledTopology) {
  GeneratorOptions g;
  g.n = 10;
  GeneratorOptions q = g;
  q.quads = true;
  const Mesh meshes[] = {GenerateTorusMesh(g), GenerateBumpMesh(g), GenerateTorusMesh(q),
                         GenerateBumpMesh(q), GenerateSphereMesh(g)};
  for (const Mesh& m : meshes) {
    std::vector<int32_t> perm;
    const Mesh s = ShuffleVertices(m, 7, &perm);
    auto t = BuildTopology(m);
    auto u = BuildTopology(s);
    ASSERT_TRUE(t.ok()) << t.status();
    ASSERT_TRUE(u.ok()) << u.status();
    EXPECT_EQ(u->num_boundary_edges, t->num_boundary_edges);
    EXPECT_EQ(u->has_quads, t->has_quads);
    EXPECT_EQ(u->vv.size(), t->vv.size());
    for (int v = 0; v < m.NumVertices(); ++v) {
      const int w = perm[v];
      EXPECT_EQ(u->is_boundary[w], t->is_boundary[v]) << v;
      std::vector<int32_t> relabelled;
      for (int32_t x : Neighbors(*t, v)) relabelled.push_back(perm[x]);
      std::sort(relabelled.begin(), relabelled.end());
      EXPECT_EQ(Neighbors(*u, w), relabelled) << v;
      EXPECT_EQ(VertexFaces(*u, w), VertexFaces(*t, v)) << v;
    }
  }
}

TEST(TopologyTest, IsolatedVertexIsAllowedButFlagged) {
  Mesh m =
      MakeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}, {5, 5, 5}}, {{0, 1, 2}, {0, 2, 3}});
  auto t = ValidateMesh(m);
  ASSERT_TRUE(t.ok()) << t.status();
  EXPECT_EQ(t->num_isolated, 1);
  EXPECT_THAT(t->is_isolated, ElementsAre(0, 0, 0, 0, 1));
  EXPECT_EQ(t->is_boundary[4], 0);
  EXPECT_EQ(t->NumNeighbors(4), 0);
  EXPECT_EQ(t->NumVertexFaces(4), 0);
}

TEST(TopologyErrorTest, EmptyMesh) {
  ExpectInvalid(BuildTopology(Mesh{}).status(), {"no vertices"});
  Mesh no_faces = Square();
  no_faces.faces.Mutable().resize(0, 4);
  ExpectInvalid(BuildTopology(no_faces).status(), {"no faces"});
}

TEST(TopologyErrorTest, IndexOutOfRange) {
  Mesh m = Square();
  m.faces.Mutable()(1, 2) = 7;
  ExpectInvalid(ValidateMesh(m).status(), {"face 1", "7", "out of range"});
}

TEST(TopologyErrorTest, NegativeIndex) {
  Mesh m = Square();
  m.faces.Mutable()(0, 1) = -2;
  ExpectInvalid(ValidateMesh(m).status(), {"face 0", "-2", "out of range"});
}

TEST(TopologyErrorTest, RepeatedVertexInFace) {
  Mesh m = Square();
  m.faces.Mutable()(1, 2) = 2;  // (0, 2, 2)
  ExpectInvalid(ValidateMesh(m).status(), {"face 1", "vertex 2", "twice"});
}

TEST(TopologyErrorTest, NonManifoldEdge) {
  // Three triangles share edge (0, 1).
  const Mesh m = MakeMesh({{0, 0, 0}, {1, 0, 0}, {0.5, 1, 0}, {0.5, -1, 0}, {0.5, 0, 1}},
                          {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}});
  ExpectInvalid(ValidateMesh(m).status(), {"non-manifold edge (0, 1)", "3 faces"});
}

TEST(TopologyErrorTest, NonManifoldVertexBowTie) {
  // Two open cones whose apexes are the same vertex 0.
  const Mesh m = MakeMesh({{0, 0, 0},
                           {1, 0, 1},
                           {-0.5, 0.8, 1},
                           {-0.5, -0.8, 1},
                           {1, 0, -1},
                           {-0.5, 0.8, -1},
                           {-0.5, -0.8, -1}},
                          {{0, 1, 2}, {0, 2, 3}, {0, 3, 1}, {0, 5, 4}, {0, 6, 5}, {0, 4, 6}});
  ExpectInvalid(ValidateMesh(m).status(), {"non-manifold vertex 0", "2 separate fans"});
}

// Cones of n faces each sharing their apex 0 (`cones` of them), closed or open:
// the fan check compares face pairs up to 12 faces at a vertex and sorts beyond.
Mesh Cones(int cones, int n, bool open) {
  std::vector<std::array<double, 3>> p = {{0, 0, 0}};
  std::vector<std::vector<int>> faces;
  for (int c = 0; c < cones; ++c) {
    const int base = static_cast<int>(p.size());
    const double z = c % 2 == 0 ? 1 : -1, shift = c / 2 * 3.0;
    for (int i = 0; i < n; ++i)
      p.push_back({shift + std::cos(2 * M_PI * i / n), std::sin(2 * M_PI * i / n), z});
    for (int i = 0; i < (open ? n - 1 : n); ++i) faces.push_back({0, base + i, base + (i + 1) % n});
  }
  return MakeMesh(p, faces);
}

TEST(TopologyErrorTest, FansCountedWithAndWithoutSorting) {
  for (const int n : {3, 5, 6, 7, 13, 20}) {  // 2n, n - 1 and 2(n - 1) faces at the apex
    EXPECT_TRUE(ValidateMesh(Cones(1, n, false)).ok()) << n;
    EXPECT_TRUE(ValidateMesh(Cones(1, n, true)).ok()) << n;
    ExpectInvalid(ValidateMesh(Cones(2, n, false)).status(),
                  {"non-manifold vertex 0", absl::StrCat("its ", 2 * n, " faces form 2 separate fans")});
    ExpectInvalid(ValidateMesh(Cones(2, n, true)).status(),
                  {"non-manifold vertex 0", absl::StrCat("its ", 2 * (n - 1), " faces form 2 separate fans")});
  }
  ExpectInvalid(ValidateMesh(Cones(3, 5, false)).status(), {"its 15 faces form 3 separate fans"});
  ExpectInvalid(ValidateMesh(Cones(3, 3, true)).status(), {"its 6 faces form 3 separate fans"});
}

TEST(TopologyErrorTest, FlippedFace) {
  Mesh m = Square();
  m.faces.Mutable().row(1) << 0, 3, 2, -1;  // traverses (2 -> 0) like face 0
  ExpectInvalid(ValidateMesh(m).status(),
                {"inconsistent orientation", "faces 0 and 1", "edge (0, 2)"});
}

TEST(TopologyErrorTest, NonFiniteCoordinates) {
  Mesh m = Tetrahedron();
  m.positions(1, 2) = std::numeric_limits<double>::quiet_NaN();
  ExpectInvalid(ValidateMesh(m).status(), {"vertex 1", "coordinate z", "not finite"});
  EXPECT_TRUE(BuildTopology(m).ok());  // connectivity alone is fine
  m = Tetrahedron();
  m.positions(3, 0) = -std::numeric_limits<double>::infinity();
  ExpectInvalid(ValidateGeometry(m), {"vertex 3", "coordinate x", "not finite"});
}

TEST(TopologyErrorTest, ZeroAreaFace) {
  const Mesh m = MakeMesh({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {1, 1, 0}},
                          {{0, 3, 1}, {0, 1, 2}});  // face 1 is collinear
  ExpectInvalid(ValidateMesh(m).status(), {"face 1", "zero area"});
}

TEST(TopologyErrorTest, HugeCoordinatesAreReportedAsOverflow) {
  const Mesh m = MakeMesh({{0, 0, 0}, {1e300, 0, 0}, {0, 1e300, 0}}, {{0, 1, 2}});
  ExpectInvalid(ValidateGeometry(m), {"face 0", "too large", "overflow"});
}

TEST(TopologyErrorTest, TinyWellShapedFacesAreNotZeroArea) {
  // Marching cubes makes faces with edges ~1e-7 in meshes of size ~1: valid.
  const double e = 2e-7;
  const Mesh m = MakeMesh({{0, 0, 0}, {3, 0, 0}, {0, 3, 0}, {1, 1, 0}, {1 + e, 1, 0}, {1, 1 + e, 0}},
                          {{3, 4, 5}, {0, 1, 2}});
  EXPECT_TRUE(ValidateGeometry(m).ok()) << ValidateGeometry(m);
  // ... but coincident corners are.
  const Mesh d = MakeMesh({{0, 0, 0}, {1, 0, 0}, {1, 0, 0}}, {{0, 1, 2}});
  ExpectInvalid(ValidateGeometry(d), {"face 0", "zero area"});
}

}  // namespace

TEST(SharedFacesTest, CopiesShareUntilOneWrites) {
  const Mesh a = Square();
  Mesh b = a;
  b.positions *= 2.0;
  EXPECT_TRUE(b.faces.SharesWith(a.faces)) << "a copy shares the faces array";
  b.faces.Mutable()(0, 0) = a.faces(0, 1);
  EXPECT_FALSE(b.faces.SharesWith(a.faces)) << "writing copies first";
  EXPECT_EQ(a.faces, Square().faces) << "the original is untouched";
  EXPECT_NE(b.faces, a.faces);
  Mesh c;
  EXPECT_EQ(c.NumFaces(), 0);
  c.faces.Mutable().resize(2, 4);
  EXPECT_EQ(c.NumFaces(), 2);
}

}  // namespace geomfit

namespace geomfit {
namespace {

// The locality order visits every vertex once, components one after another, and keeps
// neighbours close on a shuffled mesh: along the order, a vertex's first neighbour lies
// within a ring's width of it, where the file's numbering puts it anywhere.
TEST(TopologyTest, LocalityOrderIsABreadthFirstPermutation) {
  GeneratorOptions g;
  g.n = 24;
  const Mesh shuffled = testing_util::ShuffleVertices(GenerateTorusMesh(g), 5);
  const Topology t = BuildTopology(shuffled).value();
  const int nv = t.num_vertices;
  ASSERT_EQ(static_cast<int>(t.locality_order.size()), nv);
  std::vector<int> position(nv, -1);
  for (int k = 0; k < nv; ++k) {
    ASSERT_EQ(position[t.locality_order[k]], -1) << "vertex visited twice";
    position[t.locality_order[k]] = k;
  }
  double order_gap = 0, index_gap = 0;
  for (int v = 0; v < nv; ++v) {
    const int w = t.Neighbors(v)[0];
    order_gap += std::abs(position[v] - position[w]);
    index_gap += std::abs(v - w);
  }
  EXPECT_LT(order_gap / nv, 0.1 * index_gap / nv);
  // Isolated vertices and separate components are visited too.
  Mesh two = testing_util::MakeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 5, 5}, {7, 0, 0}, {8, 0, 0}, {7, 1, 0}},
                      {{0, 1, 2}, {4, 5, 6}});
  const Topology t2 = BuildTopology(two).value();
  EXPECT_THAT(t2.locality_order, ::testing::ElementsAre(0, 1, 2, 3, 4, 5, 6));
}

}  // namespace
}  // namespace geomfit

namespace geomfit {
namespace {

// A mesh relabelled for locality with RowOrder::kSource: the same mesh under the
// recorded relabelling (face rows in their source rotation), and a
// topology whose rows list the source's neighbours and faces in the source's order (so
// stencils and vertex normals repeat the source's operations). Shuffled numberings,
// quads, open and closed meshes, an isolated vertex.
TEST(LocalityRelabellingTest, TopologyRowsFollowTheSource) {
  GeneratorOptions g;
  g.n = 10;
  GeneratorOptions q = g;
  q.quads = true;
  Mesh with_isolated = GenerateBumpMesh(g);
  with_isolated.positions.conservativeResize(with_isolated.NumVertices() + 1, 3);
  with_isolated.positions.bottomRows<1>() << 0.25, 0.5, 3.0;
  const Mesh meshes[] = {GenerateTorusMesh(g), GenerateBumpMesh(q), GenerateTorusMesh(q), GenerateSphereMesh(g),
                         with_isolated};
  for (const Mesh& base : meshes) {
    const Mesh m = testing_util::ShuffleVertices(base, 11);
    const LocalityRelabelling r = RelabelForLocality(m, RowOrder::kSource).value();
    const int nv = m.NumVertices(), nf = m.NumFaces();
    ASSERT_EQ(r.mesh.NumVertices(), nv);
    ASSERT_EQ(r.mesh.NumFaces(), nf);
    std::vector<int32_t> relabel(nv, -1), face_relabel(nf, -1);
    for (int v = 0; v < nv; ++v) relabel[r.vertex_source[v]] = v;
    for (int f = 0; f < nf; ++f) face_relabel[r.face_source[f]] = f;
    ASSERT_EQ(std::count(relabel.begin(), relabel.end(), -1), 0) << "not a permutation";
    ASSERT_EQ(std::count(face_relabel.begin(), face_relabel.end(), -1), 0) << "not a permutation";
    for (int v = 0; v < nv; ++v) ASSERT_EQ(r.mesh.positions.row(v), m.positions.row(r.vertex_source[v]));
    for (int f = 0; f < nf; ++f)
      for (int c = 0; c < 4; ++c) {
        const int32_t src = m.faces(r.face_source[f], c);
        ASSERT_EQ(r.mesh.faces(f, c), src < 0 ? -1 : relabel[src]) << "face " << f;
      }
    // Faces in order of their lowest vertex: a face's corners are near its position.
    for (int f = 1; f < nf; ++f) {
      auto lowest = [&](int h) {
        int32_t low = nv;
        for (int c = 0; c < r.mesh.FaceSize(h); ++c) low = std::min(low, r.mesh.faces(h, c));
        return low;
      };
      ASSERT_LE(lowest(f - 1), lowest(f));
    }
    const Topology t = BuildTopology(m).value();
    const Topology u = BuildTopology(r).value();
    EXPECT_FALSE(u.vertex_faces_ascending);
    EXPECT_TRUE(t.vertex_faces_ascending);
    EXPECT_EQ(u.num_boundary_edges, t.num_boundary_edges);
    EXPECT_EQ(u.num_isolated, t.num_isolated);
    EXPECT_EQ(u.has_quads, t.has_quads);
    for (int v = 0; v < nv; ++v) {
      const int s = r.vertex_source[v];
      EXPECT_EQ(u.is_boundary[v], t.is_boundary[s]) << v;
      EXPECT_EQ(u.is_isolated[v], t.is_isolated[s]) << v;
      std::vector<int32_t> neighbors, faces;
      for (int32_t w : Neighbors(u, v)) neighbors.push_back(r.vertex_source[w]);
      for (int32_t f : VertexFaces(u, v)) faces.push_back(r.face_source[f]);
      ASSERT_EQ(neighbors, Neighbors(t, s)) << v;
      ASSERT_EQ(faces, VertexFaces(t, s)) << v;
    }
  }
}

// The corners after and before v in face f of m.
std::array<int32_t, 2> Spokes(const Mesh& m, int f, int v) {
  int c = 0;
  while (m.faces(f, c) != v) ++c;
  return {m.Next(f, c), m.Prev(f, c)};
}

// A torus with holes: the faces around every 37th vertex removed (that vertex left
// isolated, a boundary loop around each hole), some holes joined into larger ones.
Mesh HoledTorus(const GeneratorOptions& g) {
  const Mesh m = GenerateTorusMesh(g);
  std::vector<uint8_t> drop(m.NumFaces(), 0);
  for (int f = 0; f < m.NumFaces(); ++f)
    for (int c = 0; c < m.FaceSize(f); ++c) drop[f] |= m.faces(f, c) % 37 == 0;
  std::vector<std::array<int32_t, 4>> kept;
  for (int f = 0; f < m.NumFaces(); ++f)
    if (!drop[f]) kept.push_back({m.faces(f, 0), m.faces(f, 1), m.faces(f, 2), m.FaceSize(f) == 4 ? m.faces(f, 3) : -1});
  Mesh out;
  out.positions = m.positions;
  Faces faces(static_cast<int>(kept.size()), 4);
  for (size_t f = 0; f < kept.size(); ++f) std::copy_n(kept[f].data(), 4, faces.data() + 4 * f);
  out.faces = std::move(faces);
  return out;
}

// RowOrder::kRotational: the source's labels and face rows up to rotation (each starting
// at its corner furthest along kRowDirection); the topology's rows the source's as sets,
// each vertex's faces in fan order
// (each face's next spoke the previous face's prev spoke, closing the cycle on a closed
// fan), its neighbours the fan's spokes; an open fan (a boundary vertex) starts at its
// boundary edge, a closed one at the spoke nearest kRowDirection. Shuffled numberings,
// quads, a Delaunay sphere, open meshes with one, two and many boundary loops, isolated
// vertices.
TEST(LocalityRelabellingTest, RotationalRowsAreFans) {
  GeneratorOptions g;
  g.n = 10;
  GeneratorOptions q = g;
  q.quads = true;
  const Mesh meshes[] = {GenerateTorusMesh(g),        GenerateBumpMesh(q), GenerateTorusMesh(q),
                         GenerateDelaunaySphereMesh(500, 0.3), GenerateOpenCylinderMesh(g),
                         HoledTorus(g),               HoledTorus(q)};
  int open_fans = 0, closed_fans = 0, isolated = 0;
  for (const Mesh& base : meshes) {
    const Mesh m = testing_util::ShuffleVertices(base, 5);
    const LocalityRelabelling r = RelabelForLocality(m).value();  // kRotational
    const LocalityRelabelling rs = RelabelForLocality(m, RowOrder::kSource).value();
    const Mesh& rm = r.mesh;
    ASSERT_EQ(r.vertex_source, rs.vertex_source);
    ASSERT_EQ(r.face_source, rs.face_source);
    ASSERT_EQ(rm.positions, rs.mesh.positions);
    // Each face row a rotation of the source's, starting at its corner furthest along
    // kRowDirection.
    auto along = [&](int32_t v) {
      return rm.positions(v, 0) * kRowDirection[0] + rm.positions(v, 1) * kRowDirection[1] +
             rm.positions(v, 2) * kRowDirection[2];
    };
    for (int f = 0; f < rm.NumFaces(); ++f) {
      const int n = rm.FaceSize(f);
      ASSERT_EQ(rs.mesh.FaceSize(f), n);
      int shift = 0;
      while (rs.mesh.faces(f, shift) != rm.faces(f, 0)) ++shift;
      for (int c = 0; c < n; ++c) {
        ASSERT_EQ(rm.faces(f, c), rs.mesh.faces(f, (c + shift) % n)) << "face " << f;
        ASSERT_LE(along(rm.faces(f, c)), along(rm.faces(f, 0))) << "face " << f;
      }
    }
    const Topology t = BuildTopology(m).value();
    const Topology u = BuildTopology(r).value();
    const Topology s = BuildTopology(rs).value();
    EXPECT_FALSE(u.vertex_faces_ascending);
    EXPECT_TRUE(u.fan_rows);  // the property checked below, which BuildNeighborhoods relies on
    EXPECT_FALSE(s.fan_rows);
    EXPECT_FALSE(t.fan_rows);
    EXPECT_EQ(u.num_boundary_edges, t.num_boundary_edges);
    EXPECT_EQ(u.vv_offsets, s.vv_offsets);
    EXPECT_EQ(u.vf_offsets, s.vf_offsets);
    EXPECT_EQ(u.is_boundary, s.is_boundary);
    for (int v = 0; v < u.num_vertices; ++v) {
      std::vector<int32_t> nu = Neighbors(u, v), ns = Neighbors(s, v), fu = VertexFaces(u, v), fs = VertexFaces(s, v);
      std::sort(nu.begin(), nu.end()), std::sort(ns.begin(), ns.end());
      std::sort(fu.begin(), fu.end()), std::sort(fs.begin(), fs.end());
      ASSERT_EQ(nu, ns) << v;
      ASSERT_EQ(fu, fs) << v;
      const int k = u.NumVertexFaces(v);
      if (k == 0) {
        ++isolated;
        continue;
      }
      const bool open = u.is_boundary[v];
      ASSERT_EQ(u.NumNeighbors(v), k + open) << v;
      for (int i = 0; i < k; ++i) {
        const auto sp = Spokes(rm, u.VertexFaces(v)[i], v);
        ASSERT_EQ(u.Neighbors(v)[i], sp[0]) << v;
        if (i + 1 < k) ASSERT_EQ(Spokes(rm, u.VertexFaces(v)[i + 1], v)[0], sp[1]) << v;
      }
      const int32_t last_prev = Spokes(rm, u.VertexFaces(v)[k - 1], v)[1];
      if (open) {
        ++open_fans;
        ASSERT_EQ(u.Neighbors(v)[k], last_prev) << v;
        for (int i = 0; i < k; ++i)  // the first spoke is on the boundary: no face precedes
          ASSERT_NE(Spokes(rm, u.VertexFaces(v)[i], v)[1], u.Neighbors(v)[0]) << v;
      } else {
        ++closed_fans;
        ASSERT_EQ(last_prev, u.Neighbors(v)[0]) << v;
        const Eigen::Vector3d d(kRowDirection[0], kRowDirection[1], kRowDirection[2]);
        auto cosine = [&](int w) {
          const Eigen::Vector3d e = (rm.positions.row(w) - rm.positions.row(v)).transpose();
          return e.dot(d) / e.norm() / d.norm();
        };
        for (int i = 1; i < k; ++i) ASSERT_LE(cosine(u.Neighbors(v)[i]), cosine(u.Neighbors(v)[0]) + 1e-12) << v;
      }
    }
  }
  EXPECT_GT(open_fans, 200);  // 247
  EXPECT_GT(closed_fans, 2000);  // 2396
  EXPECT_EQ(isolated, 18);  // the holed tori's
}

// kRotational's rows are exactly kSource's rotated to their first corner furthest
// along kRowDirection (std::rotate, as RelabelForLocality did before it rotated rows
// as it filed them), ties included: positions snapped to a coarse grid make many
// corners equally far (coincident vertices), triangles and quads, open and closed.
TEST(LocalityRelabellingTest, RotationalRowsEqualTheRotatedSourceRows) {
  GeneratorOptions g;
  g.n = 10;
  GeneratorOptions q = g;
  q.quads = true;
  const Mesh meshes[] = {GenerateTorusMesh(g), GenerateBumpMesh(q), GenerateTorusMesh(q),
                         GenerateDelaunaySphereMesh(500, 0.3), GenerateOpenCylinderMesh(g), HoledTorus(q)};
  int ties = 0;
  for (const Mesh& base : meshes)
    for (double grid : {0.0, 0.5}) {
      Mesh m = testing_util::ShuffleVertices(base, 7);
      if (grid > 0) m.positions = (m.positions.array() / grid).round() * grid;
      const LocalityRelabelling r = RelabelForLocality(m).value();
      const LocalityRelabelling rs = RelabelForLocality(m, RowOrder::kSource).value();
      ASSERT_EQ(r.face_source, rs.face_source);
      const Mesh& rm = r.mesh;
      for (int f = 0; f < rm.NumFaces(); ++f) {
        std::array<int32_t, 4> row;
        for (int c = 0; c < 4; ++c) row[c] = rs.mesh.faces(f, c);
        const int n = row[3] < 0 ? 3 : 4;
        int first = 0;
        double best = -std::numeric_limits<double>::infinity();
        for (int c = 0; c < n; ++c) {
          const double a = rm.positions(row[c], 0) * kRowDirection[0] + rm.positions(row[c], 1) * kRowDirection[1] +
                           rm.positions(row[c], 2) * kRowDirection[2];
          ties += a == best;
          if (a > best) best = a, first = c;
        }
        std::rotate(row.begin(), row.begin() + first, row.begin() + n);
        for (int c = 0; c < 4; ++c) ASSERT_EQ(rm.faces(f, c), row[c]) << "face " << f;
      }
    }
  EXPECT_GT(ties, 100);
}

// A plain statement of BuildTopology(LocalityRelabelling)'s rows: each vertex's faces
// in face order, a closed fan started at the first face (face order) of highest score
// (the next spoke's cos^2 with kRowDirection, with its sign: dot |dot| / |s|^2) for
// kRotational, at its first face for kSource, an open one at its face with no
// predecessor; then each next face found by a search (the face whose next spoke is this
// one's prev spoke); kSource rows then sorted by source index.
void ReferenceFanRows(const LocalityRelabelling& r, std::vector<int32_t>* vf, std::vector<int32_t>* vv,
                      std::vector<int32_t>* vv_offsets, std::vector<uint8_t>* boundary) {
  const Mesh& m = r.mesh;
  const int nv = m.NumVertices();
  std::vector<std::vector<int32_t>> around(nv);
  for (int f = 0; f < m.NumFaces(); ++f)
    for (int c = 0; c < m.FaceSize(f); ++c) around[m.faces(f, c)].push_back(f);
  vf->clear(), vv->clear(), boundary->assign(nv, 0);
  vv_offsets->assign(1, 0);
  for (int v = 0; v < nv; ++v) {
    const std::vector<int32_t>& faces = around[v];
    const int k = static_cast<int>(faces.size());
    std::vector<std::array<int32_t, 2>> sp(k);
    for (int i = 0; i < k; ++i) sp[i] = Spokes(m, faces[i], v);
    auto next_of = [&](int i) {  // the face after face i around v, or -1
      for (int j = 0; j < k; ++j)
        if (sp[j][0] == sp[i][1]) return j;
      return -1;
    };
    int start = -1;
    for (int i = 0; i < k && start < 0; ++i) {
      bool has_pred = false;
      for (int j = 0; j < k; ++j) has_pred |= next_of(j) == i;
      if (!has_pred) start = i;
    }
    const bool open = start >= 0;
    if (!open && k > 0) {
      start = 0;
      if (r.order == RowOrder::kRotational) {
        double best = -std::numeric_limits<double>::infinity();
        for (int i = 0; i < k; ++i) {
          double s[3], dot = 0, len2 = 0;
          for (int c = 0; c < 3; ++c) s[c] = m.positions(sp[i][0], c) - m.positions(v, c);
          dot = s[0] * kRowDirection[0] + s[1] * kRowDirection[1] + s[2] * kRowDirection[2];
          len2 = s[0] * s[0] + s[1] * s[1] + s[2] * s[2];
          const double score = dot * std::abs(dot) / len2;
          if (score > best) best = score, start = i;
        }
      }
    }
    std::vector<int32_t> f_row, v_row;
    for (int i = start, c = 0; c < k; ++c, i = next_of(i)) f_row.push_back(faces[i]), v_row.push_back(sp[i][0]);
    if (open) v_row.push_back(Spokes(m, f_row.back(), v)[1]);
    if (r.order == RowOrder::kSource) {
      std::sort(f_row.begin(), f_row.end(), [&](int32_t x, int32_t y) { return r.face_source[x] < r.face_source[y]; });
      std::sort(v_row.begin(), v_row.end(),
                [&](int32_t x, int32_t y) { return r.vertex_source[x] < r.vertex_source[y]; });
    }
    vf->insert(vf->end(), f_row.begin(), f_row.end());
    vv->insert(vv->end(), v_row.begin(), v_row.end());
    vv_offsets->push_back(static_cast<int32_t>(vv->size()));
    (*boundary)[v] = open;
  }
}

// BuildTopology(LocalityRelabelling) (one pass per vertex: stamped spoke slots, a
// predecessor bit mask, rows written in fan order) gives ReferenceFanRows' rows exactly,
// the closed fans' starts included where scores tie (positions snapped to a grid):
// shuffled irregular and Delaunay triangles, quads, open meshes with one and several
// boundary loops, isolated vertices, vertices of more than 32 faces (a cone's apex),
// both row orders.
TEST(LocalityRelabellingTest, FanRowsEqualAPlainFanWalk) {
  GeneratorOptions g;
  g.n = 10;
  GeneratorOptions q = g;
  q.quads = true;
  // A cone: an apex with 40 faces, a closed fan past the bit mask's 32.
  Mesh cone;
  cone.positions.resize(42, 3);
  Faces cone_faces(80, 4);
  for (int i = 0; i < 40; ++i) {
    const double a = 2 * M_PI * i / 40;
    cone.positions.row(i) << std::cos(a), std::sin(a) * 1.3, 0.2 * std::sin(3 * a);
    cone_faces.row(i) << 40, i, (i + 1) % 40, -1;       // apex at +z
    cone_faces.row(40 + i) << 41, (i + 1) % 40, i, -1;  // apex at -z
  }
  cone.positions.row(40) << 0.1, 0.05, 1.0;
  cone.positions.row(41) << -0.05, 0.1, -1.0;
  cone.faces = std::move(cone_faces);
  const Mesh meshes[] = {GenerateTorusMesh(g), GenerateBumpMesh(q), GenerateTorusMesh(q),
                         GenerateDelaunaySphereMesh(500, 0.3), GenerateOpenCylinderMesh(g), HoledTorus(g),
                         HoledTorus(q), cone};
  int ties = 0, rows = 0;
  for (const Mesh& base : meshes)
    for (double grid : {0.0, 0.25})
      for (RowOrder order : {RowOrder::kRotational, RowOrder::kSource}) {
        Mesh m = testing_util::ShuffleVertices(base, 11);
        if (grid > 0) m.positions = (m.positions.array() / grid).round() * grid;
        const LocalityRelabelling r = RelabelForLocality(m, order).value();
        const absl::StatusOr<Topology> u = BuildTopology(r);
        if (!u.ok()) {  // snapping can fold a mesh; then the source fails too
          ASSERT_FALSE(BuildTopology(m).ok()) << u.status();
          continue;
        }
        std::vector<int32_t> vf, vv, vv_offsets;
        std::vector<uint8_t> boundary;
        ReferenceFanRows(r, &vf, &vv, &vv_offsets, &boundary);
        ASSERT_EQ(u->vf_faces, vf);
        ASSERT_EQ(u->vv, vv);
        ASSERT_EQ(u->vv_offsets, vv_offsets);
        ASSERT_EQ(u->is_boundary, boundary);
        rows += u->num_vertices;
        // Ties: closed fans with two spokes of equal score.
        if (order == RowOrder::kRotational && grid > 0)
          for (int v = 0; v < u->num_vertices; ++v) {
            std::vector<double> scores;
            for (int32_t w : Neighbors(*u, v)) {
              double s[3];
              for (int c = 0; c < 3; ++c) s[c] = r.mesh.positions(w, c) - r.mesh.positions(v, c);
              const double dot = s[0] * kRowDirection[0] + s[1] * kRowDirection[1] + s[2] * kRowDirection[2];
              scores.push_back(dot * std::abs(dot) / (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]));
            }
            std::sort(scores.begin(), scores.end());
            ties += !u->is_boundary[v] && scores.size() > 1 && scores.end()[-1] == scores.end()[-2];
          }
      }
  EXPECT_GT(rows, 10000);
  EXPECT_GT(ties, 20);
}

// BuildTopology of a relabelling (built from each vertex's fan, no half-edge sort)
// succeeds exactly when BuildTopology of the source does, with the same boundary,
// isolated vertices and row sets: small meshes with random damage (faces flipped,
// duplicated, removed, re-cornered, added between random vertices), both row orders.
TEST(LocalityRelabellingTest, FanTopologyFailsExactlyWhereTheSourceFails) {
  GeneratorOptions g;
  g.n = 4;
  GeneratorOptions q = g;
  q.quads = true;
  const Mesh bases[] = {GenerateTorusMesh(g), GenerateBumpMesh(q), GenerateDelaunaySphereMesh(40, 0.3),
                        GenerateOpenCylinderMesh(g)};
  std::mt19937_64 rng(7);
  int ok = 0, failed = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    const Mesh& base = bases[trial % 4];
    const int nv = base.NumVertices();
    std::vector<std::array<int32_t, 4>> rows;
    for (int f = 0; f < base.NumFaces(); ++f)
      rows.push_back({base.faces(f, 0), base.faces(f, 1), base.faces(f, 2), base.FaceSize(f) == 4 ? base.faces(f, 3) : -1});
    auto pick = [&](int n) { return static_cast<int>(rng() % n); };
    for (int damage = pick(3); damage >= 0; --damage) {
      const int f = pick(static_cast<int>(rows.size()));
      const int n = rows[f][3] < 0 ? 3 : 4;
      switch (pick(8)) {
        case 0: std::reverse(rows[f].begin(), rows[f].begin() + n); break;
        case 1: rows.push_back(rows[f]); break;
        case 2: rows[f][pick(n)] = pick(nv); break;
        case 3: rows.push_back({pick(nv), pick(nv), pick(nv), -1}); break;
        default: if (rows.size() > 1) rows.erase(rows.begin() + f);  // holes, bow ties
      }
    }
    Mesh m;
    m.positions = base.positions;
    Faces faces(static_cast<int>(rows.size()), 4);
    for (size_t f = 0; f < rows.size(); ++f) std::copy_n(rows[f].data(), 4, faces.data() + 4 * f);
    m.faces = std::move(faces);
    m = testing_util::ShuffleVertices(m, trial);
    const absl::StatusOr<Topology> t = BuildTopology(m);
    (t.ok() ? ok : failed)++;
    for (RowOrder order : {RowOrder::kSource, RowOrder::kRotational}) {
      const absl::StatusOr<LocalityRelabelling> r = RelabelForLocality(m, order);
      if (!r.ok()) {  // an index out of range: the source fails too
        ASSERT_FALSE(t.ok());
        continue;
      }
      const absl::StatusOr<Topology> u = BuildTopology(*r);
      ASSERT_EQ(u.ok(), t.ok()) << "trial " << trial << ": " << t.status() << " vs " << u.status();
      if (!t.ok()) {
        EXPECT_EQ(u.status().code(), absl::StatusCode::kInvalidArgument);
        continue;
      }
      ASSERT_EQ(u->num_boundary_edges, t->num_boundary_edges) << "trial " << trial;
      ASSERT_EQ(u->num_isolated, t->num_isolated);
      ASSERT_EQ(u->has_quads, t->has_quads);
      for (int v = 0; v < u->num_vertices; ++v) {
        const int s = r->vertex_source[v];
        ASSERT_EQ(u->is_boundary[v], t->is_boundary[s]) << "trial " << trial << " vertex " << v;
        ASSERT_EQ(u->is_isolated[v], t->is_isolated[s]);
        std::vector<int32_t> nu, fu;
        for (int32_t w : Neighbors(*u, v)) nu.push_back(r->vertex_source[w]);
        for (int32_t f : VertexFaces(*u, v)) fu.push_back(r->face_source[f]);
        if (order == RowOrder::kRotational) std::sort(nu.begin(), nu.end()), std::sort(fu.begin(), fu.end());
        ASSERT_EQ(nu, Neighbors(*t, s)) << "trial " << trial << " vertex " << v;
        ASSERT_EQ(fu, VertexFaces(*t, s));
      }
    }
  }
  EXPECT_GT(ok, 500);
  EXPECT_GT(failed, 500);
}

// A generator's numbering is local; a shuffled one of a large mesh is not.
TEST(LocalityRelabellingTest, LocalNumbering) {
  GeneratorOptions g;
  g.n = 100;
  const Mesh m = GenerateTorusMesh(g);
  EXPECT_TRUE(HasLocalNumbering(m));
  EXPECT_FALSE(HasLocalNumbering(testing_util::ShuffleVertices(m, 3)));
  EXPECT_TRUE(HasLocalNumbering(RelabelForLocality(testing_util::ShuffleVertices(m, 3)).value().mesh));
  // The topology's test agrees with the faces' (each edge twice there, as here on a torus).
  EXPECT_TRUE(HasLocalNumbering(BuildTopology(m).value()));
  EXPECT_FALSE(HasLocalNumbering(BuildTopology(testing_util::ShuffleVertices(m, 3)).value()));
  EXPECT_TRUE(IsLocalIndexGap(kLocalIndexGap * 10, 10));
  EXPECT_FALSE(IsLocalIndexGap(kLocalIndexGap * 10 + 1, 10));
}

// HasLocalNumbering(mesh) stops once the gap sum exceeds the bound for the most edges
// the mesh can have: the same answer as the whole sum, here for face rows whose first k
// (triangles, then mixed with quads) come from a scattered numbering and the rest from a
// local one, k across the threshold (both answers occur), and with the scattered rows
// last instead.
TEST(LocalityRelabellingTest, LocalNumberingStopsEarlyWithTheSameAnswer) {
  GeneratorOptions g;
  g.n = 160;  // shuffled: a mean gap of ~nv / 3, well above kLocalIndexGap
  GeneratorOptions q = g;
  q.quads = true;
  for (const Mesh& local : {GenerateTorusMesh(g), GenerateBumpMesh(q)}) {
    const Mesh scattered = testing_util::ShuffleVertices(local, 7);
    const int nf = local.NumFaces();
    auto whole_sum = [](const Mesh& m) {
      int64_t gap = 0, edges = 0;
      for (int f = 0; f < m.NumFaces(); ++f)
        for (int c = 0; c < m.FaceSize(f); ++c, ++edges)
          gap += std::abs(int64_t{m.faces(f, c)} - m.faces(f, (c + 1) % m.FaceSize(f)));
      return IsLocalIndexGap(gap, edges);
    };
    int answers[2] = {0, 0};
    for (int k = 0; k <= nf; k += std::max(1, nf / 100))
      for (bool scattered_first : {true, false}) {
        Mesh m = local;
        for (int f = 0; f < k; ++f) {
          const int g2 = scattered_first ? f : nf - 1 - f;
          for (int c = 0; c < 4; ++c) m.faces.Mutable()(g2, c) = scattered.faces(g2, c);
        }
        const bool want = whole_sum(m);
        ASSERT_EQ(HasLocalNumbering(m), want) << "k " << k << " first " << scattered_first;
        ++answers[want];
      }
    EXPECT_GT(answers[0], 10);
    EXPECT_GT(answers[1], 10);
  }
}

// Relabelling keeps every topology error: BuildTopology of the relabelled mesh fails
// exactly when the source's does (the CLI then reports the source's message).
TEST(LocalityRelabellingTest, FailsWhereTheSourceFails) {
  const Mesh bad[] = {
      testing_util::MakeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 1, 1}},
                             {{0, 1, 2}, {0, 1, 3}, {0, 1, 4}}),                                  // non-manifold edge
      testing_util::MakeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0}}, {{0, 1, 2}, {1, 2, 3}}),  // flipped
      testing_util::MakeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {-1, 0, 0}, {0, -1, 0}},
                             {{0, 1, 2}, {0, 3, 4}}),  // bow tie
  };
  for (const Mesh& m : bad) {
    ASSERT_FALSE(BuildTopology(m).ok());
    for (RowOrder order : {RowOrder::kSource, RowOrder::kRotational}) {
      const LocalityRelabelling r = RelabelForLocality(m, order).value();
      EXPECT_EQ(BuildTopology(r).status().code(), absl::StatusCode::kInvalidArgument);
    }
  }
  const Mesh out_of_range = testing_util::MakeMesh({{0, 0, 0}, {1, 0, 0}, {0, 1, 0}}, {{0, 1, 3}});
  EXPECT_EQ(RelabelForLocality(out_of_range).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(RelabelForLocality(Mesh{}).status().code(), absl::StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace geomfit
