// VTK XML writers: binary appended layout, .vtu cells, integer arrays, active
// attributes. (VTK's and meshio's readers check the files in tests/python.)
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "core/mesh/io.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/mesh/make_mesh.h"

namespace geomfit {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;
using testing_util::MakeMesh;

Mesh Mixed() {
  return MakeMesh({{0, 0, 0}, {1, 0, 0.125}, {2, 0, 0}, {0, 1, 0}, {1, 1, -0.5}, {2, 1, 0}},
                  {{0, 1, 4, 3}, {1, 2, 5}, {1, 5, 4}});
}

std::vector<PointField> Fields() {
  std::vector<PointField> f = {{"H", Eigen::MatrixXd(6, 1), VtkType::kFloat64},
                               {"Normals", Eigen::MatrixXd(6, 3), VtkType::kFloat64},
                               {"DegreeUsed", Eigen::MatrixXd(6, 1), VtkType::kInt32},
                               {"Flags", Eigen::MatrixXd(6, 1), VtkType::kUInt8}};
  for (int v = 0; v < 6; ++v) {
    f[0].values(v, 0) = 0.1 * v;
    f[1].values.row(v) << 0, 0, v;
    f[2].values(v, 0) = v - 2;
    f[3].values(v, 0) = 250 + v % 6;
  }
  f[0].values(3, 0) = std::numeric_limits<double>::quiet_NaN();  // raw bits in binary
  return f;
}

/// The appended block of a binary file, and the (offset -> bytes) of one array.
struct Appended {
  std::string xml, data;
  explicit Appended(const std::string& file) {
    const size_t start = file.find("<AppendedData encoding=\"raw\">");
    EXPECT_NE(start, std::string::npos);
    xml = file.substr(0, start);
    const size_t underscore = file.find('_', start);
    const size_t end = file.rfind("\n  </AppendedData>");
    data = file.substr(underscore + 1, end - underscore - 1);
  }
  /// Bytes of the array named `name` (its UInt64 size header checked).
  std::string Array(const std::string& name) const {
    const size_t at = xml.find("Name=\"" + name + "\"");
    EXPECT_NE(at, std::string::npos) << name;
    const size_t off_at = xml.find("offset=\"", at) + 8;
    const uint64_t offset = std::stoull(xml.substr(off_at, xml.find('"', off_at) - off_at));
    uint64_t size;
    std::memcpy(&size, data.data() + offset, 8);
    EXPECT_LE(offset + 8 + size, data.size()) << name;
    return data.substr(offset + 8, size);
  }
};

template <typename T>
std::vector<T> As(const std::string& bytes) {
  std::vector<T> out(bytes.size() / sizeof(T));
  std::memcpy(out.data(), bytes.data(), out.size() * sizeof(T));
  return out;
}

TEST(VtkTest, BinaryAppendedVtpHoldsEveryArrayBitExact) {
  VtkOptions o;
  o.normals = "Normals";
  o.scalars = "H";
  auto file = FormatVtp(Mixed(), Fields(), o);
  ASSERT_TRUE(file.ok()) << file.status();
  const Appended a(*file);
  EXPECT_THAT(a.xml, HasSubstr("<VTKFile type=\"PolyData\" version=\"1.0\" "
                               "byte_order=\"LittleEndian\" header_type=\"UInt64\">"));
  EXPECT_THAT(a.xml, HasSubstr("<PointData Normals=\"Normals\" Scalars=\"H\">"));
  EXPECT_THAT(a.xml, Not(HasSubstr("format=\"ascii\"")));
  EXPECT_THAT(a.xml, HasSubstr("type=\"Int32\" Name=\"DegreeUsed\" NumberOfComponents=\"1\""));
  EXPECT_THAT(a.xml, HasSubstr("type=\"UInt8\" Name=\"Flags\" NumberOfComponents=\"1\""));
  EXPECT_THAT(a.xml, HasSubstr("type=\"Int64\" Name=\"offsets\""));

  const std::vector<double> h = As<double>(a.Array("H"));
  ASSERT_EQ(h.size(), 6u);
  EXPECT_EQ(h[5], 0.5);
  EXPECT_TRUE(std::isnan(h[3]));
  EXPECT_EQ(As<double>(a.Array("Normals"))[3 * 4 + 2], 4.0);
  EXPECT_EQ(As<int32_t>(a.Array("DegreeUsed")), (std::vector<int32_t>{-2, -1, 0, 1, 2, 3}));
  EXPECT_EQ(As<uint8_t>(a.Array("Flags")), (std::vector<uint8_t>{250, 251, 252, 253, 254, 255}));
  const std::vector<double> p = As<double>(a.Array("Points"));
  EXPECT_EQ(p.size(), 18u);
  EXPECT_EQ(p[3 * 4 + 2], -0.5);
  EXPECT_EQ(As<int32_t>(a.Array("connectivity")),
            (std::vector<int32_t>{0, 1, 4, 3, 1, 2, 5, 1, 5, 4}));
  EXPECT_EQ(As<int64_t>(a.Array("offsets")), (std::vector<int64_t>{4, 7, 10}));
  // Blocks are laid out last array first (meshio looks offsets up by value).
  EXPECT_THAT(a.xml, HasSubstr("Name=\"offsets\" format=\"appended\" offset=\"0\""));
}

TEST(VtkTest, VtuHasCellTypes) {
  auto file = FormatVtu(Mixed(), {}, VtkOptions{});
  ASSERT_TRUE(file.ok()) << file.status();
  const Appended a(*file);
  EXPECT_THAT(a.xml, HasSubstr("<VTKFile type=\"UnstructuredGrid\""));
  EXPECT_THAT(a.xml, HasSubstr("<Piece NumberOfPoints=\"6\" NumberOfCells=\"3\">"));
  EXPECT_EQ(As<uint8_t>(a.Array("types")), (std::vector<uint8_t>{9, 5, 5}));  // quad, triangles
  EXPECT_EQ(As<int64_t>(a.Array("offsets")), (std::vector<int64_t>{4, 7, 10}));

  VtkOptions text;
  text.encoding = VtkEncoding::kAscii;
  auto ascii = FormatVtu(Mixed(), {}, text);
  ASSERT_TRUE(ascii.ok());
  EXPECT_THAT(*ascii, HasSubstr("<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n"
                                "          9 5 5\n"));
  EXPECT_THAT(*ascii, HasSubstr("<Cells>"));
  EXPECT_THAT(*ascii, Not(HasSubstr("AppendedData")));
}

TEST(VtkTest, AsciiIntegerArraysAreIntegers) {
  VtkOptions text;
  text.encoding = VtkEncoding::kAscii;
  std::vector<PointField> f = Fields();
  f[0].values(3, 0) = 1.0;
  auto xml = FormatVtp(Mixed(), f, text);
  ASSERT_TRUE(xml.ok());
  EXPECT_THAT(*xml, HasSubstr("Name=\"DegreeUsed\" NumberOfComponents=\"1\" format=\"ascii\">\n"
                              "          -2\n          -1\n"));
  EXPECT_THAT(*xml, HasSubstr("          255\n"));
}

TEST(VtkTest, BadFieldsAndAttributesAreRefused) {
  std::vector<PointField> f = Fields();
  f[3].values(2, 0) = 256;
  EXPECT_THAT(std::string(FormatVtp(Mixed(), f, VtkOptions{}).status().message()),
              HasSubstr("'Flags': value 256 at vertex 2 is not representable as UInt8"));
  f = Fields();
  f[2].values(1, 0) = 2.5;
  EXPECT_THAT(std::string(FormatVtu(Mixed(), f).status().message()),
              HasSubstr("'DegreeUsed': value 2.5 at vertex 1 is not representable as Int32"));
  VtkOptions o;
  o.normals = "H";  // one component
  EXPECT_THAT(std::string(FormatVtp(Mixed(), Fields(), o).status().message()),
              HasSubstr("active normals 'H'"));
  o.normals.clear();
  o.scalars = "missing";
  EXPECT_EQ(FormatVtu(Mixed(), Fields(), o).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST(VtkTest, VtuIsAnOutputFormat) {
  EXPECT_EQ(*FormatFromPath("a/b.VTU"), MeshFormat::kVtu);
  EXPECT_TRUE(IsOutputOnly(MeshFormat::kVtu));
  EXPECT_FALSE(IsOutputOnly(MeshFormat::kPly));
  EXPECT_THAT(std::string(ParseMesh("x", MeshFormat::kVtu, "in.vtu").status().message()),
              HasSubstr("in.vtu: reading VTU is not supported"));
  auto bytes = FormatMesh(Mixed(), MeshFormat::kVtu);  // binary appended by default
  ASSERT_TRUE(bytes.ok());
  EXPECT_THAT(*bytes, HasSubstr("<AppendedData encoding=\"raw\">"));
}

}  // namespace
}  // namespace geomfit

namespace geomfit {
namespace {

TEST(VtkTest, GeneralCellsAreChecked) {
  Positions p(3, 3);
  p << 0, 0, 0, 1, 0, 0, 0, 1, 0;
  VtkCells cells;
  cells.connectivity = {0, 1, 2};
  cells.offsets.push_back(3);
  cells.types = {5};
  auto ok = FormatVtu(p, cells, {});
  ASSERT_TRUE(ok.ok()) << ok.status();
  EXPECT_THAT(*ok, HasSubstr("NumberOfCells=\"1\""));
  cells.connectivity[2] = 3;
  EXPECT_THAT(std::string(FormatVtu(p, cells, {}).status().message()),
              HasSubstr("cell 0: point 3 is out of range [0, 3)"));
  cells.connectivity[2] = 2;
  cells.types.push_back(5);
  EXPECT_THAT(std::string(FormatVtu(p, cells, {}).status().message()),
              HasSubstr("2 types, 2 offsets and 3 point ids do not match"));
  EXPECT_THAT(std::string(WriteVtu("/nonexistent/x.vtu", p, cells, {}).message()),
              HasSubstr("/nonexistent/x.vtu: cells:"));
}

}  // namespace
}  // namespace geomfit
