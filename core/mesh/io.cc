#include "core/mesh/io.h"

#include <array>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <memory>
#include <unordered_map>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/str_split.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

constexpr int64_t kMaxInt32 = std::numeric_limits<int32_t>::max();

// ---------------------------------------------------------------------------
// Shared pieces: mesh assembly, little-endian bytes, text lines and tokens.

/// Collects vertices and faces (4 slots per face, -1 for triangles).
class MeshBuilder {
 public:
  void ReserveVertices(int64_t n) { xyz_.reserve(3 * n); }
  void ReserveFaces(int64_t n) { faces_.reserve(4 * n); }
  int64_t NumVertices() const { return static_cast<int64_t>(xyz_.size() / 3); }
  int64_t NumFaces() const { return static_cast<int64_t>(faces_.size() / 4); }
  void AddVertex(const double p[3]) { xyz_.insert(xyz_.end(), p, p + 3); }
  void AddFace(const int32_t* v, int n) {
    for (int i = 0; i < 4; ++i) faces_.push_back(i < n ? v[i] : -1);
  }
  Mesh Build() const {
    Mesh m;
    m.positions = Eigen::Map<const Positions>(xyz_.data(), NumVertices(), 3);
    m.faces = Eigen::Map<const Faces>(faces_.data(), NumFaces(), 4);
    return m;
  }

 private:
  std::vector<double> xyz_;
  std::vector<int32_t> faces_;
};

/// Welds vertices whose coordinates are bitwise equal (STL stores every corner).
class VertexWelder {
 public:
  explicit VertexWelder(MeshBuilder* builder) : builder_(builder) {}
  int32_t Add(const double p[3]) {
    Key key;
    std::memcpy(key.data(), p, sizeof(key));
    auto [it, inserted] = index_.emplace(key, static_cast<int32_t>(builder_->NumVertices()));
    if (inserted) builder_->AddVertex(p);
    return it->second;
  }

 private:
  using Key = std::array<uint64_t, 3>;
  struct KeyHash {
    size_t operator()(const Key& k) const {
      uint64_t h = 0x9e3779b97f4a7c15ull;
      for (uint64_t x : k) {
        h ^= x + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
        h *= 0xbf58476d1ce4e5b9ull;
      }
      return static_cast<size_t>(h ^ (h >> 31));
    }
  };
  MeshBuilder* builder_;
  std::unordered_map<Key, int32_t, KeyHash> index_;
};

void PutLE(std::string* out, uint64_t bits, int nbytes) {
  for (int i = 0; i < nbytes; ++i) out->push_back(static_cast<char>((bits >> (8 * i)) & 0xff));
}
void PutDouble(std::string* out, double d) {
  uint64_t u;
  std::memcpy(&u, &d, 8);
  PutLE(out, u, 8);
}
void PutFloat(std::string* out, float f) {
  uint32_t u;
  std::memcpy(&u, &f, 4);
  PutLE(out, u, 4);
}
uint64_t GetLE(const char* p, int nbytes) {
  uint64_t u = 0;
  for (int i = 0; i < nbytes; ++i)
    u |= static_cast<uint64_t>(static_cast<uint8_t>(p[i])) << (8 * i);
  return u;
}

/// Splits text into lines (LF or CRLF), strips `comment` to end of line, counts lines.
class LineReader {
 public:
  LineReader(absl::string_view text, absl::string_view source, char comment)
      : text_(text), source_(source), comment_(comment) {}

  /// The next line; false at the end of the text.
  bool Next(absl::string_view* line) {
    if (pos_ >= text_.size()) return false;
    size_t end = text_.find('\n', pos_);
    if (end == absl::string_view::npos) end = text_.size();
    *line = text_.substr(pos_, end - pos_);
    pos_ = end + 1;
    ++line_number_;
    if (comment_ != 0) *line = line->substr(0, line->find(comment_));
    return true;
  }
  /// The next line with at least one token; false at the end of the text.
  bool NextTokens(std::vector<absl::string_view>* tokens) {
    absl::string_view line;
    while (Next(&line)) {
      *tokens = absl::StrSplit(line, absl::ByAnyChar(" \t\r\f\v"), absl::SkipEmpty());
      if (!tokens->empty()) return true;
    }
    tokens->clear();
    return false;
  }
  /// Byte offset just past the last line returned.
  size_t position() const { return std::min(pos_, text_.size()); }
  size_t remaining() const { return text_.size() - position(); }
  /// INVALID_ARGUMENT "<source>: line <n>: <what>".
  absl::Status Error(absl::string_view what) const {
    return absl::InvalidArgumentError(absl::StrCat(source_, ": line ", line_number_, ": ", what));
  }

