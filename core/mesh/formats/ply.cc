// PLY: ascii and binary_little_endian; x, y, z of any numeric type; faces from
// `vertex_indices` / `vertex_index`; other properties and elements skipped by type.
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/formats/formats.h"
#include "core/util/status_macros.h"

namespace geomfit::mesh_io {
namespace {


enum class PlyType { kInt8, kUint8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

struct PlyTypeInfo {
  const char* names[2];
  PlyType type;
  int size;
};
constexpr PlyTypeInfo kPlyTypes[] = {
    {{"char", "int8"}, PlyType::kInt8, 1},        {{"uchar", "uint8"}, PlyType::kUint8, 1},
    {{"short", "int16"}, PlyType::kInt16, 2},     {{"ushort", "uint16"}, PlyType::kUint16, 2},
    {{"int", "int32"}, PlyType::kInt32, 4},       {{"uint", "uint32"}, PlyType::kUint32, 4},
    {{"float", "float32"}, PlyType::kFloat32, 4}, {{"double", "float64"}, PlyType::kFloat64, 8},
};

bool ParsePlyType(absl::string_view name, PlyType* type) {
  for (const PlyTypeInfo& t : kPlyTypes)
    if (name == t.names[0] || name == t.names[1]) {
      *type = t.type;
      return true;
    }
  return false;
}
int PlyTypeSize(PlyType type) { return kPlyTypes[static_cast<int>(type)].size; }

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::kFloat32;  // item type for lists
  bool is_list = false;
  PlyType count_type = PlyType::kUint8;
};

struct PlyElement {
  std::string name;
  int64_t count = 0;
  std::vector<PlyProperty> properties;
  int Find(absl::string_view name) const {
    for (size_t i = 0; i < properties.size(); ++i)
      if (properties[i].name == name) return static_cast<int>(i);
    return -1;
  }
};

struct PlyHeader {
  bool binary = false;
  std::vector<PlyElement> elements;
  size_t data_offset = 0;
};

absl::StatusOr<PlyHeader> ParsePlyHeader(absl::string_view bytes, absl::string_view source) {
  LineReader lines(bytes, source, 0);
  std::vector<absl::string_view> tok;
  if (!lines.NextTokens(&tok) || tok[0] != "ply") return lines.Error("missing 'ply' magic line");
  PlyHeader h;
  bool have_format = false;
  while (true) {
    if (!lines.NextTokens(&tok)) return lines.Error("header has no 'end_header' line");
    if (tok[0] == "end_header") break;
    if (tok[0] == "comment" || tok[0] == "obj_info") continue;
    if (tok[0] == "format") {
      if (tok.size() < 2) return lines.Error("'format' needs a value");
      if (tok[1] == "binary_big_endian")
        return lines.Error("binary_big_endian PLY is not supported (convert to little endian)");
      if (tok[1] != "ascii" && tok[1] != "binary_little_endian")
        return lines.Error(absl::StrCat("unknown PLY format '", tok[1], "'"));
      h.binary = tok[1] == "binary_little_endian";
      have_format = true;
    } else if (tok[0] == "element") {
      PlyElement e;
      if (tok.size() != 3) return lines.Error("'element' needs a name and a count");
      e.name = std::string(tok[1]);
      if (!absl::SimpleAtoi(tok[2], &e.count) || e.count < 0)
        return lines.Error(absl::StrCat("bad count '", tok[2], "' for element '", tok[1], "'"));
      h.elements.push_back(std::move(e));
    } else if (tok[0] == "property") {
      if (h.elements.empty()) return lines.Error("'property' before any 'element'");
      PlyProperty p;
      bool ok;
      if (tok.size() == 5 && tok[1] == "list") {
        p.is_list = true;
        ok = ParsePlyType(tok[2], &p.count_type) && ParsePlyType(tok[3], &p.type);
        if (ok && (p.count_type == PlyType::kFloat32 || p.count_type == PlyType::kFloat64))
          return lines.Error("list count type must be an integer type");
      } else {
        ok = tok.size() == 3 && ParsePlyType(tok[1], &p.type);
      }
      if (!ok) return lines.Error("malformed 'property' line");
      p.name = std::string(tok.back());
      h.elements.back().properties.push_back(std::move(p));
    } else {
      return lines.Error(absl::StrCat("unknown header keyword '", tok[0], "'"));
    }
  }
  if (!have_format) return lines.Error("header has no 'format' line");
  h.data_offset = lines.position();
  return h;
}

/// Where PLY values come from: lines of text or little-endian bytes.
class PlySource {
 public:
  virtual ~PlySource() = default;
  /// Starts the next element record (the next line for ASCII).
  virtual absl::Status BeginRecord() = 0;
  virtual absl::Status Read(PlyType type, double* value) = 0;
  /// Bytes not yet consumed (bounds every count before allocating).
  virtual size_t Remaining() const = 0;
  /// Smallest number of bytes one value of `type` can occupy.
  virtual size_t MinBytes(PlyType type) const = 0;
  /// Most list items of `type` that can follow in the current record.
  virtual size_t MaxItems(PlyType type) const = 0;
  virtual absl::Status Error(absl::string_view what) const = 0;
};

class PlyAsciiSource : public PlySource {
 public:
  /// Reads lines from `data_offset` on, numbering them from the top of the file.
  PlyAsciiSource(absl::string_view bytes, size_t data_offset, absl::string_view source)
      : lines_(bytes, source, 0) {
    absl::string_view skipped;
    while (lines_.position() < data_offset && lines_.Next(&skipped)) {
    }
  }
  absl::Status BeginRecord() override {
    next_ = 0;
    if (!lines_.NextTokens(&tokens_)) return Error("unexpected end of file");
    return absl::OkStatus();
  }
  absl::Status Read(PlyType, double* value) override {
    if (next_ >= tokens_.size()) return Error("too few values on the line");
    const absl::string_view t = tokens_[next_++];
    if (!ParseDouble(t, value)) return Error(absl::StrCat("'", t, "' is not a number"));
    return absl::OkStatus();
  }
  size_t Remaining() const override { return lines_.remaining(); }
  size_t MinBytes(PlyType) const override { return 2; }  // a digit and a separator
  size_t MaxItems(PlyType) const override { return tokens_.size() - next_; }
  absl::Status Error(absl::string_view what) const override { return lines_.Error(what); }

