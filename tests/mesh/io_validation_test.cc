// Readers reject faces naming vertices that do not exist (naming the line or face);
// writers refuse meshes whose connectivity is broken (issue 13 item 7).
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/mesh/io.h"
#include "core/mesh/topology.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

using ::testing::HasSubstr;
using testing_util::MakeMesh;

void ExpectInvalid(const absl::Status& s, const std::vector<std::string>& words) {
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  for (const std::string& w : words) EXPECT_THAT(std::string(s.message()), HasSubstr(w)) << s;
}

std::string Le(uint64_t bits, int n) {
  std::string out;
  for (int i = 0; i < n; ++i) out.push_back(static_cast<char>((bits >> (8 * i)) & 0xff));
  return out;
}

// ---------------------------------------------------------------------------
// OBJ

constexpr char kObjVertices[] = "v 0 0 0\nv 1 0 0\nv 1 1 0\n";

TEST(ReaderIndexTest, ObjIndexBeyondTheVerticesNamesTheLine) {
  ExpectInvalid(
      ParseMesh(std::string(kObjVertices) + "f 1 2 999\n", MeshFormat::kObj, "a.obj").status(),
      {"a.obj: line 4: face 0: vertex index 999 is out of range (the file has 3 vertices)"});
  // The second face is the bad one; a comment line between shifts the line number.
  ExpectInvalid(ParseMesh(std::string(kObjVertices) + "f 1 2 3\n# c\nf 3 2 4\n",
                          MeshFormat::kObj, "b.obj")
                    .status(),
                {"b.obj: line 6: face 1: vertex index 4"});
  // Slash forms are checked too.
  ExpectInvalid(
      ParseMesh(std::string(kObjVertices) + "f 1/1 2/2 7/3\n", MeshFormat::kObj).status(),
      {"line 4", "vertex index 7"});
}

TEST(ReaderIndexTest, ObjForwardReferencesResolveAtTheEnd) {
  // Faces before the vertices they name are legal OBJ.
  auto m = ParseMesh("f 1 2 3\nv 0 0 0\nv 1 0 0\nv 1 1 0\n", MeshFormat::kObj);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->faces.row(0), (Eigen::RowVector4i(0, 1, 2, -1)));
  EXPECT_TRUE(ValidateMesh(*m).ok());
  // ... but one that is never defined is reported at its line.
  ExpectInvalid(ParseMesh("f 1 2 4\nv 0 0 0\nv 1 0 0\nv 1 1 0\n", MeshFormat::kObj).status(),
                {"line 1: face 0: vertex index 4"});
}

// ---------------------------------------------------------------------------
// OFF

TEST(ReaderIndexTest, OffIndexOutOfRangeOrNegativeNamesTheLine) {
  const std::string head = "OFF\n3 2 0\n0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n";
  ExpectInvalid(ParseMesh(head + "3 0 2 3\n", MeshFormat::kOff, "c.off").status(),
                {"c.off: line 7: face 1: vertex index 3 is out of range [0, 3)"});
  ExpectInvalid(ParseMesh(head + "3 0 -1 2\n", MeshFormat::kOff, "c.off").status(),
                {"c.off: line 7: face 1: vertex index -1 is out of range"});
  ExpectInvalid(ParseMesh(head + "3 0 1 99999999999\n", MeshFormat::kOff).status(),
                {"line 7", "99999999999", "out of range"});
}

// ---------------------------------------------------------------------------
// PLY

std::string PlyHeader(const std::string& format, const std::string& index_type) {
  return "ply\nformat " + format +
         " 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
         "element face 2\nproperty list uchar " +
         index_type + " vertex_indices\nend_header\n";
}

TEST(ReaderIndexTest, PlyAsciiIndexOutOfRangeOrNegativeNamesTheLine) {
  const std::string head = PlyHeader("ascii", "int") + "0 0 0\n1 0 0\n1 1 0\n3 0 1 2\n";
  ExpectInvalid(ParseMesh(head + "3 0 2 3\n", MeshFormat::kPly, "d.ply").status(),
                {"d.ply: line 14: face 1: vertex index 3 is out of range [0, 3)"});
  ExpectInvalid(ParseMesh(head + "3 -2 0 1\n", MeshFormat::kPly, "d.ply").status(),
                {"d.ply: line 14: face 1: vertex index -2 is out of range"});
}

std::string BinaryFace(const std::vector<int64_t>& v, int index_bytes) {
  std::string s(1, static_cast<char>(v.size()));
  for (int64_t k : v) s += Le(static_cast<uint64_t>(k), index_bytes);
  return s;
}

std::string BinaryVertices() {
  std::string s;
  for (float x : {0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 1.f, 1.f, 0.f}) {
    uint32_t u;
    std::memcpy(&u, &x, 4);
    s += Le(u, 4);
  }
  return s;
}

