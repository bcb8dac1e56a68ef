#include "core/mesh/io.h"

#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "core/mesh/formats/formats.h"
#include "core/mesh/topology.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

#include "tests/mesh/make_mesh.h"
#include "tests/mesh/reader_fuzz.h"

namespace geomfit {
namespace {

using ::testing::HasSubstr;

// ---------------------------------------------------------------------------
// Test meshes and helpers

using testing_util::MakeMesh;

/// Closed tetrahedron; coordinates exactly representable as float (for STL).
Mesh Tetrahedron() {
  return MakeMesh({{0, 0, 0}, {1.5, 0, 0}, {0, 0.25, 0}, {0, 0, -3}},
                  {{0, 1, 2}, {0, 3, 1}, {0, 2, 3}, {1, 3, 2}});
}

/// Triangles with coordinates that need all 17 digits.
Mesh AwkwardTriangles() {
  return MakeMesh({{0.1, 1.0 / 3.0, -2.0 / 7.0},
                   {1e-300, -1e300, 6.02214076e23},
                   {std::nextafter(1.0, 2.0), -0.0, 5e-324},
                   {M_PI, M_E, -M_SQRT2}},
                  {{0, 1, 2}, {0, 2, 3}});
}

Mesh QuadStrip() {
  return MakeMesh({{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {0, 1, 0}, {1, 1, 0}, {2, 1, 0}},
                  {{0, 1, 4, 3}, {1, 2, 5, 4}});
}

Mesh Mixed() {
  return MakeMesh({{0, 0, 0}, {1, 0, 0.125}, {2, 0, 0}, {0, 1, 0}, {1, 1, -0.5}, {2, 1, 0}},
                  {{0, 1, 4, 3}, {1, 2, 5}, {1, 5, 4}});
}

/// Bitwise equality of positions (so -0.0 and NaN payloads count) and faces.
void ExpectSameMesh(const Mesh& a, const Mesh& b) {
  ASSERT_EQ(a.NumVertices(), b.NumVertices());
  ASSERT_EQ(a.NumFaces(), b.NumFaces());
  EXPECT_EQ(
      std::memcmp(a.positions.data(), b.positions.data(), sizeof(double) * 3 * a.NumVertices()), 0);
  EXPECT_EQ(a.faces, b.faces);
}

/// Same triangles up to a renumbering of vertices (STL welding reorders them).
void ExpectSameTriangles(const Mesh& original, const Mesh& welded) {
  ASSERT_EQ(original.NumFaces(), welded.NumFaces());
  for (int f = 0; f < original.NumFaces(); ++f)
    for (int i = 0; i < 3; ++i)
      EXPECT_EQ(original.positions.row(original.faces(f, i)),
                welded.positions.row(welded.faces(f, i)))
          << "face " << f << " corner " << i;
}

void ExpectError(const absl::Status& s, const std::vector<std::string>& words) {
  EXPECT_FALSE(s.ok());
  for (const std::string& w : words) EXPECT_THAT(std::string(s.message()), HasSubstr(w)) << s;
}

std::string TempPath(const std::string& name) {
  return absl::StrCat(::testing::TempDir(), "/geomfit_io_", getpid(), "_", name);
}

bool FileExists(const std::string& path) { return access(path.c_str(), F_OK) == 0; }

void AppendLE(std::string* out, uint64_t bits, int n) {
  for (int i = 0; i < n; ++i) out->push_back(static_cast<char>((bits >> (8 * i)) & 0xff));
}
void AppendF32(std::string* out, float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  AppendLE(out, u, 4);
}
void AppendF64(std::string* out, double d) {
  uint64_t u;
  std::memcpy(&u, &d, 8);
  AppendLE(out, u, 8);
}

/// Parses every prefix of `bytes`: no crash, an OK result has consistent shapes, and
/// the whole of `bytes` parses.
void ParseEveryPrefix(const std::string& bytes, MeshFormat format) {
  for (size_t n = 0; n <= bytes.size(); ++n) {
    auto m = ParseMesh(std::string_view(bytes.data(), n), format, "prefix");
    if (m.ok()) {
      EXPECT_EQ(m->positions.cols(), 3);
      EXPECT_EQ(m->faces.cols(), 4);
      // Whatever was parsed must be validated safely too.
      (void)ValidateMesh(*m);
    } else {
      EXPECT_FALSE(m.status().message().empty());
    }
    if (n == bytes.size()) {
      EXPECT_TRUE(m.ok()) << m.status();
    }
  }
}

// ---------------------------------------------------------------------------
// Formats and paths

TEST(FormatTest, FromPathIsCaseInsensitive) {
  EXPECT_EQ(*FormatFromPath("a/b/mesh.obj"), MeshFormat::kObj);
  EXPECT_EQ(*FormatFromPath("MESH.OFF"), MeshFormat::kOff);
  EXPECT_EQ(*FormatFromPath("x.Ply"), MeshFormat::kPly);
  EXPECT_EQ(*FormatFromPath("x.stl"), MeshFormat::kStl);
  EXPECT_EQ(*FormatFromPath("out.vtp"), MeshFormat::kVtp);
  ExpectError(FormatFromPath("mesh.txt").status(), {"mesh.txt", "unknown mesh file extension"});
  ExpectError(FormatFromPath("dir.obj/mesh").status(), {"unknown mesh file extension"});
  ExpectError(FormatFromPath("noext").status(), {"noext"});
}

// ---------------------------------------------------------------------------
// Round trips

class RoundTripTest : public ::testing::TestWithParam<MeshFormat> {};

TEST_P(RoundTripTest, ExactInMemory) {
  for (const Mesh& m : {Tetrahedron(), AwkwardTriangles(), QuadStrip(), Mixed()}) {
    auto bytes = FormatMesh(m, GetParam());
    ASSERT_TRUE(bytes.ok()) << bytes.status();
    auto back = ParseMesh(*bytes, GetParam());
    ASSERT_TRUE(back.ok()) << back.status();
    ExpectSameMesh(m, *back);
  }
}

TEST_P(RoundTripTest, ExactThroughFiles) {
  const std::string path =
      TempPath(absl::StrCat("roundtrip.", absl::AsciiStrToLower(MeshFormatName(GetParam()))));
  const Mesh m = Mixed();
  ASSERT_TRUE(WriteMesh(m, path).ok());
  EXPECT_FALSE(FileExists(path + ".tmp"));
  auto back = ReadMesh(path);
  ASSERT_TRUE(back.ok()) << back.status();
  ExpectSameMesh(m, *back);
  EXPECT_TRUE(ValidateMesh(*back).ok());
  std::remove(path.c_str());
}

INSTANTIATE_TEST_SUITE_P(Formats, RoundTripTest,
                         ::testing::Values(MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly),
                         [](const auto& info) { return std::string(MeshFormatName(info.param)); });

TEST(StlTest, BinaryRoundTripWeldsTetrahedron) {
  const Mesh m = Tetrahedron();
  auto bytes = FormatMesh(m, MeshFormat::kStl);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(bytes->size(), 84u + 50u * 4u);
  auto back = ParseMesh(*bytes, MeshFormat::kStl);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->NumVertices(), 4);
  ExpectSameTriangles(m, *back);
  auto topo = ValidateMesh(*back);
  ASSERT_TRUE(topo.ok()) << topo.status();
  EXPECT_EQ(topo->num_boundary_edges, 0);
}

TEST(StlTest, BinaryWithSolidHeaderIsDetectedBySize) {
  auto bytes = FormatMesh(Tetrahedron(), MeshFormat::kStl);
  ASSERT_TRUE(bytes.ok());
  bytes->replace(0, 11, "solid cube ");  // many exporters do this
  auto back = ParseMesh(*bytes, MeshFormat::kStl);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->NumVertices(), 4);
}

TEST(StlTest, QuadsAreSplit) {
  auto bytes = FormatMesh(QuadStrip(), MeshFormat::kStl);
  ASSERT_TRUE(bytes.ok());
  auto back = ParseMesh(*bytes, MeshFormat::kStl);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->NumFaces(), 4);
  EXPECT_EQ(back->NumVertices(), 6);
  EXPECT_TRUE(ValidateMesh(*back).ok());
}

