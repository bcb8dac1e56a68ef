// VTK XML output: PolyData (.vtp) and UnstructuredGrid (.vtu), ASCII or binary appended
// (raw or zlib-compressed).
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/io.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

using mesh_io::PutDouble;
using mesh_io::PutLE;

constexpr uint8_t kVtkTriangle = 5, kVtkQuad = 9;

std::string Base64(absl::string_view in) {
  static constexpr char kChars[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  for (size_t i = 0; i < in.size(); i += 3) {
    uint32_t w = 0;
    const size_t n = std::min<size_t>(3, in.size() - i);
    for (size_t k = 0; k < n; ++k)
      w |= static_cast<uint32_t>(static_cast<uint8_t>(in[i + k])) << (16 - 8 * k);
    for (size_t k = 0; k < 4; ++k) out += k <= n ? kChars[(w >> (18 - 6 * k)) & 63] : '=';
  }
  return out;
}

std::string XmlEscape(absl::string_view s) {
  return absl::StrReplaceAll(
      s, {{"&", "&amp;"}, {"<", "&lt;"}, {">", "&gt;"}, {"\"", "&quot;"}, {"'", "&apos;"}});
}

/// Array types written: the PointField types plus Int64 (offsets of binary files).
enum class ArrayType { kFloat64, kInt32, kUInt8, kInt64 };

ArrayType ToArrayType(VtkType t) {
  switch (t) {
    case VtkType::kInt32: return ArrayType::kInt32;
    case VtkType::kUInt8: return ArrayType::kUInt8;
    case VtkType::kFloat64: break;
  }
  return ArrayType::kFloat64;
}

const char* TypeName(ArrayType t) {
  switch (t) {
    case ArrayType::kFloat64: return "Float64";
    case ArrayType::kInt32: return "Int32";
    case ArrayType::kUInt8: return "UInt8";
    case ArrayType::kInt64: return "Int64";
  }
  return "?";
}

int TypeBytes(ArrayType t) {
  switch (t) {
    case ArrayType::kUInt8: return 1;
    case ArrayType::kInt32: return 4;
    case ArrayType::kFloat64:
    case ArrayType::kInt64: return 8;
  }
  return 0;
}

void StoreValue(char* p, ArrayType t, double v) {
  if (t == ArrayType::kFloat64)
    mesh_io::StoreDouble(p, v);
  else
    mesh_io::StoreLE(p, static_cast<uint64_t>(static_cast<int64_t>(v)), TypeBytes(t));
}

/// The XML of one VTK file being built; binary data collects in the appended block.
class VtkXml {
 public:
  VtkXml(absl::string_view type, VtkEncoding encoding) : type_(type), encoding_(encoding) {
    absl::StrAppend(&xml_, "<?xml version=\"1.0\"?>\n<VTKFile type=\"", type_, "\" ");
    if (encoding_ == VtkEncoding::kAscii) {
      xml_ += "version=\"0.1\" byte_order=\"LittleEndian\">\n";
    } else {
      xml_ += "version=\"1.0\" byte_order=\"LittleEndian\" header_type=\"UInt64\"";
      xml_ += encoding_ == VtkEncoding::kAppendedZlib ? " compressor=\"vtkZLibDataCompressor\">\n" : ">\n";
    }
    absl::StrAppend(&xml_, "  <", type_, ">\n");
  }

  bool binary() const { return encoding_ != VtkEncoding::kAscii; }
  std::string& xml() { return xml_; }

  /// One DataArray of `n` values value(i), `components` per tuple (0: no attribute).
  /// ASCII puts `per_line(i)` values on the line starting at value i.
  template <typename Value, typename PerLine>
  void Array(ArrayType type, absl::string_view name, int components, int64_t n, Value value,
             PerLine per_line) {
    absl::StrAppendFormat(&xml_, "        <DataArray type=\"%s\" Name=\"%s\"", TypeName(type),
                          XmlEscape(name));
    if (components > 0) absl::StrAppend(&xml_, " NumberOfComponents=\"", components, "\"");
    if (binary()) {
      xml_ += " format=\"appended\" offset=\"";
      pieces_.push_back(std::move(xml_));
      xml_ = "\"/>\n";
      const int bytes = TypeBytes(type);
      std::string block(8 + n * bytes, '\0');  // one block, filled in place
      char* p = block.data();
      mesh_io::StoreLE(p, static_cast<uint64_t>(n) * bytes, 8);
      p += 8;
      for (int64_t i = 0; i < n; ++i, p += bytes) StoreValue(p, type, value(i));
      blocks_.push_back(encoding_ == VtkEncoding::kAppendedZlib ? Compressed(block) : std::move(block));
      return;
    }
    bool finite = true;
    for (int64_t i = 0; i < n && finite; ++i) finite = std::isfinite(value(i));
    if (!finite) {  // only Float64 can hold these: inline base64, UInt32 size header
      std::string raw, header;
      for (int64_t i = 0; i < n; ++i) PutDouble(&raw, value(i));
      PutLE(&header, raw.size(), 4);
      absl::StrAppend(&xml_, " format=\"binary\">\n          ", Base64(header), Base64(raw),
                      "\n        </DataArray>\n");
      return;
    }
    xml_ += " format=\"ascii\">\n";
    for (int64_t i = 0; i < n;) {
      xml_ += "         ";
      for (const int64_t end = std::min<int64_t>(n, i + per_line(i)); i < end; ++i) {
        if (type == ArrayType::kFloat64)
          absl::StrAppendFormat(&xml_, " %.17g", value(i));
        else
          absl::StrAppend(&xml_, " ", static_cast<int64_t>(value(i)));
      }
      xml_ += '\n';
    }
    xml_ += "        </DataArray>\n";
  }

  /// An uncompressed block (8-byte size header, then the bytes) in VTK's zlib layout.
  static std::string Compressed(const std::string& block) {
    constexpr size_t kBlock = 32768;
    const size_t size = block.size() - 8;
    const size_t count = (size + kBlock - 1) / kBlock;
    std::string header, data;
    mesh_io::PutLE(&header, count, 8);
    mesh_io::PutLE(&header, kBlock, 8);
    mesh_io::PutLE(&header, size % kBlock, 8);  // 0: the last block is full
    std::vector<Bytef> out(compressBound(kBlock));
    for (size_t b = 0; b < count; ++b) {
      const size_t len = std::min(kBlock, size - b * kBlock);
      uLongf out_len = out.size();
      compress2(out.data(), &out_len, reinterpret_cast<const Bytef*>(block.data() + 8 + b * kBlock), len,
                Z_DEFAULT_COMPRESSION);  // cannot fail: the buffer is compressBound
      mesh_io::PutLE(&header, out_len, 8);
      data.append(reinterpret_cast<const char*>(out.data()), out_len);
    }
    return header + data;
  }

  std::string Finish() {
    absl::StrAppend(&xml_, "  </", type_, ">\n");
    if (!binary()) return std::move(xml_) + "</VTKFile>\n";
    // The blocks go in reverse order of their arrays: meshio 5.0 rewrites the offsets
    // one by one, looking each up by value, and would find an already rewritten
    // earlier array if one of its new offsets equalled a later array's old one.
    std::vector<uint64_t> offset(blocks_.size());
    uint64_t at = 0, total = 0;
    for (size_t k = blocks_.size(); k-- > 0;) {
      offset[k] = at;
      at += blocks_[k].size();
    }
    for (const std::string& p : pieces_) total += p.size() + 20;
    std::string out;
    out.reserve(total + xml_.size() + at + 64);
    for (size_t k = 0; k < pieces_.size(); ++k) absl::StrAppend(&out, pieces_[k], offset[k]);
    absl::StrAppend(&out, xml_, "  <AppendedData encoding=\"raw\">\n   _");
    for (size_t k = blocks_.size(); k-- > 0;) out += blocks_[k];
    out += "\n  </AppendedData>\n</VTKFile>\n";
    return out;
  }

 private:
  std::string type_;
  VtkEncoding encoding_;
  std::string xml_;
  /// Binary: the XML before each array's offset value, and each array's bytes.
  std::vector<std::string> pieces_, blocks_;
};

absl::Status CheckFields(int64_t nv, const std::vector<PointField>& fields,
                         const VtkOptions& options) {
  for (const PointField& f : fields) {
    if (f.values.rows() != nv || f.values.cols() < 1)
      return absl::InvalidArgumentError(absl::StrFormat(
          "point field '%s' is %d x %d; expected %d rows (one per vertex) and at least 1 column",
          f.name, f.values.rows(), f.values.cols(), nv));
    if (f.type == VtkType::kFloat64) continue;
    const double lo = f.type == VtkType::kUInt8 ? 0 : -2147483648.0;
    const double hi = f.type == VtkType::kUInt8 ? 255 : 2147483647.0;
    for (Eigen::Index r = 0; r < f.values.rows(); ++r)
      for (Eigen::Index c = 0; c < f.values.cols(); ++c) {
        const double v = f.values(r, c);
        if (!(v >= lo && v <= hi && v == std::floor(v)))
          return absl::InvalidArgumentError(absl::StrFormat(
              "point field '%s': value %g at vertex %d is not representable as %s", f.name, v, r,
              TypeName(ToArrayType(f.type))));
      }
  }
  const auto check_active = [&](const std::string& name, const char* what, int min_cols,
                                int max_cols) {
    if (name.empty()) return absl::OkStatus();
    for (const PointField& f : fields)
      if (f.name == name && f.values.cols() >= min_cols && f.values.cols() <= max_cols)
        return absl::OkStatus();
    return absl::InvalidArgumentError(absl::StrFormat(
        "active %s '%s' names no point field with %d..%d components", what, name, min_cols,
        max_cols));
  };
  GF_RETURN_IF_ERROR(check_active(options.normals, "normals", 3, 3));
  return check_active(options.scalars, "scalars", 1, 4);
}

absl::Status CheckCells(int64_t nv, const VtkCells& c) {
  const size_t n = c.types.size();
  if (c.offsets.size() != n + 1 || c.offsets.front() != 0 ||
      c.offsets.back() != static_cast<int64_t>(c.connectivity.size()))
    return absl::InvalidArgumentError(absl::StrFormat(
        "cells: %d types, %d offsets and %d point ids do not match", n, c.offsets.size(),
        c.connectivity.size()));
  for (size_t k = 0; k < n; ++k) {
    if (c.offsets[k + 1] <= c.offsets[k])
      return absl::InvalidArgumentError(absl::StrFormat("cell %d has no points", k));
    for (int64_t i = c.offsets[k]; i < c.offsets[k + 1]; ++i)
      if (c.connectivity[i] < 0 || c.connectivity[i] >= nv)
        return absl::InvalidArgumentError(absl::StrFormat(
            "cell %d: point %d is out of range [0, %d)", k, c.connectivity[i], nv));
  }
  return absl::OkStatus();
}

VtkCells CellsOf(const Mesh& mesh) {
  VtkCells c;
  c.offsets.reserve(mesh.NumFaces() + 1);
  c.connectivity.reserve(4 * static_cast<size_t>(mesh.NumFaces()));
  c.types.reserve(mesh.NumFaces());
  for (int f = 0; f < mesh.NumFaces(); ++f) {
    for (int i = 0; i < mesh.FaceSize(f); ++i) c.connectivity.push_back(mesh.faces(f, i));
    c.offsets.push_back(static_cast<int64_t>(c.connectivity.size()));
    c.types.push_back(mesh.FaceSize(f) == 3 ? kVtkTriangle : kVtkQuad);
  }
  return c;
}

/// <PointData> and <Points>, shared by both file types.
void AppendPoints(VtkXml* x, const Positions& points, const std::vector<PointField>& fields,
                  const VtkOptions& options) {
  const int64_t nv = points.rows();
  std::string& xml = x->xml();
  xml += "      <PointData";
  if (!options.normals.empty())
    absl::StrAppend(&xml, " Normals=\"", XmlEscape(options.normals), "\"");
  if (!options.scalars.empty())
    absl::StrAppend(&xml, " Scalars=\"", XmlEscape(options.scalars), "\"");
  xml += ">\n";
  for (const PointField& f : fields) {
    const int cols = static_cast<int>(f.values.cols());
    x->Array(
        ToArrayType(f.type), f.name, cols, nv * cols,
        [&](int64_t i) { return f.values(i / cols, i % cols); }, [&](int64_t) { return cols; });
  }
  x->xml() += "      </PointData>\n      <Points>\n";
  x->Array(
      ArrayType::kFloat64, "Points", 3, 3 * nv,
      [&](int64_t i) { return points(i / 3, i % 3); }, [](int64_t) { return 3; });
  x->xml() += "      </Points>\n";
}

/// connectivity (one cell a line in ASCII), offsets (16 a line; Int64 in binary files)
/// and, for unstructured grids, types.
void AppendCells(VtkXml* x, const VtkCells& c, bool with_types) {
  const int64_t n = static_cast<int64_t>(c.types.size());
  int64_t cell = 0;  // the cell of point id i, for the ASCII line breaks
  x->Array(
      ArrayType::kInt32, "connectivity", 0, static_cast<int64_t>(c.connectivity.size()),
      [&](int64_t i) { return c.connectivity[i]; },
      [&](int64_t i) {
        while (c.offsets[cell + 1] <= i) ++cell;
        return c.offsets[cell + 1] - i;
      });
  x->Array(
      x->binary() ? ArrayType::kInt64 : ArrayType::kInt32, "offsets", 0, n,
      [&](int64_t i) { return static_cast<double>(c.offsets[i + 1]); }, [](int64_t) { return 16; });
  if (with_types)
    x->Array(
        ArrayType::kUInt8, "types", 0, n, [&](int64_t i) { return c.types[i]; },
        [](int64_t) { return 16; });
}

std::string PieceVtp(const Mesh& mesh, const std::vector<PointField>& fields,
                     const VtkOptions& options) {
  VtkXml x("PolyData", options.encoding);
  absl::StrAppendFormat(&x.xml(),
                        "    <Piece NumberOfPoints=\"%d\" NumberOfVerts=\"0\" NumberOfLines=\"0\" "
                        "NumberOfStrips=\"0\" NumberOfPolys=\"%d\">\n",
                        mesh.NumVertices(), mesh.NumFaces());
  AppendPoints(&x, mesh.positions, fields, options);
  x.xml() += "      <Polys>\n";
  AppendCells(&x, CellsOf(mesh), /*with_types=*/false);
  x.xml() += "      </Polys>\n    </Piece>\n";
  return x.Finish();
}

std::string PieceVtu(const Positions& points, const VtkCells& cells,
                     const std::vector<PointField>& fields, const VtkOptions& options) {
  VtkXml x("UnstructuredGrid", options.encoding);
  absl::StrAppendFormat(&x.xml(), "    <Piece NumberOfPoints=\"%d\" NumberOfCells=\"%d\">\n",
                        points.rows(), cells.types.size());
  AppendPoints(&x, points, fields, options);
  x.xml() += "      <Cells>\n";
  AppendCells(&x, cells, /*with_types=*/true);
  x.xml() += "      </Cells>\n    </Piece>\n";
  return x.Finish();
}

/// Writes a formatted file, or returns its error prefixed with the path.
absl::Status WriteXml(const std::string& path, const absl::StatusOr<std::string>& xml) {
  if (!xml.ok())
    return absl::Status(xml.status().code(), absl::StrCat(path, ": ", xml.status().message()));
  return WriteFileAtomically(path, *xml);
}

}  // namespace