 private:
  absl::string_view text_, source_;
  char comment_;
  size_t pos_ = 0;
  int64_t line_number_ = 0;
};

absl::Status ParseCoordinates(const LineReader& lines, const std::vector<absl::string_view>& tok,
                              size_t first, double p[3]) {
  if (tok.size() < first + 3)
    return lines.Error(absl::StrCat("vertex needs 3 coordinates, found ", tok.size() - first));
  for (int c = 0; c < 3; ++c)
    if (!absl::SimpleAtod(tok[first + c], &p[c]))
      return lines.Error(absl::StrCat("'", tok[first + c], "' is not a number"));
  return absl::OkStatus();
}

absl::Status CheckFaceSize(const LineReader& lines, int64_t face, int64_t n) {
  if (n >= 3 && n <= 4) return absl::OkStatus();
  return lines.Error(absl::StrFormat(
      "face %d has %d vertices; only triangles and quads (3 or 4) are supported", face, n));
}

absl::Status CountError(absl::string_view source, absl::string_view what, int64_t count,
                        size_t available) {
  return absl::InvalidArgumentError(absl::StrFormat(
      "%s: header claims %d %s but only %d bytes follow", source, count, what, available));
}

// ---------------------------------------------------------------------------
// OBJ

absl::StatusOr<Mesh> ParseObj(absl::string_view bytes, absl::string_view source) {
  LineReader lines(bytes, source, '#');
  MeshBuilder b;
  std::vector<absl::string_view> tok;
  while (lines.NextTokens(&tok)) {
    if (tok[0] == "v") {
      double p[3];
      GF_RETURN_IF_ERROR(ParseCoordinates(lines, tok, 1, p));
      b.AddVertex(p);
    } else if (tok[0] == "f") {
      const int64_t n = static_cast<int64_t>(tok.size()) - 1;
      GF_RETURN_IF_ERROR(CheckFaceSize(lines, b.NumFaces(), n));
      int32_t v[4];
      for (int i = 0; i < n; ++i) {
        const absl::string_view t = tok[i + 1].substr(0, tok[i + 1].find('/'));
        int64_t k;
        if (!absl::SimpleAtoi(t, &k))
          return lines.Error(absl::StrCat("'", tok[i + 1], "' is not a vertex index"));
        if (k == 0) return lines.Error("vertex index 0 (OBJ indices start at 1)");
        k = k < 0 ? b.NumVertices() + k : k - 1;  // negative: relative to the last vertex
        if (k < 0)
          return lines.Error(absl::StrCat("relative vertex index ", tok[i + 1],
                                          " points before the first vertex"));
        if (k > kMaxInt32) return lines.Error(absl::StrCat("vertex index ", t, " is too large"));
        v[i] = static_cast<int32_t>(k);
      }
      b.AddFace(v, static_cast<int>(n));
    }
  }
  return b.Build();
}

// ---------------------------------------------------------------------------
// OFF