std::string AsciiStl(const Mesh& m, const std::string& eol) {
  std::string s = "solid tet" + eol;
  for (int f = 0; f < m.NumFaces(); ++f) {
    s += "  facet normal 0 0 0" + eol + "    outer loop" + eol;
    for (int i = 0; i < 3; ++i) {
      const auto p = m.positions.row(m.faces(f, i));
      s += absl::StrCat("      vertex ", p(0), " ", p(1), " ", p(2), eol);
    }
    s += "    endloop" + eol + "  endfacet" + eol;
  }
  return s + "endsolid tet" + eol;
}

TEST(StlTest, AsciiWeldsTetrahedron) {
  for (const std::string eol : {"\n", "\r\n"}) {
    auto back = ParseMesh(AsciiStl(Tetrahedron(), eol), MeshFormat::kStl);
    ASSERT_TRUE(back.ok()) << back.status();
    EXPECT_EQ(back->NumVertices(), 4);
    ExpectSameTriangles(Tetrahedron(), *back);
    EXPECT_TRUE(ValidateMesh(*back).ok());
  }
}

TEST(StlTest, AsciiErrors) {
  const std::string good = AsciiStl(Tetrahedron(), "\n");
  ExpectError(ParseMesh(good.substr(0, good.size() - 13), MeshFormat::kStl).status(),
              {"missing 'endsolid'"});
  ExpectError(ParseMesh(absl::StrReplaceAll(good, {{"vertex 1.5", "vertex abc"}}), MeshFormat::kStl)
                  .status(),
              {"line 5", "'abc' is not a number"});
  std::string four = good;
  four.insert(four.find("    endloop"), "      vertex 9 9 9\n");
  ExpectError(ParseMesh(four, MeshFormat::kStl).status(), {"line 7", "more than 3 vertices"});
  ExpectError(ParseMesh("solid x\n  bogus\nendsolid\n", MeshFormat::kStl).status(),
              {"line 2", "unexpected token 'bogus'"});
  ExpectError(ParseMesh("hello", MeshFormat::kStl).status(), {"not an STL file"});
}

TEST(StlTest, TruncatedBinaryNeverCrashes) {
  auto bytes = FormatMesh(Tetrahedron(), MeshFormat::kStl);
  ASSERT_TRUE(bytes.ok());
  ParseEveryPrefix(*bytes, MeshFormat::kStl);
  ExpectError(ParseMesh(bytes->substr(0, 150), MeshFormat::kStl).status(),
              {"byte 80", "claims 4 triangles", "150 bytes"});
  ParseEveryPrefix(AsciiStl(Tetrahedron(), "\n"), MeshFormat::kStl);
  // A truncated binary STL whose header starts with "solid": both readings explained.
  std::string solid = *bytes;
  solid.replace(0, 6, "solid ");
  ExpectError(ParseMesh(solid.substr(0, 200), MeshFormat::kStl).status(),
              {"line 1", "and as a binary STL", "claims 4 triangles", "200 bytes"});
}

// ---------------------------------------------------------------------------
// OBJ

TEST(ObjTest, SlashesNegativeIndicesAndIgnoredLines) {
  const std::string obj =
      "# a comment\n"
      "mtllib x.mtl\n"
      "o square\n"
      "v 0 0 0\n"
      "v 1 0 0 1.0\n"          // optional w
      "v 1 1 0 0.5 0.5 0.5\n"  // vertex colours
      "v 0 1 0\n"
      "vt 0 0\n"
      "vn 0 0 1\n"
      "usemtl red\n"
      "s off\n"
      "f 1/1/1 2/1/1 3/1/1\n"
      "f -4//1 -2//1 -1//1  # trailing comment\n"
      "g rest\n"
      "l 1 2\n";
  auto m = ParseMesh(obj, MeshFormat::kObj);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->NumVertices(), 4);
  ASSERT_EQ(m->NumFaces(), 2);
  EXPECT_EQ(m->faces.row(0), (Eigen::RowVector4i(0, 1, 2, -1)));
  EXPECT_EQ(m->faces.row(1), (Eigen::RowVector4i(0, 2, 3, -1)));
  EXPECT_TRUE(ValidateMesh(*m).ok());
}

TEST(ObjTest, QuadsWithTextureIndices) {
  auto m =
      ParseMesh("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\r\nf 1/1 2/2 3/3 4/4\r\n", MeshFormat::kObj);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->faces.row(0), (Eigen::RowVector4i(0, 1, 2, 3)));
}

