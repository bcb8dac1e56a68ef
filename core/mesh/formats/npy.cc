// NumPy .npy output.
#include <algorithm>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/io.h"

namespace geomfit {
namespace {

/// Magic, version, header length and the header dict padded to a multiple of 64 bytes.
std::string NpyHeader(int64_t rows, int64_t cols) {
  std::string dict = absl::StrFormat(
      "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, %d), }", rows, cols);
  // Magic (6) + version (2) + header length (2) + dict + padding + '\n': multiple of 64.
  dict.resize((10 + dict.size() + 1 + 63) / 64 * 64 - 10 - 1, ' ');
  dict += '\n';
  std::string out("\x93NUMPY\x01\x00", 8);
  mesh_io::PutLE(&out, dict.size(), 2);
  return out + dict;
}

/// Doubles in place as little-endian bytes (nothing to do on little-endian machines).
void ToLittleEndian(double* values, size_t n) {
  char* p = reinterpret_cast<char*>(values);
  for (size_t i = 0; i < n; ++i, p += 8) mesh_io::StoreDouble(p, values[i]);
}

}  // namespace

std::string FormatNpy(const Eigen::Ref<const RowMajorMatrixXd>& a) {
  std::string out = NpyHeader(a.rows(), a.cols());
  const size_t head = out.size();
  out.resize(head + 8 * a.size());  // one block, filled in place
  char* p = out.data() + head;
  for (Eigen::Index r = 0; r < a.rows(); ++r)
    for (Eigen::Index c = 0; c < a.cols(); ++c, p += 8) mesh_io::StoreDouble(p, a(r, c));
  return out;
}

absl::Status WriteNpy(const std::string& path, const Eigen::Ref<const RowMajorMatrixXd>& a) {
  return WriteNpy(path, a.rows(), a.cols(), [&](int64_t begin, int64_t end, double* out) {
    for (int64_t r = begin; r < end; ++r)
      for (Eigen::Index c = 0; c < a.cols(); ++c) *out++ = a(r, c);
  });
}

absl::Status WriteNpy(const std::string& path, int64_t rows, int64_t cols,
                      const std::function<void(int64_t begin, int64_t end, double* out)>& fill) {
  const std::string header = NpyHeader(rows, cols);
  // Blocks of ~256 KB: written from the cache, ~2x less CPU than one write of the whole
  // table (measured for 9 MB: the kernel's copy into the page cache reads a cold buffer).
  const int64_t block = cols == 0 ? rows : std::max<int64_t>(1, (256 << 10) / (8 * cols));
  std::vector<double> buffer(static_cast<size_t>(std::min(rows, block) * cols));
  int64_t next = -1;  // -1: the header
  return WriteFileAtomicallyInPieces(path, [&]() -> std::string_view {
    if (next < 0) {
      next = 0;
      return header;
    }
    if (next >= rows || cols == 0) return {};
    const int64_t end = std::min(rows, next + block);
    fill(next, end, buffer.data());
    const size_t n = static_cast<size_t>((end - next) * cols);
    ToLittleEndian(buffer.data(), n);
    next = end;
    return std::string_view(reinterpret_cast<const char*>(buffer.data()), 8 * n);
  });
}

}  // namespace geomfit
