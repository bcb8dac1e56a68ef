// Writing per-vertex differential quantities as TSV, NPY or VTP (both CLI modes).
#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "clients/cpp/cli/cli.h"
#include "core/util/status_macros.h"
#include "core/reconstruction/meshing.h"

namespace geomfit::cli {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

/// Value (v, c) of an optional per-vertex array; NaN if the array was not computed.
template <typename M>
double At(const M& m, int v, int c) {
  return v < m.rows() ? m(v, c) : kNaN;
}

int NumVertices(const Differentials& d) {
  return static_cast<int>(
      std::max({d.normals.rows(), d.mean.rows(), d.gaussian.rows(), d.k1.rows(), d.dir1.rows(),
                d.tensor.rows(), static_cast<Eigen::Index>(d.diagnostics.size())}));
}

/// Columns of DifferentialsTable: normal, H, K, k1, k2, dir1, dir2.
constexpr int kTableColumns = 13;

/// Row v of DifferentialsTable(d), stored at row[0..kTableColumns).
void TableRow(const Differentials& d, int v, double* row) {
  for (int c = 0; c < 3; ++c) {
    row[c] = At(d.normals, v, c);
    row[7 + c] = At(d.dir1, v, c);
    row[10 + c] = At(d.dir2, v, c);
  }
  row[3] = At(d.mean, v, 0);
  row[4] = At(d.gaussian, v, 0);
  row[5] = At(d.k1, v, 0);
  row[6] = At(d.k2, v, 0);
}

/// Rows of `m` moved from relabelled to source order (empty arrays stay empty).
template <typename M>
void ToSourceOrder(const std::vector<int32_t>& source, M* m) {
  if (m->rows() == 0) return;
  M out(m->rows(), m->cols());
  for (size_t i = 0; i < source.size(); ++i) out.row(source[i]) = m->row(static_cast<Eigen::Index>(i));
  *m = std::move(out);
}

/// A #V x cols field copied out of any per-vertex array.
template <typename M>
PointField Field(const std::string& name, const M& m) {
  return {name, Eigen::MatrixXd(m.template cast<double>()), VtkType::kFloat64};
}

}  // namespace

absl::StatusOr<OutputKind> OutputKindFromPath(const std::string& path) {
  const std::string lower = absl::AsciiStrToLower(path);
  if (path == "-") return OutputKind::kTsv;
  if (absl::EndsWith(lower, ".tsv") || absl::EndsWith(lower, ".txt")) return OutputKind::kTsv;
  if (absl::EndsWith(lower, ".npy")) return OutputKind::kNpy;
  if (absl::EndsWith(lower, ".vtp")) return OutputKind::kVtp;
  if (absl::EndsWith(lower, ".vtu")) return OutputKind::kVtu;
  if (IsStreamPath(path)) return OutputKind::kTsv;  // /dev/null, a pipe
  return UsageError(absl::StrCat("output '", path,
                                 "': unknown extension (expected .vtp, .vtu, .npy, .tsv or .txt, or - for stdout)"));
}

bool OutputNeedsMesh(const std::string& path) {
  const OutputKind kind = OutputKindFromPath(path).value_or(OutputKind::kTsv);
  return kind == OutputKind::kVtp || kind == OutputKind::kVtu;
}

const std::vector<std::string>& DifferentialsColumns() {
  static const std::vector<std::string> columns = {
      "nx",  "ny",  "nz",  "H",   "K",   "k1",          "k2",     "e1x",
      "e1y", "e1z", "e2x", "e2y", "e2z", "degree_used", "points", "flags"};
  return columns;
}

RowMajorMatrixXd DifferentialsTable(const Differentials& d) {
  const int nv = NumVertices(d);
  RowMajorMatrixXd t(nv, kTableColumns);
  for (int v = 0; v < nv; ++v) TableRow(d, v, t.row(v).data());
  return t;
}

std::string DifferentialsTsv(const Differentials& d) {
  const RowMajorMatrixXd t = DifferentialsTable(d);
  std::string out = "# " + absl::StrJoin(DifferentialsColumns(), "\t");  // '#': numpy.loadtxt skips it
  out += '\n';
  for (int v = 0; v < t.rows(); ++v) {
    for (int c = 0; c < t.cols(); ++c) absl::StrAppendFormat(&out, "%.17g\t", t(v, c));
    const VertexDiagnostics diag =
        v < static_cast<int>(d.diagnostics.size()) ? d.diagnostics[v] : VertexDiagnostics{};
    absl::StrAppend(&out, static_cast<int>(diag.degree_used), "\t", static_cast<int>(diag.points),
                    "\t", static_cast<int>(diag.flags), "\n");
  }
  return out;
}