TEST(ObjTest, Errors) {
  const std::string v = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 2 0\n";
  ExpectError(ParseMesh(v + "f 1 2 3 4 5\n", MeshFormat::kObj, "pent.obj").status(),
              {"pent.obj", "line 6", "face 0", "5 vertices", "triangles and quads"});
  ExpectError(ParseMesh(v + "f 1 2\n", MeshFormat::kObj).status(), {"line 6", "2 vertices"});
  ExpectError(ParseMesh("v 1 x 3\n", MeshFormat::kObj).status(), {"line 1", "'x' is not a number"});
  ExpectError(ParseMesh("v 1 2\n", MeshFormat::kObj).status(), {"line 1", "3 coordinates"});
  ExpectError(ParseMesh(v + "f 1 2 b\n", MeshFormat::kObj).status(),
              {"line 6", "'b' is not a vertex index"});
  ExpectError(ParseMesh(v + "f 0 1 2\n", MeshFormat::kObj).status(), {"index 0"});
  ExpectError(ParseMesh(v + "f -1 -2 -9\n", MeshFormat::kObj).status(),
              {"line 6", "before the first vertex"});
  ExpectError(ParseMesh(v + "f 1 2 99999999999\n", MeshFormat::kObj).status(), {"line 6"});
}

// Readers reject out-of-range indices themselves, naming the line (issue 13 item 7);
// ValidateMesh still rejects such a mesh built in memory.
TEST(ObjTest, OutOfRangeIndexIsRejectedWithTheLineAndValidationRejects) {
  auto m = ParseMesh("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 9\n", MeshFormat::kObj, "m.obj");
  EXPECT_EQ(m.status().code(), absl::StatusCode::kInvalidArgument);
  ExpectError(m.status(), {"m.obj: line 4", "face 0", "vertex index 9", "out of range"});
  const Mesh bad = MakeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}}, {{0, 1, 8}});
  ExpectError(ValidateMesh(bad).status(), {"face 0", "out of range"});
}

TEST(ObjTest, NonFiniteCoordinatesPassThroughAndValidationRejects) {
  auto m = ParseMesh("v 0 0 0\nv 1 nan 0\nv 1 1 0\nf 1 2 3\n", MeshFormat::kObj);
  ASSERT_TRUE(m.ok()) << m.status();
  ExpectError(ValidateMesh(*m).status(), {"vertex 1", "not finite"});
}

// The OBJ reader's fast path (plain "v"/"f" lines read straight from the bytes) gives
// the general path's meshes and errors, bit for bit, on lines built from awkward pieces
// (signs, exponents, non-finite and out-of-range numbers, slashes, forward, zero and
// huge indices, comments, CR, tabs, form feeds, missing final newline) and on the
// reader fuzz corpus's mutations.
using TextParser = absl::StatusOr<Mesh> (*)(absl::string_view, absl::string_view, bool);
void ExpectPathsAgree(TextParser parse, const std::string& text) {
  const absl::StatusOr<Mesh> fast = parse(text, "t", true);
  const absl::StatusOr<Mesh> general = parse(text, "t", false);
  ASSERT_EQ(fast.status(), general.status()) << text;
  if (!fast.ok()) return;
  ASSERT_EQ(fast->NumVertices(), general->NumVertices()) << text;
  ASSERT_EQ(fast->faces, general->faces) << text;
  ASSERT_EQ(std::memcmp(fast->positions.data(), general->positions.data(),
                        sizeof(double) * fast->positions.size()),
            0)
      << text;
}

TEST(ObjTest, FastPathReadsLikeTheGeneralPath) {
  const std::vector<std::string> numbers = {
      "0", "1", "-1", "+1", "1.5", "-0", "0.1", "1e5", "1E-5", "1e", "1.", ".5", "-.5", "1e400",
      "-1e400", "1e-400", "inf", "-inf", "nan", "0x10", "1.2999381274644852",
      "-3.1840816777831192e-16", "123456789012345678901234567890", "1x", "--1", "", "#1"};
  const std::vector<std::string> indices = {"1",     "2",   "3",       "4",          "01",
                                            "0",     "-1",  "+2",      "9",          "2147483648",
                                            "0000000001",   "00000000001", "99999999999",
                                            "1/1",   "2//3", "3/4/5",  "1/",         "2/#",
                                            "1a",    "",    "x"};
  const std::vector<std::string> gaps = {" ", "  ", "\t", " \t", "\f", "\v", "\r"};
  const std::vector<std::string> ends = {"\n", "\r\n", " \n", "\t\r\n", "\r", "#c\n", " # c\n",
                                         "\f\n", " 1\n", " x\n", ""};
  std::mt19937_64 rng(7);
  const auto pick = [&](const std::vector<std::string>& v) { return v[rng() % v.size()]; };
  const auto odd = [&] { return rng() % 10 == 0; };  // an awkward piece, else a plain one
  int parsed = 0;
  for (int file = 0; file < 3000; ++file) {
    std::string text = file % 2 == 0 ? "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n" : "";
    for (int line = 0; line < 6; ++line) {
      switch (rng() % 8) {
        case 0: case 1: case 2:
          text += "v";
          for (int c = 0; c < (odd() ? 2 + static_cast<int>(rng() % 3) : 3); ++c)
            text += (odd() ? pick(gaps) : " ") + (odd() ? pick(numbers) : absl::StrCat(rng() % 100 * 0.37));
          break;
        case 3: case 4: case 5:
          text += "f";
          for (int c = 0; c < (odd() ? 2 + static_cast<int>(rng() % 4) : 3 + static_cast<int>(rng() % 2)); ++c)
            text += (odd() ? pick(gaps) : " ") + (odd() ? pick(indices) : absl::StrCat(1 + rng() % 4));
          break;
        case 6: text += pick({"vn 0 0 1", "vt", "# v 1 2 3", "", " v 1 2 3", "v#", "f#1 2 3", "fo 1 2 3",
                              "vv 1 2 3", "\tf 1 2 3", "g", "v1 2 3"});
          break;
        default: text += pick(gaps);
      }
      text += odd() ? pick(ends) : "\n";
    }
    ExpectPathsAgree(mesh_io::ParseObj, text);
    parsed += mesh_io::ParseObj(text, "t.obj").ok();
  }
  EXPECT_GT(parsed, 600);  // both outcomes are exercised
  EXPECT_LT(parsed, 2400);
  std::mt19937_64 mutations(11);
  for (const reader_fuzz::SeedFile& seed : reader_fuzz::SeedFiles())
    for (int i = 0; i < 300; ++i) ExpectPathsAgree(mesh_io::ParseObj, reader_fuzz::Mutate(seed.bytes, mutations));
  ExpectPathsAgree(mesh_io::ParseObj, *FormatMesh(Tetrahedron(), MeshFormat::kObj));
}

