// NumPy .npy output.
#include <string>

#include "absl/strings/str_format.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/io.h"

namespace geomfit {

using mesh_io::PutLE;

std::string FormatNpy(const Eigen::Ref<const RowMajorMatrixXd>& a) {
  std::string dict = absl::StrFormat(
      "{'descr': '<f8', 'fortran_order': False, 'shape': (%d, %d), }", a.rows(), a.cols());
  // Magic (6) + version (2) + header length (2) + dict + padding + '\n': multiple of 64.
  dict.resize((10 + dict.size() + 1 + 63) / 64 * 64 - 10 - 1, ' ');
  dict += '\n';
  std::string out("\x93NUMPY\x01\x00", 8);
  PutLE(&out, dict.size(), 2);
  out += dict;
  const size_t head = out.size();
  out.resize(head + 8 * a.size());  // one block, filled in place
  char* p = out.data() + head;
  for (Eigen::Index r = 0; r < a.rows(); ++r)
    for (Eigen::Index c = 0; c < a.cols(); ++c, p += 8) mesh_io::StoreDouble(p, a(r, c));
  return out;
}

absl::Status WriteNpy(const std::string& path, const Eigen::Ref<const RowMajorMatrixXd>& a) {
  return WriteFileAtomically(path, FormatNpy(a));
}

}  // namespace geomfit
