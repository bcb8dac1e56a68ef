#pragma once
// Internal to core/mesh: pieces shared by the format readers and writers.
#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <system_error>
#include <limits>
#include <string>
#include <unordered_map>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/string_view.h"
#include "core/mesh/mesh.h"

namespace geomfit::mesh_io {

constexpr int64_t kMaxInt32 = std::numeric_limits<int32_t>::max();

// ---------------------------------------------------------------------------
// Mesh assembly

/// Collects vertices and faces (4 slots per face, -1 for triangles) straight into the
/// mesh's arrays: they grow by doubling and Build() shrinks them in place (realloc), so
/// the mesh is never copied.
class MeshBuilder {
 public:
  void ReserveVertices(int64_t n) {
    if (n > xyz_.rows()) xyz_.conservativeResize(n, 3);
  }
  void ReserveFaces(int64_t n) {
    if (n > faces_.rows()) faces_.conservativeResize(n, 4);
  }
  int64_t NumVertices() const { return num_vertices_; }
  int64_t NumFaces() const { return num_faces_; }
  void AddVertex(const double p[3]) {
    if (num_vertices_ == xyz_.rows()) ReserveVertices(std::max<int64_t>(64, 2 * num_vertices_));
    double* row = xyz_.data() + 3 * num_vertices_++;
    row[0] = p[0], row[1] = p[1], row[2] = p[2];
  }
  void AddFace(const int32_t* v, int n) {
    if (num_faces_ == faces_.rows()) ReserveFaces(std::max<int64_t>(64, 2 * num_faces_));
    int32_t* row = faces_.data() + 4 * num_faces_++;
    for (int i = 0; i < 4; ++i) row[i] = i < n ? v[i] : -1;
  }
  /// The mesh; the builder is empty afterwards.
  Mesh Build();

 private:
  Positions xyz_;
  Faces faces_;
  int64_t num_vertices_ = 0, num_faces_ = 0;
};

/// Welds vertices whose coordinates are bitwise equal (STL stores every corner).
class VertexWelder {
 public:
  explicit VertexWelder(MeshBuilder* builder) : builder_(builder) {}
  int32_t Add(const double p[3]);

 private:
  using Key = std::array<uint64_t, 3>;
  struct KeyHash {
    size_t operator()(const Key& k) const;
  };
  MeshBuilder* builder_;
  std::unordered_map<Key, int32_t, KeyHash> index_;
};

/// The connectivity every reader guarantees and every writer requires: each face has
/// 3 or 4 corners (a triangle carries -1 in its fourth slot) that index existing
/// vertices. Errors (INVALID_ARGUMENT) name the face. Geometry and manifoldness are
/// ValidateMesh's business (topology.h).
absl::Status CheckFaces(const Mesh& mesh);

/// CheckFaces for writers: "refusing to write an invalid mesh: face ...".
absl::Status CheckWritable(const Mesh& mesh);

/// "face <f>: vertex index <k> is out of range [0, <nv>)" (the readers' and writers' words).
std::string IndexRangeMessage(int64_t face, int64_t index, int64_t num_vertices);

// ---------------------------------------------------------------------------
// Little-endian bytes

/// Stores the low `nbytes` bytes of `bits` at p, least significant first (one store on
/// little-endian machines once inlined).
inline void StoreLE(char* p, uint64_t bits, int nbytes) {
  for (int i = 0; i < nbytes; ++i) p[i] = static_cast<char>(bits >> (8 * i));
}
inline void StoreDouble(char* p, double d) {
  uint64_t u;
  std::memcpy(&u, &d, 8);
  StoreLE(p, u, 8);
}
/// Appends; for many values, size the output once and Store* into it instead.
void PutLE(std::string* out, uint64_t bits, int nbytes);
void PutDouble(std::string* out, double d);
void PutFloat(std::string* out, float f);
uint64_t GetLE(const char* p, int nbytes);
float GetFloat(const char* p);

// ---------------------------------------------------------------------------
// Text: lines, tokens, numbers

/// Splits text into lines (LF or CRLF), strips `comment` to end of line, counts lines.
class LineReader {
 public:
  LineReader(absl::string_view text, absl::string_view source, char comment);

  /// The next line; false at the end of the text.
  bool Next(absl::string_view* line);
  /// The next line with at least one token; false at the end of the text.
  bool NextTokens(std::vector<absl::string_view>* tokens);
  /// Byte offset just past the last line returned.
  size_t position() const { return std::min(pos_, text_.size()); }
  /// The unread bytes [cursor(), end()), for a caller that parses a line itself and
  /// then consumes it with SkipLine (the next line starts at `next`).
  const char* cursor() const { return text_.data() + position(); }
  const char* end() const { return text_.data() + text_.size(); }
  void SkipLine(const char* next) {
    pos_ = static_cast<size_t>(next - text_.data());
    ++line_number_;
  }
  size_t remaining() const { return text_.size() - position(); }
  int64_t line_number() const { return line_number_; }
  /// INVALID_ARGUMENT "<source>: line <n>: <what>".
  absl::Status Error(absl::string_view what) const { return ErrorAt(line_number_, what); }
  absl::Status ErrorAt(int64_t line, absl::string_view what) const;