std::vector<PointField> DifferentialsFields(const Differentials& d) {
  std::vector<PointField> fields;
  if (d.normals.rows() > 0) fields.push_back(Field("Normals", d.normals));
  if (d.mean.rows() > 0) fields.push_back(Field("MeanCurvature", d.mean));
  if (d.gaussian.rows() > 0) fields.push_back(Field("GaussianCurvature", d.gaussian));
  if (d.k1.rows() > 0) fields.push_back(Field("k1", d.k1));
  if (d.k2.rows() > 0) fields.push_back(Field("k2", d.k2));
  if (d.dir1.rows() > 0) fields.push_back(Field("Direction1", d.dir1));
  if (d.dir2.rows() > 0) fields.push_back(Field("Direction2", d.dir2));
  if (d.tensor.rows() > 0) fields.push_back(Field("CurvatureTensor", d.tensor));
  if (!d.diagnostics.empty()) {
    const int nv = static_cast<int>(d.diagnostics.size());
    // "StencilPoints", not "Points": VTK names the geometry array Points.
    PointField degree{"DegreeUsed", Eigen::MatrixXd(nv, 1), VtkType::kInt32},
        points{"StencilPoints", Eigen::MatrixXd(nv, 1), VtkType::kInt32},
        flags{"Flags", Eigen::MatrixXd(nv, 1), VtkType::kUInt8};
    for (int v = 0; v < nv; ++v) {
      degree.values(v, 0) = d.diagnostics[v].degree_used;
      points.values(v, 0) = d.diagnostics[v].points;
      flags.values(v, 0) = d.diagnostics[v].flags;
    }
    fields.push_back(std::move(degree));
    fields.push_back(std::move(points));
    fields.push_back(std::move(flags));
  }
  return fields;
}

absl::Status WriteLagrangeVtu(const std::string& path, const HighOrderMesh& ho) {
  constexpr uint8_t kVtkLagrangeTriangle = 69, kVtkLagrangeQuadrilateral = 70;
  const int k = ho.order, tri_nodes = (k + 1) * (k + 2) / 2;
  VtkCells cells;
  for (size_t f = 0; f + 1 < ho.offsets.size(); ++f) {
    const int32_t* e = ho.elements.data() + ho.offsets[f];
    const int n = ho.offsets[f + 1] - ho.offsets[f];
    if (n == tri_nodes) {  // corners, edges 0-1, 1-2, 2-0, interior: VTK's order
      cells.connectivity.insert(cells.connectivity.end(), e, e + n);
      cells.types.push_back(kVtkLagrangeTriangle);
    } else {
      // VTK runs the edges of a quadrilateral along its parameter directions: 0-1, 1-2,
      // 3-2, 0-3; ours run around it (0-1, 1-2, 2-3, 3-0), so the last two reverse.
      cells.connectivity.insert(cells.connectivity.end(), e, e + 4 + 2 * (k - 1));
      for (int edge = 2; edge < 4; ++edge)
        for (int t = k - 2; t >= 0; --t) cells.connectivity.push_back(e[4 + edge * (k - 1) + t]);
      cells.connectivity.insert(cells.connectivity.end(), e + 4 + 4 * (k - 1), e + n);
      cells.types.push_back(kVtkLagrangeQuadrilateral);
    }
    cells.offsets.push_back(static_cast<int64_t>(cells.connectivity.size()));
  }
  return WriteVtu(path, ho.nodes, cells, {});
}

absl::StatusOr<MeshFormat> MeshOutputFormat(const std::string& path) {
  if (IsStreamPath(path) && !FormatFromPath(path).ok()) return MeshFormat::kObj;
  absl::StatusOr<MeshFormat> format = FormatFromPath(path);
  if (!format.ok()) return UsageError(format.status().message());
  return format;
}

absl::Status WriteMeshOutput(const Mesh& mesh, const std::string& path, const VtkOptions& vtk) {
  if (FormatFromPath(path).ok()) return WriteMesh(mesh, path, vtk);  // streams too (WriteFileAtomically)
  GF_ASSIGN_OR_RETURN(const MeshFormat format, MeshOutputFormat(path));
  GF_ASSIGN_OR_RETURN(const std::string bytes, FormatMesh(mesh, format));
  return WriteFileAtomically(path, bytes);
}

absl::StatusOr<VtkEncoding> VtkEncodingFromFlags(bool ascii, bool zlib) {
  if (ascii && zlib) return UsageError("--ascii and --zlib exclude each other (zlib compresses binary arrays)");
  return ascii ? VtkEncoding::kAscii : zlib ? VtkEncoding::kAppendedZlib : VtkEncoding::kAppended;
}