absl::StatusOr<Mesh> ParseOff(absl::string_view bytes, absl::string_view source) {
  LineReader lines(bytes, source, '#');
  std::vector<absl::string_view> tok;
  if (!lines.NextTokens(&tok)) return lines.Error("empty file");
  size_t first = 0;
  if (absl::EndsWith(tok[0], "OFF")) {
    const absl::string_view prefix = tok[0].substr(0, tok[0].size() - 3);
    if (prefix != "" && prefix != "C" && prefix != "N" && prefix != "CN" && prefix != "NC" &&
        prefix != "ST" && prefix != "STC" && prefix != "STN" && prefix != "STCN")
      return lines.Error(absl::StrCat("unsupported OFF variant '", tok[0], "'"));
    if (tok.size() > 1 && absl::AsciiStrToLower(tok[1]) == "binary")
      return lines.Error("binary OFF is not supported");
    first = 1;
    if (tok.size() == 1) {  // the counts are on the next line
      if (!lines.NextTokens(&tok)) return lines.Error("missing counts line");
      first = 0;
    }
  }
  if (tok.size() < first + 2) return lines.Error("counts line needs #vertices and #faces");
  int64_t nv, nf;
  if (!absl::SimpleAtoi(tok[first], &nv) || !absl::SimpleAtoi(tok[first + 1], &nf) || nv < 0 ||
      nf < 0)
    return lines.Error(absl::StrCat("bad counts '", tok[first], " ", tok[first + 1],
                                    "' (expected non-negative integers)"));
  // Every vertex line holds at least "x y z\n" (6 bytes), every face "3 a b c\n" (8).
  if (nv > static_cast<int64_t>(lines.remaining() / 6) || nv > kMaxInt32)
    return CountError(source, "vertices", nv, lines.remaining());
  if (nf > static_cast<int64_t>(lines.remaining() / 8) || nf > kMaxInt32)
    return CountError(source, "faces", nf, lines.remaining());

  MeshBuilder b;
  b.ReserveVertices(nv);
  b.ReserveFaces(nf);
  for (int64_t i = 0; i < nv; ++i) {
    if (!lines.NextTokens(&tok))
      return lines.Error(absl::StrFormat("unexpected end of file after %d of %d vertices", i, nv));
    double p[3];
    GF_RETURN_IF_ERROR(ParseCoordinates(lines, tok, 0, p));
    b.AddVertex(p);
  }
  for (int64_t f = 0; f < nf; ++f) {
    if (!lines.NextTokens(&tok))
      return lines.Error(absl::StrFormat("unexpected end of file after %d of %d faces", f, nf));
    int64_t n;
    if (!absl::SimpleAtoi(tok[0], &n))
      return lines.Error(absl::StrCat("'", tok[0], "' is not a face size"));
    GF_RETURN_IF_ERROR(CheckFaceSize(lines, f, n));
    if (static_cast<int64_t>(tok.size()) < n + 1)
      return lines.Error(
          absl::StrFormat("face %d needs %d indices, found %d", f, n, tok.size() - 1));
    int32_t v[4];
    for (int i = 0; i < n; ++i)
      if (!absl::SimpleAtoi(tok[i + 1], &v[i]))
        return lines.Error(absl::StrCat("'", tok[i + 1], "' is not a vertex index"));
    b.AddFace(v, static_cast<int>(n));
  }
  return b.Build();
}

// ---------------------------------------------------------------------------
// PLY

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
    if (!absl::SimpleAtod(t, value)) return Error(absl::StrCat("'", t, "' is not a number"));
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
      case PlyType::kFloat32: {
        const uint32_t u32 = static_cast<uint32_t>(u);
        float f;
        std::memcpy(&f, &u32, 4);
        *value = f;
        break;
      }
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
  MeshBuilder b;
  bool have_vertices = false;
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
      have_vertices = true;
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
        if (k == list) b.AddFace(face, n);
      }
      if (is_vertex) b.AddVertex(p);
    }
  }
  if (!have_vertices)
    return absl::InvalidArgumentError(absl::StrCat(source, ": no 'vertex' element"));
  return b.Build();
}

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

// ---------------------------------------------------------------------------
// STL

bool LooksLikeAsciiStl(absl::string_view bytes) {
  return absl::StartsWith(absl::StripLeadingAsciiWhitespace(bytes), "solid");
}

absl::StatusOr<Mesh> ParseBinaryStl(absl::string_view bytes, int64_t n) {
  MeshBuilder b;
  VertexWelder welder(&b);
  b.ReserveFaces(n);
  for (int64_t t = 0; t < n; ++t) {
    const char* rec = bytes.data() + 84 + 50 * t + 12;  // skip the facet normal
    int32_t v[3];
    for (int i = 0; i < 3; ++i) {
      double p[3];
      for (int c = 0; c < 3; ++c) {
        const uint32_t u = static_cast<uint32_t>(GetLE(rec + 12 * i + 4 * c, 4));
        float f;
        std::memcpy(&f, &u, 4);
        p[c] = f;
      }
      v[i] = welder.Add(p);
    }
    b.AddFace(v, 3);
  }
  return b.Build();
}