absl::StatusOr<std::string> FormatVtp(const Mesh& mesh, const std::vector<PointField>& fields) {
  VtkOptions text;
  text.encoding = VtkEncoding::kAscii;
  return FormatVtp(mesh, fields, text);
}

absl::StatusOr<std::string> FormatVtp(const Mesh& mesh, const std::vector<PointField>& fields,
                                      const VtkOptions& options) {
  GF_RETURN_IF_ERROR(mesh_io::CheckWritable(mesh));
  GF_RETURN_IF_ERROR(CheckFields(mesh.NumVertices(), fields, options));
  return PieceVtp(mesh, fields, options);
}

absl::StatusOr<std::string> FormatVtu(const Mesh& mesh, const std::vector<PointField>& fields,
                                      const VtkOptions& options) {
  GF_RETURN_IF_ERROR(mesh_io::CheckWritable(mesh));
  GF_RETURN_IF_ERROR(CheckFields(mesh.NumVertices(), fields, options));
  return PieceVtu(mesh.positions, CellsOf(mesh), fields, options);
}

absl::StatusOr<std::string> FormatVtu(const Positions& points, const VtkCells& cells,
                                      const std::vector<PointField>& fields,
                                      const VtkOptions& options) {
  GF_RETURN_IF_ERROR(CheckCells(points.rows(), cells));
  GF_RETURN_IF_ERROR(CheckFields(points.rows(), fields, options));
  return PieceVtu(points, cells, fields, options);
}

absl::Status WriteVtp(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields) {
  VtkOptions text;
  text.encoding = VtkEncoding::kAscii;
  return WriteVtp(path, mesh, fields, text);
}

absl::Status WriteVtp(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields, const VtkOptions& options) {
  return WriteXml(path, FormatVtp(mesh, fields, options));
}

absl::Status WriteVtu(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields, const VtkOptions& options) {
  return WriteXml(path, FormatVtu(mesh, fields, options));
}

absl::Status WriteVtu(const std::string& path, const Positions& points, const VtkCells& cells,
                      const std::vector<PointField>& fields, const VtkOptions& options) {
  return WriteXml(path, FormatVtu(points, cells, fields, options));
}

}  // namespace geomfit