 private:
  LineReader lines_;
  std::vector<absl::string_view> tokens_;
  size_t next_ = 0;
};

class PlyBinarySource : public PlySource {
 public:
  PlyBinarySource(absl::string_view bytes, size_t offset, absl::string_view source)
      : bytes_(bytes), pos_(offset), source_(source) {}
  absl::Status BeginRecord() override { return absl::OkStatus(); }
  absl::Status Read(PlyType type, double* value) override {
    const int n = PlyTypeSize(type);
    if (bytes_.size() - pos_ < static_cast<size_t>(n)) return Error("unexpected end of data");
    const uint64_t u = GetLE(bytes_.data() + pos_, n);
    pos_ += n;
    switch (type) {
      case PlyType::kInt8: *value = static_cast<int8_t>(u); break;
      case PlyType::kUint8: *value = static_cast<uint8_t>(u); break;
      case PlyType::kInt16: *value = static_cast<int16_t>(u); break;
      case PlyType::kUint16: *value = static_cast<uint16_t>(u); break;
      case PlyType::kInt32: *value = static_cast<int32_t>(u); break;
      case PlyType::kUint32: *value = static_cast<uint32_t>(u); break;
      case PlyType::kFloat32: *value = GetFloat(bytes_.data() + pos_ - n); break;
      case PlyType::kFloat64: std::memcpy(value, &u, 8); break;
    }
    return absl::OkStatus();
  }
  size_t Remaining() const override { return bytes_.size() - pos_; }
  size_t MinBytes(PlyType type) const override { return PlyTypeSize(type); }
  size_t MaxItems(PlyType type) const override { return Remaining() / PlyTypeSize(type); }
  absl::Status Error(absl::string_view what) const override {
    return absl::InvalidArgumentError(absl::StrCat(source_, ": byte ", pos_, ": ", what));
  }