absl::StatusOr<Mesh> ParseAsciiStl(absl::string_view bytes, absl::string_view source) {
  LineReader lines(bytes, source, 0);
  MeshBuilder b;
  VertexWelder welder(&b);
  std::vector<absl::string_view> tok;
  enum { kOutside, kSolid, kFacet, kLoop } state = kOutside;
  int32_t v[3];
  int corners = 0;
  auto expect = [&](bool ok, absl::string_view keyword) {
    return ok ? absl::OkStatus() : lines.Error(absl::StrCat("unexpected '", keyword, "'"));
  };
  while (lines.NextTokens(&tok)) {
    const absl::string_view k = tok[0];
    if (k == "solid") {
      GF_RETURN_IF_ERROR(expect(state == kOutside, k));
      state = kSolid;
    } else if (k == "facet") {
      GF_RETURN_IF_ERROR(expect(state == kSolid, k));
      state = kFacet;
      corners = 0;
    } else if (k == "outer") {
      GF_RETURN_IF_ERROR(expect(state == kFacet && corners == 0, k));
      state = kLoop;
    } else if (k == "vertex") {
      GF_RETURN_IF_ERROR(expect(state == kLoop, k));
      if (corners == 3) return lines.Error("facet has more than 3 vertices");
      double p[3];
      GF_RETURN_IF_ERROR(ParseCoordinates(lines, tok, 1, p));
      v[corners++] = welder.Add(p);
    } else if (k == "endloop") {
      GF_RETURN_IF_ERROR(expect(state == kLoop, k));
      if (corners != 3) return lines.Error(absl::StrCat("facet has ", corners, " vertices, not 3"));
      state = kFacet;
    } else if (k == "endfacet") {
      GF_RETURN_IF_ERROR(expect(state == kFacet && corners == 3, k));
      b.AddFace(v, 3);
      state = kSolid;
    } else if (k == "endsolid") {
      GF_RETURN_IF_ERROR(expect(state == kSolid, k));
      state = kOutside;
    } else {
      return lines.Error(absl::StrCat("unexpected token '", k, "'"));
    }
  }
  if (state != kOutside) return lines.Error("unexpected end of file (missing 'endsolid')");
  return b.Build();
}

absl::StatusOr<Mesh> ParseStl(absl::string_view bytes, absl::string_view source) {
  if (bytes.size() < 84 && !LooksLikeAsciiStl(bytes))
    return absl::InvalidArgumentError(absl::StrCat(
        source, ": not an STL file (shorter than the 84-byte binary header and no 'solid')"));
  const uint64_t n = bytes.size() >= 84 ? GetLE(bytes.data() + 80, 4) : 0;
  if (bytes.size() >= 84 && 84 + 50 * n == bytes.size()) {
    if (n > kMaxInt32 / 3)
      return absl::InvalidArgumentError(absl::StrCat(source, ": too many triangles (", n, ")"));
    return ParseBinaryStl(bytes, static_cast<int64_t>(n));
  }
  const std::string binary_error = absl::StrFormat(
      "byte 80: binary STL header claims %d triangles (%d bytes) but the file has %d bytes", n,
      84 + 50 * n, bytes.size());
  if (!LooksLikeAsciiStl(bytes))
    return absl::InvalidArgumentError(absl::StrCat(source, ": ", binary_error));
  absl::StatusOr<Mesh> ascii = ParseAsciiStl(bytes, source);
  // A binary STL may start with "solid" too: say what is wrong either way.
  if (!ascii.ok() && bytes.size() >= 84)
    return absl::InvalidArgumentError(
        absl::StrCat(ascii.status().message(), " (and as a binary STL: ", binary_error, ")"));
  return ascii;
}

// ---------------------------------------------------------------------------
// Writers

