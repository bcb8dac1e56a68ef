// VTK XML PolyData (.vtp) output.
#include <cmath>
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

/// One Float64 DataArray of `rows` x `cols` values given by value(r, c): ASCII, or
/// inline base64 (UInt32 byte-count header encoded separately, as VTK writes it)
/// when a value is not finite.
template <typename Fn>
void AppendFloat64Array(std::string* out, absl::string_view name, int64_t rows, int cols,
                        Fn value) {
  bool finite = true;
  for (int64_t r = 0; r < rows && finite; ++r)
    for (int c = 0; c < cols; ++c) finite = finite && std::isfinite(value(r, c));
  absl::StrAppendFormat(out,
                        "        <DataArray type=\"Float64\" Name=\"%s\" NumberOfComponents=\"%d\" "
                        "format=\"%s\">\n",
                        XmlEscape(name), cols, finite ? "ascii" : "binary");
  if (finite) {
    for (int64_t r = 0; r < rows; ++r) {
      *out += "         ";
      for (int c = 0; c < cols; ++c) absl::StrAppendFormat(out, " %.17g", value(r, c));
      *out += '\n';
    }
  } else {
    std::string raw, header;
    for (int64_t r = 0; r < rows; ++r)
      for (int c = 0; c < cols; ++c) PutDouble(&raw, value(r, c));
    PutLE(&header, raw.size(), 4);
    absl::StrAppend(out, "          ", Base64(header), Base64(raw), "\n");
  }
  *out += "        </DataArray>\n";
}

}  // namespace

absl::StatusOr<std::string> FormatVtp(const Mesh& mesh, const std::vector<PointField>& fields) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
  GF_RETURN_IF_ERROR(mesh_io::CheckWritable(mesh));
  for (const PointField& f : fields)
    if (f.values.rows() != nv || f.values.cols() < 1)
      return absl::InvalidArgumentError(absl::StrFormat(
          "point field '%s' is %d x %d; expected %d rows (one per vertex) and at least 1 column",
          f.name, f.values.rows(), f.values.cols(), nv));
  std::string out = absl::StrFormat(
      "<?xml version=\"1.0\"?>\n"
      "<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
      "  <PolyData>\n"
      "    <Piece NumberOfPoints=\"%d\" NumberOfVerts=\"0\" NumberOfLines=\"0\" "
      "NumberOfStrips=\"0\" NumberOfPolys=\"%d\">\n"
      "      <PointData>\n",
      nv, nf);
  for (const PointField& f : fields)
    AppendFloat64Array(&out, f.name, nv, static_cast<int>(f.values.cols()),
                       [&](int64_t r, int c) { return f.values(r, c); });
  out += "      </PointData>\n      <Points>\n";
  AppendFloat64Array(&out, "Points", nv, 3, [&](int64_t r, int c) { return mesh.positions(r, c); });
  out += "      </Points>\n      <Polys>\n";
  out += "        <DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n";
  for (int f = 0; f < nf; ++f) {
    out += "         ";
    for (int i = 0; i < mesh.FaceSize(f); ++i) absl::StrAppend(&out, " ", mesh.faces(f, i));
    out += '\n';
  }
  out += "        </DataArray>\n";
  out += "        <DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n";
  int64_t offset = 0;
  for (int f = 0; f < nf; ++f) {
    offset += mesh.FaceSize(f);
    absl::StrAppend(&out, f % 16 == 0 ? "          " : " ", offset,
                    f % 16 == 15 || f == nf - 1 ? "\n" : "");
  }
  out += "        </DataArray>\n      </Polys>\n    </Piece>\n  </PolyData>\n</VTKFile>\n";
  return out;
}

absl::Status WriteVtp(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields) {
  absl::StatusOr<std::string> xml = FormatVtp(mesh, fields);
  if (!xml.ok())
    return absl::InvalidArgumentError(absl::StrCat(path, ": ", xml.status().message()));
  return WriteFileAtomically(path, *xml);
}

}  // namespace geomfit