// Face lines of spaces and 1-8 digit indices are read from their bytes classified at
// once (PlainFace, 32 bytes at a time): the same faces as the general path for indices
// of 1-10 digits (leading zeros), 2-5 of them, any blanks, LF or CRLF, values in and out
// of range, each line followed by at least 40 bytes or near the end of the text; and
// the expected rows for plain lines (written rows, read back exactly).
TEST(ObjTest, PlainFaceLinesReadLikeTheGeneralPath) {
  std::mt19937_64 rng(13);
  const std::vector<std::string> gaps = {" ", " ", " ", "  ", "\t", " \t "};
  const std::vector<std::string> ends = {"\n", "\n", "\n", "\r\n", " \n", "\n# a comment long enough to pass 40 bytes\n"};
  constexpr int kVertices = 120;
  std::string vertices;
  for (int i = 0; i < kVertices; ++i) vertices += absl::StrCat("v ", i, " ", i % 7, " ", i % 3, "\n");
  int faces_read = 0;
  for (int file = 0; file < 400; ++file) {
    std::string text = vertices, plain = vertices;
    std::vector<std::array<int32_t, 4>> rows;
    for (int line = 0; line < 20; ++line) {
      const int count = rng() % 8 == 0 ? 2 + static_cast<int>(rng() % 4) : 3 + static_cast<int>(rng() % 2);
      text += "f";
      std::array<int32_t, 4> row = {-1, -1, -1, -1};
      for (int c = 0; c < count; ++c) {
        const int index = rng() % 16 == 0 ? kVertices + 1 + static_cast<int>(rng() % 3) : 1 + static_cast<int>(rng() % kVertices);
        const int zeros = rng() % 4 == 0 ? static_cast<int>(rng() % 9) : 0;  // up to 10 digits in all
        text += (rng() % 6 == 0 ? gaps[rng() % gaps.size()] : " ") + std::string(zeros, '0') + std::to_string(index);
        if (count <= 4 && c < 4) row[c] = (c * 37 + line * 11) % kVertices;
      }
      text += rng() % 5 == 0 ? ends[rng() % ends.size()] : "\n";
      if (count >= 3 && count <= 4) {
        plain += "f";
        for (int c = 0; c < count; ++c) plain += absl::StrCat(" ", std::string(c, '0'), row[c] + 1);
        plain += "\n";
        rows.push_back(row);
        if (count == 3) rows.back()[3] = -1;
      }
    }
    ExpectPathsAgree(mesh_io::ParseObj, text);
    const absl::StatusOr<Mesh> m = mesh_io::ParseObj(plain, "p.obj");
    ASSERT_TRUE(m.ok()) << m.status();
    ASSERT_EQ(m->NumFaces(), static_cast<int>(rows.size())) << plain;
    for (int f = 0; f < m->NumFaces(); ++f)
      for (int c = 0; c < 4; ++c) ASSERT_EQ(m->faces(f, c), rows[f][c]) << plain;
    faces_read += m->NumFaces();
    ExpectPathsAgree(mesh_io::ParseObj, plain);
  }
  EXPECT_GT(faces_read, 5000);
}

// The same for OFF's fast path (vertex lines "X Y Z", face lines "N I J K [L]").
TEST(OffTest, FastPathReadsLikeTheGeneralPath) {
  const std::vector<std::string> pieces = {
      "0", "1", "2", "3", "4", "5", "-1", "+1", "1.5", "1e400", "nan", "inf", "03", "0x1", "1x",
      "99999999999", "#", "# c", "", " ", "\t", "\r", "\f", "255 0 0", "1/2"};
  std::mt19937_64 rng(9);
  const auto odd = [&] { return rng() % 20 == 0; };
  const auto pick = [&] { return pieces[rng() % pieces.size()]; };
  int parsed = 0;
  for (int file = 0; file < 3000; ++file) {
    std::string text = "OFF\n4 2 0\n";
    for (int v = 0; v < 4 + (odd() ? 1 : 0); ++v) {
      for (int c = 0; c < (odd() ? 2 + static_cast<int>(rng() % 3) : 3); ++c)
        text += (c > 0 ? (odd() ? pick() + " " : std::string(" ")) : std::string()) +
                (odd() ? pick() : absl::StrCat(rng() % 100 * 0.37));
      text += odd() ? pick() + "\n" : "\n";
    }
    for (int f = 0; f < 2; ++f) {
      const int n = odd() ? static_cast<int>(rng() % 6) : 3 + static_cast<int>(rng() % 2);
      text += odd() ? pick() : absl::StrCat(n);
      for (int c = 0; c < n; ++c) text += (odd() ? pick() + " " : std::string(" ")) + (odd() ? pick() : absl::StrCat(rng() % 4));
      text += odd() ? pick() + (rng() % 2 ? "\r\n" : "\n") : "\n";
    }
    if (odd()) text.pop_back();  // no final newline
    ExpectPathsAgree(mesh_io::ParseOff, text);
    parsed += mesh_io::ParseOff(text, "t.off").ok();
  }
  EXPECT_GT(parsed, 600);  // both outcomes are exercised
  EXPECT_LT(parsed, 2400);
  std::mt19937_64 mutations(13);
  for (const reader_fuzz::SeedFile& seed : reader_fuzz::SeedFiles())
    for (int i = 0; i < 300; ++i) ExpectPathsAgree(mesh_io::ParseOff, reader_fuzz::Mutate(seed.bytes, mutations));
  ExpectPathsAgree(mesh_io::ParseOff, *FormatMesh(Tetrahedron(), MeshFormat::kOff));
}

// ---------------------------------------------------------------------------
// OFF

TEST(OffTest, HeaderVariantsAndComments) {
  const std::string body = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n";
  for (const std::string& text :
       {"OFF\n4 2 0\n" + body, "OFF 4 2 0\n" + body, "4 2 0\n" + body,
        "# comment\nOFF # trailing\n\n# another\n4 2 5\n" + body,
        std::string("COFF\n4 2 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n1 1 0 1 1 1 1\n"
                    "0 1 0 1 1 1 1\n3 0 1 2 255 0 0\n3 0 2 3\n")}) {
    auto m = ParseMesh(text, MeshFormat::kOff);
    ASSERT_TRUE(m.ok()) << m.status() << "\n" << text;
    EXPECT_EQ(m->NumVertices(), 4);
    EXPECT_EQ(m->faces.row(1), (Eigen::RowVector4i(0, 2, 3, -1)));
  }
}