 private:
  absl::string_view text_, source_;
  char comment_;
  enum : uint8_t { kToken, kSeparator, kLineEnd };  // byte classes for NextTokens
  std::array<uint8_t, 256> class_{};
  size_t pos_ = 0;
  int64_t line_number_ = 0;
};

// Fast path of the text readers: plain lines read straight from the bytes, no tokens.
// Each function returns where reading continues, or nullptr for anything it would not
// read exactly as the general path (LineReader tokens, ParseDouble) does; the reader
// then leaves that line to the general path, with its checks and error messages.

inline bool IsBlank(char c) { return c == ' ' || c == '\t'; }
inline bool IsDigit(char c) { return static_cast<unsigned>(c - '0') <= 9; }
inline const char* SkipBlanks(const char* p, const char* end) {
  while (p < end && IsBlank(*p)) ++p;
  return p;
}

/// Where the next line starts if only blanks and the line's end ("\n", "\r\n" or the
/// end of the text) follow p; else nullptr.
inline const char* LineEnd(const char* p, const char* end) {
  p = SkipBlanks(p, end);
  if (p == end) return end;
  if (*p == '\n') return p + 1;
  if (*p == '\r' && p + 1 < end && p[1] == '\n') return p + 2;
  return nullptr;
}

/// Three blank-separated finite numbers from p, then the line's end. std::from_chars
/// reads each on the bytes; its answer is ParseDouble's for the token, which ends where
/// from_chars stops (a blank or the line's end must follow).
/// `blank_first`: blanks must also come before the first number (OBJ's "v" line after
/// its "v").
inline const char* FastCoordinates(const char* p, const char* end, double xyz[3], bool blank_first = false) {
  for (int c = 0; c < 3; ++c) {
    if (c > 0 || blank_first) {
      if (p == end || !IsBlank(*p)) return nullptr;
      do ++p;
      while (p < end && IsBlank(*p));
    }
    const std::from_chars_result r = std::from_chars(p, end, xyz[c]);
    if (r.ec != std::errc() || !std::isfinite(xyz[c])) return nullptr;
    p = r.ptr;
  }
  return LineEnd(p, end);
}

/// The value of the n digits (1 <= n <= 8) at p, which has 8 readable bytes: one load
/// and a multiply-shift (the digits moved to the word's top bytes, the bytes below them
/// read as leading zeros).
inline uint64_t EightDigitsValue(const char* p, int n) {
  uint64_t w;
  std::memcpy(&w, p, 8);  // little-endian: p[0] in the low byte
  uint64_t d = (w ^ 0x3030303030303030ull) << (8 * (8 - n));
  d = d * 10 + (d >> 8);
  return (((d & 0x000000ff000000ffull) * (100 + (1000000ull << 32))) +
          (((d >> 16) & 0x000000ff000000ffull) * (1 + (10000ull << 32)))) >>
         32;
}

/// The decimal digits at p (a digit; up to 10 of them) as *value; where they end
/// (nullptr: more than 10).
/// Fewer than 8 digits cost one 8-byte load and no branch per digit (SWAR: the digits
/// moved to the word's top bytes, the bytes below them read as leading zeros, then
/// EightDigitsValue).
inline const char* FastDigits(const char* p, const char* end, uint64_t* value) {
  if (end - p >= 8) {
    uint64_t w;
    std::memcpy(&w, p, 8);  // little-endian: p[0] in the low byte
    const uint64_t t = w ^ 0x3030303030303030ull;  // digits: bytes 0-9
    const uint64_t non_digit =
        (((t & 0x7f7f7f7f7f7f7f7full) + 0x7676767676767676ull) | t) & 0x8080808080808080ull;
    const int n = non_digit == 0 ? 8 : __builtin_ctzll(non_digit) / 8;
    if (n < 8) {
      *value = EightDigitsValue(p, n);
      return p + n;
    }
  }
  const char* const first = p;
  uint64_t k = 0;
  while (p < end && IsDigit(*p)) {
    if (p - first == 10) return nullptr;
    k = 10 * k + static_cast<uint64_t>(*p++ - '0');
  }
  *value = k;
  return p;
}

/// Three coordinates from tok[first], tok[first + 1], tok[first + 2].
absl::Status ParseCoordinates(const LineReader& lines, const std::vector<absl::string_view>& tok,
                              size_t first, double p[3]);

/// A number token (absl::SimpleAtod's syntax and values, faster); false if it is not one.
bool ParseDouble(absl::string_view token, double* value);

/// A decimal integer token; false if it is not one (or overflows int64).
bool ParseInteger(absl::string_view token, int64_t* value);

/// OK for 3 or 4 corners, else the line's error naming the face.
absl::Status CheckFaceSize(const LineReader& lines, int64_t face, int64_t n);

/// "<source>: header claims <count> <what> but only <available> bytes follow".
absl::Status CountError(absl::string_view source, absl::string_view what, int64_t count,
                        size_t available);

/// Vertex and face lines of OBJ ("v x y z", "f 1 2 3": 1-based) or OFF ("x y z",
/// "3 0 1 2"), coordinates with %.17g (exact round trip).
enum class TextDialect { kObj, kOff };
void AppendTextBody(std::string* out, const Mesh& mesh, TextDialect dialect);

}  // namespace geomfit::mesh_io