/// Vertex and face lines of OBJ ("v x y z", "f 1 2 3": 1-based) or OFF ("x y z", "3 0 1 2").
void AppendTextBody(std::string* out, const Mesh& m, bool obj) {
  for (int v = 0; v < m.NumVertices(); ++v)
    absl::StrAppendFormat(out, "%s%.17g %.17g %.17g\n", obj ? "v " : "", m.positions(v, 0),
                          m.positions(v, 1), m.positions(v, 2));
  for (int f = 0; f < m.NumFaces(); ++f) {
    absl::StrAppend(out, obj ? "f" : absl::StrCat(m.FaceSize(f)));
    for (int i = 0; i < m.FaceSize(f); ++i)
      absl::StrAppend(out, " ", m.faces(f, i) + (obj ? 1 : 0));
    *out += '\n';
  }
}

std::string FormatObj(const Mesh& m) {
  std::string out = "# geomfit\n";
  AppendTextBody(&out, m, /*obj=*/true);
  return out;
}

std::string FormatOff(const Mesh& m) {
  std::string out = absl::StrFormat("OFF\n%d %d 0\n", m.NumVertices(), m.NumFaces());
  AppendTextBody(&out, m, /*obj=*/false);
  return out;
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

absl::StatusOr<std::string> FormatStl(const Mesh& m) {
  std::vector<std::array<int32_t, 3>> tris;
  for (int f = 0; f < m.NumFaces(); ++f) {
    for (int i = 0; i < m.FaceSize(f); ++i)
      if (m.faces(f, i) < 0 || m.faces(f, i) >= m.NumVertices())
        return absl::InvalidArgumentError(absl::StrFormat("face %d: vertex index out of range", f));
    tris.push_back({m.faces(f, 0), m.faces(f, 1), m.faces(f, 2)});
    if (m.FaceSize(f) == 4) tris.push_back({m.faces(f, 0), m.faces(f, 2), m.faces(f, 3)});
  }
  std::string out = "geomfit binary STL";
  out.resize(80, ' ');
  PutLE(&out, tris.size(), 4);
  for (const auto& t : tris) {
    const Eigen::Vector3d a = m.positions.row(t[0]), b = m.positions.row(t[1]),
                          c = m.positions.row(t[2]);
    const Eigen::Vector3d n = (b - a).cross(c - a).normalized();
    for (int k = 0; k < 3; ++k) PutFloat(&out, static_cast<float>(n[k]));
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 3; ++k) PutFloat(&out, static_cast<float>(m.positions(t[i], k)));
    PutLE(&out, 0, 2);
  }
  return out;
}

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

// ---------------------------------------------------------------------------
// Public API

absl::StatusOr<MeshFormat> FormatFromPath(std::string_view path_in) {
  const absl::string_view path(path_in.data(), path_in.size());
  const size_t dot = path.rfind('.');
  const size_t slash = path.find_last_of("/\\");
  const std::string ext =
      dot == absl::string_view::npos || (slash != absl::string_view::npos && dot < slash)
          ? ""
          : absl::AsciiStrToLower(path.substr(dot + 1));
  if (ext == "obj") return MeshFormat::kObj;
  if (ext == "off") return MeshFormat::kOff;
  if (ext == "ply") return MeshFormat::kPly;
  if (ext == "stl") return MeshFormat::kStl;
  if (ext == "vtp") return MeshFormat::kVtp;
  return absl::InvalidArgumentError(absl::StrCat(path, ": unknown mesh file extension '", ext,
                                                 "' (expected .obj, .off, .ply, .stl or .vtp)"));
}

const char* MeshFormatName(MeshFormat format) {
  switch (format) {
    case MeshFormat::kObj: return "OBJ";
    case MeshFormat::kOff: return "OFF";
    case MeshFormat::kPly: return "PLY";
    case MeshFormat::kStl: return "STL";
    case MeshFormat::kVtp: return "VTP";
  }
  return "?";
}

absl::StatusOr<Mesh> ParseMesh(std::string_view bytes_in, MeshFormat format,
                               std::string_view source_in) {
  // Debian's Abseil is built with its own absl::string_view, distinct from std's.
  const absl::string_view bytes(bytes_in.data(), bytes_in.size());
  const absl::string_view source_name(source_in.data(), source_in.size());
  try {
    switch (format) {
      case MeshFormat::kObj: return ParseObj(bytes, source_name);
      case MeshFormat::kOff: return ParseOff(bytes, source_name);
      case MeshFormat::kPly: return ParsePly(bytes, source_name);
      case MeshFormat::kStl: return ParseStl(bytes, source_name);
      case MeshFormat::kVtp: break;
    }
    return absl::InvalidArgumentError(
        absl::StrCat(source_name, ": reading VTP is not supported (VTP is an output format)"));
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(absl::StrCat(source_name, ": out of memory while reading"));
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat(source_name, ": ", e.what()));
  }
}