TEST(OffTest, Errors) {
  const std::string v = "OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n";
  ExpectError(ParseMesh(v + "5 0 1 2 3 0\n", MeshFormat::kOff, "m.off").status(),
              {"m.off", "line 7", "face 0 has 5 vertices"});
  ExpectError(ParseMesh(v + "3 0 1\n", MeshFormat::kOff).status(), {"line 7", "needs 3 indices"});
  ExpectError(ParseMesh(v + "3 0 1 x\n", MeshFormat::kOff).status(), {"'x' is not a vertex index"});
  ExpectError(ParseMesh(v, MeshFormat::kOff).status(), {"unexpected end of file", "0 of 1 faces"});
  ExpectError(ParseMesh("OFF\n2 0 0\n0 0 0\n1 zero 0\n", MeshFormat::kOff).status(),
              {"line 4", "'zero' is not a number"});
  ExpectError(ParseMesh("OFF\n-4 1 0\n", MeshFormat::kOff).status(), {"line 2", "bad counts"});
  ExpectError(ParseMesh("OFF\n4000000000 1 0\n0 0 0\n", MeshFormat::kOff).status(),
              {"4000000000 vertices", "bytes"});
  ExpectError(ParseMesh("4OFF\n", MeshFormat::kOff).status(), {"unsupported OFF variant"});
  ExpectError(ParseMesh("", MeshFormat::kOff).status(), {"empty file"});
}

TEST(OffTest, OutOfRangeIndexIsRejectedWithTheLineAndValidationRejects) {
  auto m = ParseMesh("OFF\n3 1 0\n0 0 0\n1 0 0\n1 1 0\n3 0 1 -7\n", MeshFormat::kOff, "m.off");
  EXPECT_EQ(m.status().code(), absl::StatusCode::kInvalidArgument);
  ExpectError(m.status(), {"m.off: line 6", "face 0", "-7", "out of range"});
  const Mesh bad = MakeMesh({{0, 0, 0}, {1, 0, 0}, {1, 1, 0}}, {{0, 1, -7}});
  ExpectError(ValidateMesh(bad).status(), {"face 0", "-7", "out of range"});
}

TEST(OffTest, EveryPrefixIsSafe) {
  auto bytes = FormatMesh(Mixed(), MeshFormat::kOff);
  ASSERT_TRUE(bytes.ok());
  ParseEveryPrefix(*bytes, MeshFormat::kOff);
  auto obj = FormatMesh(Mixed(), MeshFormat::kObj);
  ParseEveryPrefix(*obj, MeshFormat::kObj);
}

// ---------------------------------------------------------------------------
// PLY

TEST(PlyTest, AsciiWithExtraPropertiesAndElements) {
  const std::string ply =
      "ply\r\n"
      "format ascii 1.0\r\n"
      "comment made by hand\r\n"
      "element vertex 4\r\n"
      "property float x\r\n"
      "property uchar red\r\n"
      "property float y\r\n"
      "property list uchar int extra\r\n"
      "property double z\r\n"
      "element face 2\r\n"
      "property uchar flags\r\n"
      "property list int uint vertex_index\r\n"
      "element edge 1\r\n"
      "property int vertex1\r\n"
      "property int vertex2\r\n"
      "end_header\r\n"
      "0 255 0 2 7 8 0\r\n"
      "1 0 0 0 0\r\n"
      "1 0 1 1 5 0\r\n"
      "0 0 1 0 0\r\n"
      "1 3 0 1 2\r\n"
      "0 3 0 2 3\r\n"
      "0 1\r\n";
  auto m = ParseMesh(ply, MeshFormat::kPly);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(m->NumVertices(), 4);
  EXPECT_EQ(m->positions.row(2), (Eigen::RowVector3d(1, 1, 0)));
  EXPECT_EQ(m->faces.row(1), (Eigen::RowVector4i(0, 2, 3, -1)));
}

/// A binary PLY with float coordinates between other properties, uint indices with
/// int counts, and an extra element with a list (all to be skipped by type).
std::string BinaryPly(const Mesh& m) {
  std::string s = absl::StrCat(
      "ply\nformat binary_little_endian 1.0\nelement vertex ", m.NumVertices(),
      "\nproperty short id\nproperty float x\nproperty float y\nproperty float z\n"
      "property double quality\nelement face ",
      m.NumFaces(),
      "\nproperty list int uint vertex_indices\nproperty float area\n"
      "element material 1\nproperty list ushort char name\nproperty uchar r\nend_header\n");
  for (int v = 0; v < m.NumVertices(); ++v) {
    AppendLE(&s, static_cast<uint16_t>(-v), 2);
    for (int c = 0; c < 3; ++c) AppendF32(&s, static_cast<float>(m.positions(v, c)));
    AppendF64(&s, 0.5 * v);
  }
  for (int f = 0; f < m.NumFaces(); ++f) {
    AppendLE(&s, m.FaceSize(f), 4);
    for (int i = 0; i < m.FaceSize(f); ++i) AppendLE(&s, m.faces(f, i), 4);
    AppendF32(&s, 1.0f);
  }
  AppendLE(&s, 3, 2);
  s += "abc";
  s += '\x07';
  return s;
}

TEST(PlyTest, BinaryWithExtraPropertiesSkippedByType) {
  const Mesh m = Mixed();
  auto back = ParseMesh(BinaryPly(m), MeshFormat::kPly);
  ASSERT_TRUE(back.ok()) << back.status();
  ExpectSameMesh(m, *back);  // all coordinates are floats
}

TEST(PlyTest, TruncatedBinaryNeverCrashes) {
  auto ours = FormatMesh(Mixed(), MeshFormat::kPly);
  ASSERT_TRUE(ours.ok());
  ParseEveryPrefix(*ours, MeshFormat::kPly);
  ParseEveryPrefix(BinaryPly(Mixed()), MeshFormat::kPly);
  const std::string& full = *ours;
  const size_t data = full.find("end_header\n") + 11;
  ExpectError(ParseMesh(full.substr(0, data + 30), MeshFormat::kPly, "t.ply").status(),
              {"t.ply", "6 'vertex' elements", "30 bytes"});
  ExpectError(ParseMesh(full.substr(0, full.size() - 1), MeshFormat::kPly, "t.ply").status(),
              {"t.ply", "byte 363", "bad list length 3", "face"});
  const std::string theirs = BinaryPly(Mixed());  // each face ends with a float
  ExpectError(ParseMesh(theirs.substr(0, theirs.size() - 10), MeshFormat::kPly).status(),
              {"byte", "unexpected end of data"});
}

TEST(PlyTest, TruncatedAsciiNeverCrashes) {
  auto ours = FormatMesh(Mixed(), MeshFormat::kPly);
  ASSERT_TRUE(ours.ok());
  std::string ascii = absl::StrReplaceAll(ours->substr(0, ours->find("end_header\n") + 11),
                                          {{"binary_little_endian", "ascii"}});
  ascii += "0 0 0\n1 0 0.125\n2 0 0\n0 1 0\n1 1 -0.5\n2 1 0\n4 0 1 4 3\n3 1 2 5\n3 1 5 4\n";
  auto m = ParseMesh(ascii, MeshFormat::kPly);
  ASSERT_TRUE(m.ok()) << m.status();
  ExpectSameMesh(Mixed(), *m);
  ParseEveryPrefix(ascii, MeshFormat::kPly);
}