TEST(ReaderIndexTest, PlyBinaryIndexOutOfRangeOrNegativeNamesTheFace) {
  const std::string head = PlyHeader("binary_little_endian", "int") + BinaryVertices() +
                           BinaryFace({0, 1, 2}, 4);
  ExpectInvalid(ParseMesh(head + BinaryFace({0, 2, 3}, 4), MeshFormat::kPly, "e.ply").status(),
                {"e.ply: byte ", "face 1: vertex index 3 is out of range [0, 3)"});
  ExpectInvalid(ParseMesh(head + BinaryFace({0, -1, 2}, 4), MeshFormat::kPly).status(),
                {"face 1: vertex index -1 is out of range"});
  // An unsigned short index beyond the vertices.
  const std::string ushort = PlyHeader("binary_little_endian", "ushort") + BinaryVertices() +
                             BinaryFace({0, 1, 2}, 2) + BinaryFace({65535, 1, 2}, 2);
  ExpectInvalid(ParseMesh(ushort, MeshFormat::kPly).status(), {"face 1: vertex index 65535"});
}

TEST(ReaderIndexTest, PlyFacesBeforeVerticesAreCheckedAgainstTheHeaderCount) {
  const std::string header =
      "ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int vertex_indices\n"
      "element vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
  auto m = ParseMesh(header + "3 0 1 2\n0 0 0\n1 0 0\n1 1 0\n", MeshFormat::kPly);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_TRUE(ValidateMesh(*m).ok());
  ExpectInvalid(ParseMesh(header + "3 0 1 3\n0 0 0\n1 0 0\n1 1 0\n", MeshFormat::kPly).status(),
                {"line 10: face 0: vertex index 3 is out of range [0, 3)"});
}

// ---------------------------------------------------------------------------
// STL: indices come from welding, so they are always in range.

TEST(ReaderIndexTest, StlIndicesAreAlwaysInRange) {
  std::string stl(80, ' ');
  stl += Le(2, 4);
  for (int t = 0; t < 2; ++t) {
    stl += std::string(12, '\0');  // normal
    for (float x : {0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 1.f, 1.f, t == 0 ? 0.f : 2.f}) {
      uint32_t u;
      std::memcpy(&u, &x, 4);
      stl += Le(u, 4);
    }
    stl += Le(0, 2);
  }
  auto m = ParseMesh(stl, MeshFormat::kStl);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->NumVertices(), 4);
  EXPECT_EQ(m->faces.row(1), (Eigen::RowVector4i(0, 1, 3, -1)));
}

// ---------------------------------------------------------------------------
// Writers

struct BadMesh {
  Mesh mesh;
  std::vector<std::string> words;
};

std::vector<BadMesh> BadMeshes() {
  const std::vector<std::array<double, 3>> v = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  std::vector<BadMesh> bad = {
      {MakeMesh(v, {{0, 1, 2}, {0, 2, 998}}), {"face 1: vertex index 998 is out of range [0, 4)"}},
      {MakeMesh(v, {{-3, 1, 2}}), {"face 0: vertex index -3 is out of range"}},
      {MakeMesh(v, {{0, 1, 2, 4}}), {"face 0: vertex index 4 is out of range"}},
      {MakeMesh(v, {{0, 1, 2, -5}}), {"face 0", "fourth corner -5"}},
  };
  return bad;
}

TEST(WriterValidationTest, EveryFormatRefusesBrokenConnectivity) {
  for (const BadMesh& b : BadMeshes())
    for (MeshFormat f :
         {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly, MeshFormat::kStl,
          MeshFormat::kVtp, MeshFormat::kVtu}) {
      SCOPED_TRACE(MeshFormatName(f));
      std::vector<std::string> words = b.words;
      words.push_back("refusing to write an invalid mesh");
      ExpectInvalid(FormatMesh(b.mesh, f).status(), words);
    }
  ExpectInvalid(FormatVtp(BadMeshes()[0].mesh, {}).status(), {"face 1", "998"});
}

TEST(WriterValidationTest, WriteMeshNamesThePathAndLeavesNoFile) {
  const std::string path = absl::StrCat(::testing::TempDir(), "/geomfit_wv_", getpid(), ".obj");
  ExpectInvalid(WriteMesh(BadMeshes()[0].mesh, path), {path, "face 1", "998"});
  EXPECT_NE(access(path.c_str(), F_OK), 0);
  EXPECT_NE(access((path + ".tmp").c_str(), F_OK), 0);
  ExpectInvalid(WriteVtp(path + ".vtp", BadMeshes()[0].mesh, {}), {"face 1", "998"});
  EXPECT_NE(access((path + ".vtp").c_str(), F_OK), 0);
}

TEST(WriterValidationTest, GeometryProblemsAreWrittenAsIs) {
  // Writers check connectivity only: a NaN coordinate or a non-manifold fan is data a
  // converter passes on (ValidateMesh rejects it where it matters).
  Mesh m = MakeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}}, {{0, 1, 2}});
  m.positions(1, 1) = std::numeric_limits<double>::quiet_NaN();
  for (MeshFormat f : {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly, MeshFormat::kStl}) {
    auto bytes = FormatMesh(m, f);
    ASSERT_TRUE(bytes.ok()) << bytes.status();
    auto back = ParseMesh(*bytes, f);
    ASSERT_TRUE(back.ok()) << back.status();
    EXPECT_TRUE(std::isnan(back->positions(1, 1)) || std::isnan(back->positions(0, 1)) ||
                std::isnan(back->positions(2, 1)));
  }
}

}  // namespace
}  // namespace geomfit
