#include "core/mesh/formats/common.h"

#include <charconv>
#include <cmath>
#include <cstring>
#include <system_error>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace geomfit::mesh_io {

Mesh MeshBuilder::Build() {
  xyz_.conservativeResize(num_vertices_, 3);  // row-major, same columns: a realloc
  faces_.conservativeResize(num_faces_, 4);
  Mesh m;
  m.positions = std::move(xyz_);
  m.faces = SharedFaces(std::move(faces_));
  num_vertices_ = num_faces_ = 0;
  xyz_.resize(0, 3);
  faces_.resize(0, 4);
  return m;
}

int32_t VertexWelder::Add(const double p[3]) {
  Key key;
  std::memcpy(key.data(), p, sizeof(key));
  auto [it, inserted] = index_.emplace(key, static_cast<int32_t>(builder_->NumVertices()));
  if (inserted) builder_->AddVertex(p);
  return it->second;
}

size_t VertexWelder::KeyHash::operator()(const Key& k) const {
  uint64_t h = 0x9e3779b97f4a7c15ull;
  for (uint64_t x : k) {
    h ^= x + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
    h *= 0xbf58476d1ce4e5b9ull;
  }
  return static_cast<size_t>(h ^ (h >> 31));
}

std::string IndexRangeMessage(int64_t face, int64_t index, int64_t num_vertices) {
  return absl::StrFormat("face %d: vertex index %d is out of range [0, %d)", face, index,
                         num_vertices);
}

absl::Status CheckFaces(const Mesh& mesh) {
  const int nv = mesh.NumVertices();
  for (int f = 0; f < mesh.NumFaces(); ++f) {
    const int32_t last = mesh.faces(f, 3);
    if (last < -1)
      return absl::InvalidArgumentError(absl::StrFormat(
          "face %d: fourth corner %d is neither a vertex index nor -1 (a triangle)", f, last));
    for (int i = 0; i < mesh.FaceSize(f); ++i)
      if (mesh.faces(f, i) < 0 || mesh.faces(f, i) >= nv)
        return absl::InvalidArgumentError(IndexRangeMessage(f, mesh.faces(f, i), nv));
  }
  return absl::OkStatus();
}

absl::Status CheckWritable(const Mesh& mesh) {
  absl::Status faces = CheckFaces(mesh);
  if (faces.ok()) return faces;
  return absl::InvalidArgumentError(
      absl::StrCat("refusing to write an invalid mesh: ", faces.message()));
}

void PutLE(std::string* out, uint64_t bits, int nbytes) {
  char buf[8];
  StoreLE(buf, bits, nbytes);
  out->append(buf, nbytes);
}

void PutDouble(std::string* out, double d) {
  char buf[8];
  StoreDouble(buf, d);
  out->append(buf, 8);
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

float GetFloat(const char* p) {
  const uint32_t u = static_cast<uint32_t>(GetLE(p, 4));
  float f;
  std::memcpy(&f, &u, 4);
  return f;
}

bool LineReader::Next(absl::string_view* line) {
  if (pos_ >= text_.size()) return false;
  size_t end = text_.find('\n', pos_);
  if (end == absl::string_view::npos) end = text_.size();
  *line = text_.substr(pos_, end - pos_);
  pos_ = end + 1;
  ++line_number_;
  if (comment_ != 0) *line = line->substr(0, line->find(comment_));
  return true;
}

LineReader::LineReader(absl::string_view text, absl::string_view source, char comment)
    : text_(text), source_(source), comment_(comment) {
  for (const char c : {' ', '\t', '\r', '\f', '\v'}) class_[static_cast<uint8_t>(c)] = kSeparator;
  class_[static_cast<uint8_t>('\n')] = kLineEnd;
  if (comment != 0) class_[static_cast<uint8_t>(comment)] = kLineEnd;
}

// Next() and the split of its line, in one pass over the bytes.
bool LineReader::NextTokens(std::vector<absl::string_view>* tokens) {
  tokens->clear();  // reused: no allocation once it holds the longest line's tokens
  const char* const begin = text_.data();
  const char* const end = begin + text_.size();
  while (pos_ < text_.size()) {
    ++line_number_;
    const char* p = begin + pos_;
    for (;;) {
      while (p < end && class_[static_cast<uint8_t>(*p)] == kSeparator) ++p;
      if (p == end || class_[static_cast<uint8_t>(*p)] == kLineEnd) break;
      const char* const start = p;
      while (p < end && class_[static_cast<uint8_t>(*p)] == kToken) ++p;
      tokens->emplace_back(start, static_cast<size_t>(p - start));
    }
    if (p < end && *p != '\n') {  // a comment: skip to the end of the line
      p = static_cast<const char*>(std::memchr(p, '\n', end - p));
      if (p == nullptr) p = end;
    }
    pos_ = static_cast<size_t>(p - begin) + 1;
    if (!tokens->empty()) return true;
  }
  return false;
}

absl::Status LineReader::ErrorAt(int64_t line, absl::string_view what) const {
  return absl::InvalidArgumentError(absl::StrCat(source_, ": line ", line, ": ", what));
}

absl::Status ParseCoordinates(const LineReader& lines, const std::vector<absl::string_view>& tok,
                              size_t first, double p[3]) {
  if (tok.size() < first + 3)
    return lines.Error(absl::StrCat("vertex needs 3 coordinates, found ", tok.size() - first));
  for (int c = 0; c < 3; ++c)
    if (!ParseDouble(tok[first + c], &p[c]))
      return lines.Error(absl::StrCat("'", tok[first + c], "' is not a number"));
  return absl::OkStatus();
}

// Both parsers below take std::from_chars's answer when it reads the whole token to a
// finite value (then it is the correctly rounded value Abseil's parser gives too) and
// leave everything else (a '+' sign, overflow, inf, nan, malformed text) to Abseil,
// whose rules define what is accepted.
bool ParseDouble(absl::string_view token, double* value) {
  const char* const end = token.data() + token.size();
  double v;
  const std::from_chars_result r = std::from_chars(token.data(), end, v);
  if (r.ec == std::errc() && r.ptr == end && std::isfinite(v)) {
    *value = v;
    return true;
  }
  return absl::SimpleAtod(token, value);
}

bool ParseInteger(absl::string_view token, int64_t* value) {
  const char* const end = token.data() + token.size();
  int64_t v;
  const std::from_chars_result r = std::from_chars(token.data(), end, v);
  if (r.ec == std::errc() && r.ptr == end) {
    *value = v;
    return true;
  }
  return absl::SimpleAtoi(token, value);
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

void AppendTextBody(std::string* out, const Mesh& m, TextDialect dialect) {
  const bool obj = dialect == TextDialect::kObj;
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

}  // namespace geomfit::mesh_io