TEST(PlyTest, HugeCountsAreRejectedBeforeAllocating) {
  for (const std::string format : {"ascii", "binary_little_endian"}) {
    const std::string ply = "ply\nformat " + format +
                            " 1.0\nelement vertex 4000000000\nproperty float x\n"
                            "property float y\nproperty float z\nend_header\n0 0 0\n";
    ExpectError(ParseMesh(ply, MeshFormat::kPly, "huge.ply").status(),
                {"huge.ply", "4000000000", "bytes"});
  }
  // A list length beyond the data.
  std::string ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n"
      "property float y\nproperty float z\nelement junk 1\nproperty list int int v\nend_header\n";
  AppendLE(&ply, 1u << 30, 4);
  ExpectError(ParseMesh(ply, MeshFormat::kPly).status(), {"bad list length"});
}

TEST(PlyTest, Errors) {
  const std::string head =
      "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n1 1 0\n0 1 0\n0 2 0\n";
  ExpectError(ParseMesh(head + "5 0 1 2 3 4\n", MeshFormat::kPly, "p.ply").status(),
              {"p.ply", "line 15", "face 0 has 5 vertices"});
  ExpectError(ParseMesh(head + "3 0 1 q\n", MeshFormat::kPly).status(),
              {"line 15", "'q' is not a number"});
  ExpectError(ParseMesh(head + "3 0 1\n", MeshFormat::kPly).status(),
              {"line 15", "bad list length 3", "at most 2"});
  ExpectError(
      ParseMesh(absl::StrReplaceAll(head, {{"0 2 0\n", "0 2\n"}}) + "3 0 1 2\n", MeshFormat::kPly)
          .status(),
      {"line 14", "too few values"});
  ExpectError(ParseMesh(head + "3 0 1 2.5\n", MeshFormat::kPly).status(), {"not an int32"});
  ExpectError(
      ParseMesh(absl::StrReplaceAll(head, {{"ascii", "binary_big_endian"}}), MeshFormat::kPly)
          .status(),
      {"line 2", "binary_big_endian", "not supported"});
  ExpectError(ParseMesh(absl::StrReplaceAll(head, {{"property float y\n", ""}}) + "3 0 1 2\n",
                        MeshFormat::kPly)
                  .status(),
              {"no scalar property 'y'"});
  ExpectError(ParseMesh(absl::StrReplaceAll(head, {{"vertex_indices", "corners"}}) + "3 0 1 2\n",
                        MeshFormat::kPly)
                  .status(),
              {"vertex_indices"});
  ExpectError(ParseMesh("ply\nformat ascii 1.0\nelement vertex 1\n", MeshFormat::kPly).status(),
              {"end_header"});
  ExpectError(ParseMesh("plx\n", MeshFormat::kPly).status(), {"line 1", "'ply'"});
  ExpectError(ParseMesh("ply\nformat ascii 1.0\nelement vertex -3\nend_header\n", MeshFormat::kPly)
                  .status(),
              {"line 3", "bad count"});
  ExpectError(
      ParseMesh("ply\nformat ascii 1.0\nproperty float x\nend_header\n", MeshFormat::kPly).status(),
      {"before any 'element'"});
  ExpectError(ParseMesh("ply\nformat ascii 1.0\nelement vertex 1\nproperty float128 x\n"
                        "end_header\n",
                        MeshFormat::kPly)
                  .status(),
              {"line 4", "malformed 'property'"});
}

TEST(PlyTest, UnsignedIndexBeyondInt32IsRejected) {
  std::string ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1\n"
      "property list uchar uint vertex_indices\nend_header\n";
  ply += '\x03';
  AppendLE(&ply, 0, 4);
  AppendLE(&ply, 1, 4);
  AppendLE(&ply, 4000000000u, 4);
  ExpectError(ParseMesh(ply, MeshFormat::kPly).status(), {"face 0", "4e+09", "not an int32"});
}

// ---------------------------------------------------------------------------
// Garbage

TEST(GarbageTest, RandomBytesNeverCrashAndNeverValidate) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 200; ++trial) {
    std::string bytes(rng() % 600, '\0');
    for (char& c : bytes) c = static_cast<char>(rng());
    if (trial % 4 == 1) bytes = "ply\nformat binary_little_endian 1.0\n" + bytes;
    if (trial % 4 == 2) bytes = "OFF\n3 1 0\n" + bytes;
    for (MeshFormat f : {MeshFormat::kObj, MeshFormat::kOff, MeshFormat::kPly, MeshFormat::kStl}) {
      auto m = ParseMesh(bytes, f);
      if (m.ok()) {
        EXPECT_FALSE(ValidateMesh(*m).ok()) << MeshFormatName(f) << " trial " << trial;
      }
    }
  }
}

/// Deterministic mutation fuzzing of valid files: flipped bytes, digits written over
/// counts, deleted and repeated chunks. Nothing may crash (run under ASan/UBSan too).
TEST(GarbageTest, MutatedFilesNeverCrash) {
  std::vector<std::pair<std::string, MeshFormat>> seeds = {
      {*FormatMesh(Mixed(), MeshFormat::kPly), MeshFormat::kPly},
      {BinaryPly(Mixed()), MeshFormat::kPly},
      {*FormatMesh(Tetrahedron(), MeshFormat::kStl), MeshFormat::kStl},
      {AsciiStl(Tetrahedron(), "\n"), MeshFormat::kStl},
      {*FormatMesh(Mixed(), MeshFormat::kObj), MeshFormat::kObj},
      {*FormatMesh(Mixed(), MeshFormat::kOff), MeshFormat::kOff}};
  std::string ascii_ply = *FormatMesh(Mixed(), MeshFormat::kPly);
  ascii_ply = absl::StrReplaceAll(ascii_ply.substr(0, ascii_ply.find("end_header\n") + 11),
                                  {{"binary_little_endian", "ascii"}}) +
              "0 0 0\n1 0 0\n2 0 0\n0 1 0\n1 1 0\n2 1 0\n4 0 1 4 3\n3 1 2 5\n3 1 5 4\n";
  seeds.emplace_back(ascii_ply, MeshFormat::kPly);
  std::mt19937 rng(11);
  int parsed = 0;
  for (const auto& [seed, format] : seeds) {
    for (int trial = 0; trial < 1500; ++trial) {
      std::string b = seed;
      for (int k = 1 + rng() % 3; k > 0 && !b.empty(); --k) {
        const size_t at = rng() % b.size();
        switch (rng() % 5) {
          case 0: b[at] = static_cast<char>(rng()); break;
          case 1: b[at] = "0123456789-"[rng() % 11]; break;
          case 2: b.insert(at, std::string(1 + rng() % 4, "9\xff\n "[rng() % 4])); break;
          case 3: b.erase(at, 1 + rng() % 8); break;
          case 4: b.insert(at, b.substr(at, 1 + rng() % 16)); break;
        }
      }
      auto m = ParseMesh(b, format);
      if (!m.ok()) continue;
      ++parsed;
      EXPECT_EQ(m->positions.cols(), 3);
      EXPECT_EQ(m->faces.cols(), 4);
      (void)ValidateMesh(*m);
    }
  }
  EXPECT_GT(parsed, 0);  // some mutations (e.g. of coordinates) still parse
}