absl::Status WriteDifferentials(const std::string& path, const Mesh& mesh, const Differentials& d,
                                VtkEncoding encoding) {
  if (path.empty() || path == "-") {
    const std::string tsv = DifferentialsTsv(d);
    if (std::fwrite(tsv.data(), 1, tsv.size(), stdout) != tsv.size() || std::fflush(stdout) != 0)
      return absl::ErrnoToStatus(errno, "cannot write to standard output");
    return absl::OkStatus();
  }
  auto kind = OutputKindFromPath(path);
  if (!kind.ok()) return kind.status();
  switch (*kind) {
    case OutputKind::kTsv: return WriteFileAtomically(path, DifferentialsTsv(d));
    case OutputKind::kNpy:  // DifferentialsTable's rows, packed a block at a time (no whole table)
      return WriteNpy(path, NumVertices(d), kTableColumns, [&](int64_t begin, int64_t end, double* out) {
        for (int64_t v = begin; v < end; ++v, out += kTableColumns) TableRow(d, static_cast<int>(v), out);
      });
    case OutputKind::kVtp:
    case OutputKind::kVtu: {
      const std::vector<PointField> fields = DifferentialsFields(d);
      VtkOptions options;
      options.encoding = encoding;
      for (const PointField& f : fields) {
        if (f.name == "Normals") options.normals = f.name;
        if (f.name == "MeanCurvature") options.scalars = f.name;
      }
      return *kind == OutputKind::kVtp ? WriteVtp(path, mesh, fields, options)
                                       : WriteVtu(path, mesh, fields, options);
    }
  }
  return absl::InternalError("unreachable");
}

uint32_t OutputQuantities(const std::string& path) {
  if (path.empty() || path == "-") return kAllQuantities & ~kCurvatureTensor;
  const OutputKind kind = OutputKindFromPath(path).value_or(OutputKind::kVtp);
  return kind == OutputKind::kVtp || kind == OutputKind::kVtu ? kAllQuantities
                                                              : kAllQuantities & ~kCurvatureTensor;
}

Differentials InSourceOrder(Differentials d, const std::vector<int32_t>& source) {
  if (source.empty()) return d;
  ToSourceOrder(source, &d.normals);
  ToSourceOrder(source, &d.mean);
  ToSourceOrder(source, &d.gaussian);
  ToSourceOrder(source, &d.k1);
  ToSourceOrder(source, &d.k2);
  ToSourceOrder(source, &d.dir1);
  ToSourceOrder(source, &d.dir2);
  ToSourceOrder(source, &d.tensor);
  if (!d.diagnostics.empty()) {
    std::vector<VertexDiagnostics> diagnostics(d.diagnostics.size());
    for (size_t i = 0; i < source.size(); ++i) diagnostics[source[i]] = d.diagnostics[i];
    d.diagnostics = std::move(diagnostics);
  }
  return d;
}

absl::Status WriteRelabelledDifferentials(const std::string& path, const Mesh& mesh, Differentials d,
                                          const std::vector<int32_t>& source, VtkEncoding encoding) {
  if (source.empty() || path.empty() || path == "-" ||
      OutputKindFromPath(path).value_or(OutputKind::kTsv) != OutputKind::kNpy)
    return WriteDifferentials(path, mesh, InSourceOrder(std::move(d), source), encoding);
  // .npy: d's rows packed into the table in d's order (sequential reads), then each
  // block of the file gathered from the table's rows as it is written: one 104-byte
  // row per vertex read in scattered order instead of seven arrays' (2.5x less time).
  // The table in pieces of kPieceRows rows (832 KB): allocated while d is alive, they
  // fit in the heap's holes (the fit's freed records and stencils) where one 8.6 MB
  // table (87k vertices) went above them all, onto fresh pages.
  std::vector<int32_t> row_of(source.size());
  for (size_t i = 0; i < source.size(); ++i) row_of[source[i]] = static_cast<int32_t>(i);
  constexpr int kPieceBits = 13, kPieceRows = 1 << kPieceBits;
  const int64_t nv = NumVertices(d);
  std::vector<std::unique_ptr<double[]>> pieces((nv + kPieceRows - 1) / kPieceRows);
  for (size_t p = 0; p < pieces.size(); ++p) {
    const int64_t first = static_cast<int64_t>(p) * kPieceRows, rows = std::min<int64_t>(kPieceRows, nv - first);
    pieces[p].reset(new double[rows * kTableColumns]);  // not zeroed: every row is written
    for (int64_t r = 0; r < rows; ++r) TableRow(d, static_cast<int>(first + r), pieces[p].get() + kTableColumns * r);
  }
  d = Differentials();
  const auto row = [&](int32_t r) { return pieces[r >> kPieceBits].get() + kTableColumns * (r & (kPieceRows - 1)); };
  return WriteNpy(path, nv, kTableColumns, [&](int64_t begin, int64_t end, double* out) {
    constexpr int64_t kAhead = 8;
    for (int64_t v = begin; v < end; ++v, out += kTableColumns) {
      if (v + kAhead < nv) {
        const double* ahead = row(row_of[v + kAhead]);
        __builtin_prefetch(ahead), __builtin_prefetch(ahead + 12);
      }
      std::memcpy(out, row(row_of[v]), kTableColumns * sizeof(double));
    }
  });
}

}  // namespace geomfit::cli