 private:
  absl::string_view bytes_;
  size_t pos_;
  absl::string_view source_;
};

/// A list length or vertex index must be an integer in [lo, hi].
bool IsIntegerIn(double v, double lo, double hi) {
  return v >= lo && v <= hi && v == std::floor(v);
}

absl::StatusOr<Mesh> ParsePlyData(const PlyHeader& h, PlySource& src, absl::string_view source) {
  // Faces are checked against the header's vertex count, whichever element comes first.
  int64_t num_vertices = 0;
  bool have_vertices = false;
  for (const PlyElement& e : h.elements)
    if (e.name == "vertex") {
      have_vertices = true;
      num_vertices += e.count;
    }
  if (!have_vertices)
    return absl::InvalidArgumentError(absl::StrCat(source, ": no 'vertex' element"));
  MeshBuilder b;
  for (const PlyElement& e : h.elements) {
    // Bound the count by the bytes left before allocating anything.
    size_t min_record = 0;
    for (const PlyProperty& p : e.properties)
      min_record += src.MinBytes(p.is_list ? p.count_type : p.type);
    if (e.count > kMaxInt32 ||
        (min_record > 0 && static_cast<uint64_t>(e.count) > src.Remaining() / min_record))
      return CountError(source, absl::StrCat("'", e.name, "' elements"), e.count, src.Remaining());

    const bool is_vertex = e.name == "vertex", is_face = e.name == "face";
    int xyz[3] = {-1, -1, -1}, list = -1;
    if (is_vertex) {
      for (int c = 0; c < 3; ++c) {
        const char name[2] = {"xyz"[c], 0};
        xyz[c] = e.Find(name);
        if (xyz[c] < 0 || e.properties[xyz[c]].is_list)
          return absl::InvalidArgumentError(
              absl::StrCat(source, ": element 'vertex' has no scalar property '", name, "'"));
      }
      b.ReserveVertices(e.count);
    } else if (is_face) {
      list = e.Find("vertex_indices");
      if (list < 0) list = e.Find("vertex_index");
      if (list < 0 || !e.properties[list].is_list || PlyTypeSize(e.properties[list].type) > 4 ||
          e.properties[list].type == PlyType::kFloat32)
        return absl::InvalidArgumentError(absl::StrCat(
            source, ": element 'face' has no integer list 'vertex_indices' or 'vertex_index'"));
      b.ReserveFaces(e.count);
    }

    // An element without properties occupies no bytes: nothing to read.
    for (int64_t r = 0; r < (e.properties.empty() ? 0 : e.count); ++r) {
      GF_RETURN_IF_ERROR(src.BeginRecord());
      double p[3] = {0, 0, 0};
      int32_t face[4];
      for (int k = 0; k < static_cast<int>(e.properties.size()); ++k) {
        const PlyProperty& prop = e.properties[k];
        double v;
        GF_RETURN_IF_ERROR(src.Read(prop.is_list ? prop.count_type : prop.type, &v));
        if (!prop.is_list) {
          for (int c = 0; c < 3; ++c)
            if (k == xyz[c]) p[c] = v;
          continue;
        }
        const size_t max_items = src.MaxItems(prop.type);
        if (!IsIntegerIn(v, 0, static_cast<double>(max_items)))
          return src.Error(
              absl::StrFormat("bad list length %g in element '%s' %d (at most %d can follow)", v,
                              e.name, r, max_items));
        const int n = static_cast<int>(v);
        if (k == list && (n < 3 || n > 4))
          return src.Error(absl::StrFormat(
              "face %d has %d vertices; only triangles and quads (3 or 4) are supported", r, n));
        for (int i = 0; i < n; ++i) {
          GF_RETURN_IF_ERROR(src.Read(prop.type, &v));
          if (k != list) continue;
          if (!IsIntegerIn(v, -2147483648.0, 2147483647.0))
            return src.Error(absl::StrFormat("face %d: vertex index %g is not an int32", r, v));
          face[i] = static_cast<int32_t>(v);
        }
        if (k != list) continue;
        for (int i = 0; i < n; ++i)
          if (face[i] < 0 || face[i] >= num_vertices)
            return src.Error(IndexRangeMessage(r, face[i], num_vertices));
        b.AddFace(face, n);
      }
      if (is_vertex) b.AddVertex(p);
    }
  }
  return b.Build();
}

}  // namespace

absl::StatusOr<Mesh> ParsePly(absl::string_view bytes, absl::string_view source) {
  GF_ASSIGN_OR_RETURN(const PlyHeader h, ParsePlyHeader(bytes, source));
  if (h.binary) {
    PlyBinarySource src(bytes, h.data_offset, source);
    return ParsePlyData(h, src, source);
  }
  // ASCII: line numbers in errors count from the top of the file.
  PlyAsciiSource src(bytes, h.data_offset, source);
  return ParsePlyData(h, src, source);
}

std::string FormatPly(const Mesh& m) {
  std::string out = absl::StrFormat(
      "ply\nformat binary_little_endian 1.0\ncomment geomfit\nelement vertex %d\n"
      "property double x\nproperty double y\nproperty double z\nelement face %d\n"
      "property list uchar int vertex_indices\nend_header\n",
      m.NumVertices(), m.NumFaces());
  out.reserve(out.size() + 24 * m.NumVertices() + 17 * m.NumFaces());
  for (int v = 0; v < m.NumVertices(); ++v)
    for (int c = 0; c < 3; ++c) PutDouble(&out, m.positions(v, c));
  for (int f = 0; f < m.NumFaces(); ++f) {
    out.push_back(static_cast<char>(m.FaceSize(f)));
    for (int i = 0; i < m.FaceSize(f); ++i) PutLE(&out, static_cast<uint32_t>(m.faces(f, i)), 4);
  }
  return out;
}

}  // namespace geomfit::mesh_io