// ---------------------------------------------------------------------------
// Files

TEST(FileTest, ErrorsNameThePath) {
  const std::string missing = TempPath("does_not_exist.obj");
  auto m = ReadMesh(missing);
  EXPECT_EQ(m.status().code(), absl::StatusCode::kNotFound);
  ExpectError(m.status(), {missing, "No such file"});
  ExpectError(ReadMesh(TempPath("x.vtp")).status(), {"not supported"});
  ExpectError(ReadMesh(TempPath("x.abc")).status(), {"unknown mesh file extension"});

  const std::string bad_dir = TempPath("no_such_dir/out.ply");
  ExpectError(WriteMesh(Mixed(), bad_dir), {bad_dir, "No such file"});
  EXPECT_FALSE(FileExists(bad_dir + ".tmp"));
}

TEST(FileTest, ParseErrorsNameTheFile) {
  const std::string path = TempPath("pentagon.obj");
  ASSERT_TRUE(WriteFileAtomically(path,
                                  "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 2 0\n"
                                  "f 1 2 3 4 5\n")
                  .ok());
  ExpectError(ReadMesh(path).status(), {path + ": line 6", "5 vertices"});
  std::remove(path.c_str());
}

TEST(FileTest, AtomicWriteReplacesExistingFile) {
  const std::string path = TempPath("atomic.txt");
  ASSERT_TRUE(WriteFileAtomically(path, "first").ok());
  ASSERT_TRUE(WriteFileAtomically(path, "second").ok());
  EXPECT_EQ(*ReadFileToString(path), "second");
  EXPECT_FALSE(FileExists(path + ".tmp"));
  std::remove(path.c_str());
}

// ReadFileBytes: a regular file in one read of its size; a pipe (size unknown) in
// doubling blocks from 64 KB, here 300,001 bytes (five blocks), byte for byte.
TEST(FileTest, ReadFileBytesReadsRegularFilesAndPipesWhole) {
  std::string text(300001, '\0');
  for (size_t i = 0; i < text.size(); ++i) text[i] = static_cast<char>('a' + (i * 7919) % 26);
  const std::string path = TempPath("bytes.txt");
  ASSERT_TRUE(WriteFileAtomically(path, text).ok());
  absl::StatusOr<FileBytes> file = ReadFileBytes(path);
  ASSERT_TRUE(file.ok()) << file.status();
  EXPECT_EQ(file->view(), text);
  EXPECT_EQ(*ReadFileToString(path), text);
  std::remove(path.c_str());

  int fds[2];
  ASSERT_EQ(pipe(fds), 0);
  std::thread writer([&] {
    size_t done = 0;
    while (done < text.size()) {
      const ssize_t n = write(fds[1], text.data() + done, text.size() - done);
      if (n <= 0) break;
      done += static_cast<size_t>(n);
    }
    close(fds[1]);
  });
  absl::StatusOr<FileBytes> piped = ReadFileBytes("/dev/fd/" + std::to_string(fds[0]));
  writer.join();
  close(fds[0]);
  ASSERT_TRUE(piped.ok()) << piped.status();
  EXPECT_EQ(piped->view(), text);

  EXPECT_EQ(ReadFileBytes(TempPath("missing.txt")).status().code(), absl::StatusCode::kNotFound);
}

// ---------------------------------------------------------------------------
// VTP

std::vector<PointField> SampleFields(int nv) {
  std::vector<PointField> fields(3);
  fields[0] = {"Mean & \"Curvature\"", Eigen::MatrixXd(nv, 1)};
  fields[1] = {"Normals", Eigen::MatrixXd(nv, 3)};
  fields[2] = {"CurvatureTensor", Eigen::MatrixXd(nv, 9)};
  for (auto& f : fields)
    for (int r = 0; r < nv; ++r)
      for (int c = 0; c < f.values.cols(); ++c) f.values(r, c) = 0.1 * r + c / 3.0;
  return fields;
}

TEST(VtpTest, StructureAndCounts) {
  const Mesh m = Mixed();
  auto xml = FormatVtp(m, SampleFields(m.NumVertices()));
  ASSERT_TRUE(xml.ok()) << xml.status();
  for (const char* s :
       {"<?xml version=\"1.0\"?>",
        "<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">", "<PolyData>",
        "<Piece NumberOfPoints=\"6\" NumberOfVerts=\"0\" NumberOfLines=\"0\" "
        "NumberOfStrips=\"0\" NumberOfPolys=\"3\">",
        "<PointData>", "Name=\"Mean &amp; &quot;Curvature&quot;\" NumberOfComponents=\"1\"",
        "Name=\"Normals\" NumberOfComponents=\"3\"",
        "Name=\"CurvatureTensor\" NumberOfComponents=\"9\"", "<Points>",
        "<DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">", "  0 1 4 3\n",
        "  1 2 5\n", "<DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">", "4 7 10\n",
        "</Polys>", "</Piece>", "</PolyData>", "</VTKFile>"})
    EXPECT_THAT(*xml, HasSubstr(s));
  EXPECT_THAT(*xml, ::testing::Not(HasSubstr("format=\"binary\"")));
  EXPECT_THAT(*xml, HasSubstr(" 0.33333333333333331 "));  // %.17g

  std::vector<PointField> bad = {{"short", Eigen::MatrixXd::Zero(2, 1)}};
  ExpectError(FormatVtp(m, bad).status(), {"short", "6 rows"});
  ExpectError(WriteVtp(TempPath("bad.vtp"), m, bad), {"bad.vtp", "short"});
}