absl::StatusOr<Mesh> ReadMesh(const std::string& path) {
  GF_ASSIGN_OR_RETURN(const MeshFormat format, FormatFromPath(path));
  if (format == MeshFormat::kVtp)
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": reading VTP is not supported (VTP is an output format)"));
  GF_ASSIGN_OR_RETURN(const std::string bytes, ReadFileToString(path));
  return ParseMesh(bytes, format, path);
}

absl::StatusOr<std::string> FormatMesh(const Mesh& mesh, MeshFormat format) {
  try {
    switch (format) {
      case MeshFormat::kObj: return FormatObj(mesh);
      case MeshFormat::kOff: return FormatOff(mesh);
      case MeshFormat::kPly: return FormatPly(mesh);
      case MeshFormat::kStl: return FormatStl(mesh);
      case MeshFormat::kVtp: return FormatVtp(mesh, {});
    }
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError("out of memory while formatting a mesh");
  }
  return absl::InvalidArgumentError("unknown mesh format");
}

absl::Status WriteMesh(const Mesh& mesh, const std::string& path) {
  GF_ASSIGN_OR_RETURN(const MeshFormat format, FormatFromPath(path));
  GF_ASSIGN_OR_RETURN(const std::string bytes, FormatMesh(mesh, format));
  return WriteFileAtomically(path, bytes);
}

absl::StatusOr<std::string> FormatVtp(const Mesh& mesh, const std::vector<PointField>& fields) {
  const int nv = mesh.NumVertices(), nf = mesh.NumFaces();
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

std::string FormatNpy(const Eigen::Ref<const RowMajorMatrixXd>& a) {
  std::string dict = absl::StrFormat(
      "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, %d), }", a.rows(), a.cols());
  // Magic (6) + version (2) + header length (2) + dict + padding + '\n': multiple of 64.
  dict.resize((10 + dict.size() + 1 + 63) / 64 * 64 - 10 - 1, ' ');
  dict += '\n';
  std::string out("\x93NUMPY\x01\x00", 8);
  PutLE(&out, dict.size(), 2);
  out += dict;
  out.reserve(out.size() + 8 * a.size());
  for (Eigen::Index r = 0; r < a.rows(); ++r)
    for (Eigen::Index c = 0; c < a.cols(); ++c) PutDouble(&out, a(r, c));
  return out;
}

absl::Status WriteNpy(const std::string& path, const Eigen::Ref<const RowMajorMatrixXd>& a) {
  return WriteFileAtomically(path, FormatNpy(a));
}

absl::StatusOr<std::string> ReadFileToString(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot open '", path, "'"));
  std::string out;
  char buf[1 << 16];
  size_t n;
  while ((n = std::fread(buf, 1, sizeof(buf), f.get())) > 0) out.append(buf, n);
  if (std::ferror(f.get()))
    return absl::ErrnoToStatus(errno, absl::StrCat("cannot read '", path, "'"));
  return out;
}

absl::Status WriteFileAtomically(const std::string& path, std::string_view contents) {
  const std::string tmp = path + ".tmp";
  FILE* f = std::fopen(tmp.c_str(), "wb");
  if (!f) return absl::ErrnoToStatus(errno, absl::StrCat("cannot write '", path, "'"));
  bool ok =
      std::fwrite(contents.data(), 1, contents.size(), f) == contents.size() && std::fflush(f) == 0;
  int err = ok ? 0 : errno;
  if (std::fclose(f) != 0 && ok) {
    ok = false;
    err = errno;
  }
  if (!ok) {
    std::remove(tmp.c_str());
    return absl::ErrnoToStatus(err, absl::StrCat("cannot write '", path, "'"));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    err = errno;
    std::remove(tmp.c_str());
    return absl::ErrnoToStatus(err, absl::StrCat("cannot rename '", tmp, "' to '", path, "'"));
  }
  return absl::OkStatus();
}

}  // namespace geomfit