TEST(VtpTest, NonFiniteArraysAreWrittenAsBase64) {
  const Mesh m = Mixed();
  std::vector<PointField> fields = {{"H", Eigen::MatrixXd::Zero(6, 1)}};
  fields[0].values(4, 0) = std::numeric_limits<double>::quiet_NaN();
  auto xml = FormatVtp(m, fields);
  ASSERT_TRUE(xml.ok());
  EXPECT_THAT(*xml, HasSubstr("Name=\"H\" NumberOfComponents=\"1\" format=\"binary\""));
  // UInt32 header 48 bytes, base64 on its own: "MAAAAA==".
  EXPECT_THAT(*xml, HasSubstr("MAAAAA=="));
}

/// Parses the file back with Python's XML parser (Debian's /usr/bin/python3).
TEST(VtpTest, PythonXmlParsesItBack) {
  const Mesh m = Mixed();
  std::vector<PointField> fields = SampleFields(m.NumVertices());
  fields.push_back({"WithNaN", Eigen::MatrixXd::Ones(6, 1)});
  fields.back().values(2, 0) = std::numeric_limits<double>::quiet_NaN();
  const std::string vtp = TempPath("check.vtp"), py = TempPath("check.py");
  ASSERT_TRUE(WriteVtp(vtp, m, fields).ok());
  ASSERT_TRUE(WriteFileAtomically(py, R"PY(
import base64, math, struct, sys
import xml.etree.ElementTree as ET
root = ET.parse(sys.argv[1]).getroot()
assert root.tag == "VTKFile" and root.get("type") == "PolyData", root.tag
piece = root.find("PolyData/Piece")
npts, npolys = int(piece.get("NumberOfPoints")), int(piece.get("NumberOfPolys"))
assert (npts, npolys) == (6, 3), (npts, npolys)
def values(a):
    if a.get("format") == "ascii":
        return [float(x) for x in a.text.split()]
    raw = "".join(a.text.split())
    nbytes = struct.unpack("<I", base64.b64decode(raw[:8]))[0]
    data = base64.b64decode(raw[8:])
    assert len(data) == nbytes
    return list(struct.unpack("<%dd" % (nbytes // 8), data))
pts = piece.find("Points/DataArray")
assert len(values(pts)) == 3 * npts
conn = [int(x) for x in piece.find("Polys/DataArray[@Name='connectivity']").text.split()]
offs = [int(x) for x in piece.find("Polys/DataArray[@Name='offsets']").text.split()]
assert len(offs) == npolys and offs[-1] == len(conn) == 10, (offs, conn)
arrays = {a.get("Name"): a for a in piece.find("PointData")}
assert set(arrays) == {'Mean & "Curvature"', "Normals", "CurvatureTensor", "WithNaN"}, arrays
for a in arrays.values():
    assert len(values(a)) == npts * int(a.get("NumberOfComponents")), a.get("Name")
w = values(arrays["WithNaN"])
assert math.isnan(w[2]) and w[0] == 1.0, w
print("ok")
)PY")
                  .ok());
  EXPECT_EQ(std::system(("/usr/bin/python3 " + py + " " + vtp).c_str()), 0);
  std::remove(vtp.c_str());
  std::remove(py.c_str());
}

// ---------------------------------------------------------------------------
// NPY

TEST(NpyTest, HeaderAndData) {
  RowMajorMatrixXd a(3, 2);
  a << 1, 2, 3.5, -4, 1e-300, std::numeric_limits<double>::quiet_NaN();
  const std::string path = TempPath("a.npy");
  ASSERT_TRUE(WriteNpy(path, a).ok());
  auto bytes = ReadFileToString(path);
  ASSERT_TRUE(bytes.ok());
  ASSERT_GE(bytes->size(), 10u);
  EXPECT_EQ(bytes->substr(0, 8), std::string("\x93NUMPY\x01\x00", 8));
  const size_t header_len = static_cast<uint8_t>((*bytes)[8]) | static_cast<uint8_t>((*bytes)[9])
                                                                    << 8;
  EXPECT_EQ((10 + header_len) % 64, 0u);
  const std::string header = bytes->substr(10, header_len);
  EXPECT_EQ(header.back(), '\n');
  EXPECT_THAT(header, HasSubstr("'descr': '<f8'"));
  EXPECT_THAT(header, HasSubstr("'fortran_order': False"));
  EXPECT_THAT(header, HasSubstr("'shape': (3, 2)"));
  ASSERT_EQ(bytes->size(), 10 + header_len + 6 * 8);
  for (int i = 0; i < 6; ++i) {
    double d;
    std::memcpy(&d, bytes->data() + 10 + header_len + 8 * i, 8);
    const double want = a(i / 2, i % 2);
    if (std::isnan(want))
      EXPECT_TRUE(std::isnan(d));
    else
      EXPECT_EQ(d, want) << i;
  }
  std::remove(path.c_str());
}

// Written in blocks of rows (a 5000 x 13 table: several blocks, the last one partial),
// the file holds FormatNpy's bytes; an empty table and a table without columns too.
TEST(NpyTest, BlockWritesEqualFormatNpy) {
  for (const auto& [rows, cols] : {std::pair{5000, 13}, std::pair{0, 3}, std::pair{4, 0}, std::pair{1, 1}}) {
    RowMajorMatrixXd a(rows, cols);
    for (int i = 0; i < a.size(); ++i) a.data()[i] = std::sin(1.0 + i) * std::pow(10.0, i % 40 - 20);
    const std::string path = TempPath("blocks.npy");
    ASSERT_TRUE(WriteNpy(path, a).ok());
    auto bytes = ReadFileToString(path);
    ASSERT_TRUE(bytes.ok());
    EXPECT_TRUE(*bytes == FormatNpy(a)) << rows << " x " << cols;
    std::remove(path.c_str());
  }
  const std::string missing = TempPath("no_such_dir/x.npy");
  ExpectError(WriteNpy(missing, RowMajorMatrixXd(2, 2)), {"cannot write", "x.npy"});
}

TEST(NpyTest, NumpyLoadsIt) {
  // Debian's python3-numpy (installed by scripts/install-deps.sh) is for /usr/bin/python3.
  RowMajorMatrixXd a(2, 3);
  a << 1, 2, 3, 4, 5, 6.25;
  const std::string path = TempPath("b.npy");
  ASSERT_TRUE(WriteNpy(path, a).ok());
  const std::string cmd =
      "/usr/bin/python3 -c 'import numpy, sys; a = numpy.load(sys.argv[1]); "
      "assert a.shape == (2, 3) and a.dtype == numpy.float64 and "
      "a[1, 2] == 6.25 and a[0, 1] == 2, a' " +
      path;
  EXPECT_EQ(std::system(cmd.c_str()), 0);
  std::remove(path.c_str());
}

}  // namespace
}  // namespace geomfit
