#include "proto/wire.h"

#include <algorithm>
#include <cstring>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "core/quantities/differentials.h"
#include "core/util/status_macros.h"

namespace geomfit::wire {
namespace {

template <typename T, typename Array>
void Encode(const T* data, int64_t rows, int64_t cols, Array* out) {
  out->clear_shape();
  out->add_shape(rows);
  if (cols > 0) out->add_shape(cols);
  const size_t bytes = sizeof(T) * static_cast<size_t>(rows) * static_cast<size_t>(cols > 0 ? cols : 1);
  out->mutable_data()->assign(reinterpret_cast<const char*>(data), bytes);
}

template <typename T, typename Array>
absl::StatusOr<ArrayView<T>> View(const Array& a, absl::string_view field,
                                  std::initializer_list<int64_t> allowed_cols) {
  const bool one_d = allowed_cols.size() == 1 && *allowed_cols.begin() == 0;
  const int want_dims = one_d ? 1 : 2;
  if (a.shape_size() != want_dims) {
    return absl::InvalidArgumentError(absl::StrCat(field, ": shape has ", a.shape_size(),
                                                   " dimensions, expected ", want_dims));
  }
  const int64_t rows = a.shape(0);
  const int64_t cols = one_d ? 1 : a.shape(1);
  if (rows < 0 || rows > (int64_t{1} << 31)) {
    return absl::InvalidArgumentError(absl::StrCat(field, ": invalid row count ", rows));
  }
  if (!one_d && std::find(allowed_cols.begin(), allowed_cols.end(), cols) == allowed_cols.end()) {
    return absl::InvalidArgumentError(absl::StrCat(field, ": shape[1] is ", cols, ", expected ",
                                                   absl::StrJoin(allowed_cols, " or ")));
  }
  const size_t want = sizeof(T) * static_cast<size_t>(rows) * static_cast<size_t>(cols);
  if (a.data().size() != want) {
    return absl::InvalidArgumentError(absl::StrCat(field, ": data has ", a.data().size(),
                                                   " bytes, shape [", absl::StrJoin(a.shape(), ", "),
                                                   "] needs ", want));
  }
  return ArrayView<T>{a.data().data(), rows, cols};
}

template <typename Matrix, typename Array>
absl::StatusOr<Matrix> Decode(const Array& a, absl::string_view field,
                              std::initializer_list<int64_t> allowed_cols) {
  GF_ASSIGN_OR_RETURN(const auto v, (View<typename Matrix::Scalar>(a, field, allowed_cols)));
  Matrix m(v.rows, v.cols);
  v.CopyTo(m.data());
  return m;
}

}  // namespace

void EncodeDoubles(const double* data, int64_t rows, int64_t cols, v1::DoubleArray* out) {
  Encode(data, rows, cols, out);
}
void EncodeInts(const int32_t* data, int64_t rows, int64_t cols, v1::Int32Array* out) {
  Encode(data, rows, cols, out);
}

absl::StatusOr<ArrayView<double>> ViewDoubles(const v1::DoubleArray& a, absl::string_view field,
                                              std::initializer_list<int64_t> allowed_cols) {
  return View<double>(a, field, allowed_cols);
}
absl::StatusOr<ArrayView<int32_t>> ViewInts(const v1::Int32Array& a, absl::string_view field,
                                            std::initializer_list<int64_t> allowed_cols) {
  return View<int32_t>(a, field, allowed_cols);
}
absl::StatusOr<RowsXd> DecodeDoubles(const v1::DoubleArray& a, absl::string_view field,
                                     std::initializer_list<int64_t> allowed_cols) {
  return Decode<RowsXd>(a, field, allowed_cols);
}
absl::StatusOr<RowsXi> DecodeInts(const v1::Int32Array& a, absl::string_view field,
                                  std::initializer_list<int64_t> allowed_cols) {
  return Decode<RowsXi>(a, field, allowed_cols);
}

absl::StatusOr<FitOptions> FromProto(const v1::FitOptions& p) { return FromProto(p, FitOptions()); }

absl::StatusOr<FitOptions> FromProto(const v1::FitOptions& p, FitOptions o) {
  if (p.degree() != 0) o.degree = p.degree();
  if (p.rings() != 0) o.rings = p.rings();
  if (p.has_adaptive()) o.adaptive = p.adaptive();
  switch (p.method()) {
    case v1::FIT_METHOD_UNSPECIFIED:
    case v1::FIT_METHOD_LHF: o.method = FitMethod::kLHF; break;
    case v1::FIT_METHOD_LOP: o.method = FitMethod::kLOP; break;
    case v1::FIT_METHOD_XU: o.method = FitMethod::kXu; break;
    case v1::FIT_METHOD_LSCM: o.method = FitMethod::kLSCM; break;
    default: return absl::InvalidArgumentError(absl::StrCat("options.method: unknown value ", p.method()));
  }
  switch (p.noise()) {
    case v1::NOISE_MODE_UNSPECIFIED:
    case v1::NOISE_MODE_OFF: o.noise = NoiseMode::kOff; break;
    case v1::NOISE_MODE_ON: o.noise = NoiseMode::kOn; break;
    case v1::NOISE_MODE_AUTO: o.noise = NoiseMode::kAuto; break;
    default: return absl::InvalidArgumentError(absl::StrCat("options.noise: unknown value ", p.noise()));
  }
  if (p.has_smoothing_passes()) o.smoothing_passes = p.smoothing_passes();
  if (p.normal_degree() != 0) o.normal_degree = p.normal_degree();
  if (p.hermite_hessian()) o.hermite_hessian = true;
  if (p.slope_refinement() != 0) o.slope_refinement = p.slope_refinement();
  if (p.has_cubic_hermite()) o.cubic_hermite = p.cubic_hermite();
  if (p.has_plane_hermite()) o.plane_hermite = p.plane_hermite();
  if (p.has_quadratic_hermite()) o.quadratic_hermite = p.quadratic_hermite();
  if (p.has_jet_hermite()) o.jet_hermite = p.jet_hermite() ? JetHermiteMode::kOn : JetHermiteMode::kOff;
  switch (p.solver()) {
    case v1::WLS_SOLVER_UNSPECIFIED:
    case v1::WLS_SOLVER_QR: o.solver = WlsSolver::kQR; break;
    case v1::WLS_SOLVER_SVD: o.solver = WlsSolver::kSVD; break;
    default: return absl::InvalidArgumentError(absl::StrCat("options.solver: unknown value ", p.solver()));
  }
  if (p.has_safeguard_angle_deg()) o.safeguard_angle_deg = p.safeguard_angle_deg();
  if (p.has_interpolate()) o.interpolate = p.interpolate();
  if (p.has_two_pass()) o.two_pass = p.two_pass();
  switch (p.frame_normals()) {
    case v1::NORMAL_WEIGHTING_UNSPECIFIED:
    case v1::NORMAL_WEIGHTING_AREA: o.frame_normals = NormalWeighting::kArea; break;
    case v1::NORMAL_WEIGHTING_ANGLE: o.frame_normals = NormalWeighting::kAngle; break;
    default:
      return absl::InvalidArgumentError(absl::StrCat("options.frame_normals: unknown value ", p.frame_normals()));
  }
  if (p.has_weight_epsilon()) o.weight_epsilon = p.weight_epsilon();
  if (p.min_points_factor() != 0) o.min_points_factor = p.min_points_factor();
  if (p.has_oscillation_safeguard()) o.oscillation_safeguard = p.oscillation_safeguard();
  if (p.has_boundary_points_factor()) o.boundary_points_factor = p.boundary_points_factor();
  if (p.has_max_rings()) o.max_rings = p.max_rings();
  if (p.max_points() != 0) o.max_points = p.max_points();
  if (p.cond_threshold_size() != 0) {
    if (p.cond_threshold_size() != kMaxDegree) {
      return absl::InvalidArgumentError(absl::StrCat("options.cond_threshold: has ", p.cond_threshold_size(),
                                                     " values, expected ", kMaxDegree, " (degrees 1..",
                                                     kMaxDegree, ") or none"));
    }
    for (int d = 1; d <= kMaxDegree; ++d) o.cond_threshold[d] = p.cond_threshold(d - 1);
  }
  GF_RETURN_IF_ERROR(ValidateFitOptions(o));
  return o;
}

absl::StatusOr<ReconstructionOptions> FromProto(const v1::ReconstructionOptions& p) {
  ReconstructionOptions o;
  absl::StatusOr<FitOptions> fit = FromProto(p.fit(), o.fit);
  if (!fit.ok()) return absl::InvalidArgumentError(absl::StrCat("fit: ", fit.status().message()));
  o.fit = *fit;
  switch (p.method()) {
    case v1::RECONSTRUCTION_UNSPECIFIED:
    case v1::RECONSTRUCTION_WALF: o.method = ReconstructionMethod::kWalf; break;
    case v1::RECONSTRUCTION_CMF: o.method = ReconstructionMethod::kCmf; break;
    case v1::RECONSTRUCTION_LINEAR: o.method = ReconstructionMethod::kLinear; break;
    default: return absl::InvalidArgumentError(absl::StrCat("method: unknown reconstruction ", p.method()));
  }
  o.feature_angle_deg = p.feature_angle_deg();
  if (p.feature_edges().shape_size() > 0) {
    GF_ASSIGN_OR_RETURN(const RowsXi e, DecodeInts(p.feature_edges(), "feature_edges", {2}));
    for (Eigen::Index i = 0; i < e.rows(); ++i) o.feature_edges.emplace_back(e(i, 0), e(i, 1));
  }
  GF_RETURN_IF_ERROR(o.Validate());
  return o;
}

v1::ReconstructionOptions ToProto(const ReconstructionOptions& o) {
  v1::ReconstructionOptions p;
  *p.mutable_fit() = ToProto(o.fit);
  switch (o.method) {
    case ReconstructionMethod::kWalf: p.set_method(v1::RECONSTRUCTION_WALF); break;
    case ReconstructionMethod::kCmf: p.set_method(v1::RECONSTRUCTION_CMF); break;
    case ReconstructionMethod::kLinear: p.set_method(v1::RECONSTRUCTION_LINEAR); break;
  }
  p.set_feature_angle_deg(o.feature_angle_deg);
  if (!o.feature_edges.empty())
    EncodeInts(&o.feature_edges[0].first, static_cast<int64_t>(o.feature_edges.size()), 2, p.mutable_feature_edges());
  return p;
}

v1::FitOptions ToProto(const FitOptions& o) {
  v1::FitOptions p;
  p.set_degree(o.degree);
  p.set_rings(o.rings);
  p.set_adaptive(o.adaptive);
  switch (o.method) {
    case FitMethod::kLHF: p.set_method(v1::FIT_METHOD_LHF); break;
    case FitMethod::kLOP: p.set_method(v1::FIT_METHOD_LOP); break;
    case FitMethod::kXu: p.set_method(v1::FIT_METHOD_XU); break;
    case FitMethod::kLSCM: p.set_method(v1::FIT_METHOD_LSCM); break;
  }
  p.set_noise(o.noise == NoiseMode::kOn     ? v1::NOISE_MODE_ON
              : o.noise == NoiseMode::kAuto ? v1::NOISE_MODE_AUTO
                                            : v1::NOISE_MODE_OFF);
  p.set_smoothing_passes(o.smoothing_passes);
  p.set_normal_degree(o.normal_degree);
  p.set_hermite_hessian(o.hermite_hessian);
  p.set_slope_refinement(o.slope_refinement);
  p.set_cubic_hermite(o.cubic_hermite);
  p.set_plane_hermite(o.plane_hermite);
  if (o.quadratic_hermite) p.set_quadratic_hermite(true);  // unset = off
  if (o.jet_hermite != JetHermiteMode::kAuto) p.set_jet_hermite(o.jet_hermite == JetHermiteMode::kOn);  // unset = auto
  p.set_solver(o.solver == WlsSolver::kSVD ? v1::WLS_SOLVER_SVD : v1::WLS_SOLVER_QR);
  p.set_safeguard_angle_deg(o.safeguard_angle_deg);
  p.set_interpolate(o.interpolate);
  p.set_two_pass(o.two_pass);
  p.set_frame_normals(o.frame_normals == NormalWeighting::kAngle ? v1::NORMAL_WEIGHTING_ANGLE
                                                                 : v1::NORMAL_WEIGHTING_AREA);
  p.set_weight_epsilon(o.weight_epsilon);
  p.set_min_points_factor(o.min_points_factor);
  p.set_oscillation_safeguard(o.oscillation_safeguard);
  p.set_boundary_points_factor(o.boundary_points_factor);
  p.set_max_rings(o.max_rings);
  p.set_max_points(o.max_points);
  for (int d = 1; d <= kMaxDegree; ++d) p.add_cond_threshold(o.cond_threshold[d]);
  return p;
}

absl::StatusOr<uint32_t> QuantityMask(const google::protobuf::RepeatedField<int>& quantities) {
  if (quantities.empty()) return kNormals | kMeanCurvature | kGaussianCurvature | kPrincipalCurvatures;
  uint32_t mask = 0;
  for (int i = 0; i < quantities.size(); ++i) {
    switch (quantities[i]) {
      case v1::QUANTITY_NORMALS: mask |= kNormals; break;
      case v1::QUANTITY_MEAN_CURVATURE: mask |= kMeanCurvature; break;
      case v1::QUANTITY_GAUSSIAN_CURVATURE: mask |= kGaussianCurvature; break;
      case v1::QUANTITY_PRINCIPAL_CURVATURES: mask |= kPrincipalCurvatures; break;
      case v1::QUANTITY_PRINCIPAL_DIRECTIONS: mask |= kPrincipalDirections; break;
      case v1::QUANTITY_CURVATURE_TENSOR: mask |= kCurvatureTensor; break;
      default:
        return absl::InvalidArgumentError(
            absl::StrCat("quantities[", i, "]: unknown quantity ", quantities[i]));
    }
  }
  return mask;
}

void AddQuantities(uint32_t mask, v1::ComputeDifferentialsRequest* request) {
  const std::pair<uint32_t, v1::Quantity> table[] = {
      {kNormals, v1::QUANTITY_NORMALS},
      {kMeanCurvature, v1::QUANTITY_MEAN_CURVATURE},
      {kGaussianCurvature, v1::QUANTITY_GAUSSIAN_CURVATURE},
      {kPrincipalCurvatures, v1::QUANTITY_PRINCIPAL_CURVATURES},
      {kPrincipalDirections, v1::QUANTITY_PRINCIPAL_DIRECTIONS},
      {kCurvatureTensor, v1::QUANTITY_CURVATURE_TENSOR}};
  for (const auto& [bit, q] : table)
    if (mask & bit) request->add_quantities(q);
}

v1::FaceKind KindOf(const Mesh& mesh) {
  int quads = 0;
  for (int f = 0; f < mesh.NumFaces(); ++f) quads += mesh.FaceSize(f) == 4;
  if (quads == 0) return v1::FACE_KIND_TRIANGLE;
  return quads == mesh.NumFaces() ? v1::FACE_KIND_QUAD : v1::FACE_KIND_MIXED;
}

}  // namespace geomfit::wire

namespace geomfit::wire {

std::vector<v1::UploadMeshRequest> UploadChunks(const Mesh& mesh, v1::MeshHeader header, int64_t chunk_rows) {
  chunk_rows = std::max<int64_t>(1, chunk_rows);
  header.set_num_vertices(mesh.NumVertices());
  header.set_num_faces(mesh.NumFaces());
  header.set_face_kind(KindOf(mesh));
  std::vector<v1::UploadMeshRequest> out(1);
  *out[0].mutable_header() = std::move(header);
  for (int64_t b = 0; b < mesh.NumVertices(); b += chunk_rows) {
    const int64_t n = std::min<int64_t>(chunk_rows, mesh.NumVertices() - b);
    v1::PositionsChunk* c = out.emplace_back().mutable_positions();
    c->set_vertex_offset(b);
    EncodeDoubles(mesh.positions.data() + 3 * b, n, 3, c->mutable_positions());
  }
  const bool triangles = !mesh.HasQuads();
  for (int64_t b = 0; b < mesh.NumFaces(); b += chunk_rows) {
    const int64_t n = std::min<int64_t>(chunk_rows, mesh.NumFaces() - b);
    v1::FacesChunk* c = out.emplace_back().mutable_faces();
    c->set_face_offset(b);
    if (triangles) {
      const Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor> tri = mesh.faces.get().block(b, 0, n, 3);
      EncodeInts(tri.data(), n, 3, c->mutable_faces());
    } else {
      EncodeInts(mesh.faces.data() + 4 * b, n, 4, c->mutable_faces());
    }
  }
  return out;
}

std::vector<v1::UpdatePositionsRequest> UpdateChunks(PositionsRef positions, v1::UpdateHeader header,
                                                     int64_t chunk_rows) {
  chunk_rows = std::max<int64_t>(1, chunk_rows);
  std::vector<v1::UpdatePositionsRequest> out(1);
  *out[0].mutable_header() = std::move(header);
  for (int64_t b = 0; b < positions.rows(); b += chunk_rows) {
    const int64_t n = std::min<int64_t>(chunk_rows, positions.rows() - b);
    v1::PositionsChunk* c = out.emplace_back().mutable_positions();
    c->set_vertex_offset(b);
    EncodeDoubles(positions.data() + 3 * b, n, 3, c->mutable_positions());
  }
  return out;
}

namespace {

/// Copies one chunk array straight into rows [offset, offset + rows) of `dest`
/// (resized on first use to `total` rows). An empty array was not requested.
template <typename Dest>
absl::Status Place(const v1::DoubleArray& a, const std::string& field, int64_t offset, int64_t rows, int64_t total,
                   Dest* dest) {
  if (a.shape_size() == 0) return absl::OkStatus();
  constexpr bool kVector = Dest::ColsAtCompileTime == 1;
  constexpr int64_t kCols = kVector ? 1 : Dest::ColsAtCompileTime;
  const int want_dims = kVector ? 1 : 2;
  if (a.shape_size() != want_dims || a.shape(0) != rows || (!kVector && a.shape(1) != kCols)) {
    return absl::DataLossError(absl::StrCat(field, ": shape [", absl::StrJoin(a.shape(), ", "), "], expected [",
                                            rows, kVector ? "" : absl::StrCat(", ", kCols), "]"));
  }
  const size_t bytes = sizeof(double) * static_cast<size_t>(rows * kCols);
  if (a.data().size() != bytes) {
    return absl::DataLossError(absl::StrCat(field, ": ", a.data().size(), " bytes, expected ", bytes));
  }
  if (dest->rows() != total) dest->resize(total, kCols);
  if (bytes > 0) std::memcpy(dest->data() + offset * kCols, a.data().data(), bytes);
  return absl::OkStatus();
}

}  // namespace

absl::Status DifferentialsReader::Add(const v1::ComputeDifferentialsResponse& c) {
  const std::string where = absl::StrCat("chunk ", chunks_++);
  if (!started_) {
    if (!c.has_summary()) return absl::DataLossError(where + ": the first chunk carries no summary");
    summary_ = c.summary();
    started_ = true;
  } else if (c.has_summary()) {  // the last chunk completes the first one's summary
    if (c.summary().num_vertices() != summary_.num_vertices()) {
      return absl::DataLossError(absl::StrCat(where, ": summary of ", c.summary().num_vertices(),
                                              " vertices after one of ", summary_.num_vertices()));
    }
    summary_ = c.summary();
  }
  const int64_t total = summary_.num_vertices();
  if (c.vertex_offset() != rows_ || c.num_vertices() < 0 || rows_ + c.num_vertices() > total) {
    return absl::DataLossError(absl::StrCat(where, ": rows ", c.vertex_offset(), "+", c.num_vertices(),
                                            " do not continue at ", rows_, " of ", total));
  }
  const int64_t off = c.vertex_offset(), n = c.num_vertices();
  GF_RETURN_IF_ERROR(Place(c.normals(), where + " normals", off, n, total, &out_.normals));
  GF_RETURN_IF_ERROR(Place(c.mean(), where + " mean", off, n, total, &out_.mean));
  GF_RETURN_IF_ERROR(Place(c.gaussian(), where + " gaussian", off, n, total, &out_.gaussian));
  GF_RETURN_IF_ERROR(Place(c.k1(), where + " k1", off, n, total, &out_.k1));
  GF_RETURN_IF_ERROR(Place(c.k2(), where + " k2", off, n, total, &out_.k2));
  GF_RETURN_IF_ERROR(Place(c.dir1(), where + " dir1", off, n, total, &out_.dir1));
  GF_RETURN_IF_ERROR(Place(c.dir2(), where + " dir2", off, n, total, &out_.dir2));
  GF_RETURN_IF_ERROR(Place(c.tensor(), where + " tensor", off, n, total, &out_.tensor));
  if (c.has_diagnostics()) {
    const v1::VertexDiagnostics& d = c.diagnostics();
    GF_ASSIGN_OR_RETURN(RowsXi points, DecodeInts(d.points(), where + " diagnostics.points", {0}));
    GF_ASSIGN_OR_RETURN(RowsXi degree, DecodeInts(d.degree_used(), where + " diagnostics.degree_used", {0}));
    GF_ASSIGN_OR_RETURN(RowsXi flags, DecodeInts(d.flags(), where + " diagnostics.flags", {0}));
    GF_ASSIGN_OR_RETURN(RowsXd cond, DecodeDoubles(d.condition(), where + " diagnostics.condition", {0}));
    if (points.rows() != n || degree.rows() != n || flags.rows() != n || cond.rows() != n) {
      return absl::DataLossError(where + ": diagnostics arrays do not have one row per vertex");
    }
    out_.diagnostics.resize(static_cast<size_t>(total));
    for (int64_t i = 0; i < n; ++i) {
      VertexDiagnostics& v = out_.diagnostics[off + i];
      v.points = static_cast<int16_t>(points(i));
      v.degree_used = static_cast<int8_t>(degree(i));
      v.degree_requested = static_cast<int8_t>(summary_.degree_requested());
      v.flags = static_cast<uint8_t>(flags(i));
      v.condition = static_cast<float>(cond(i));
    }
  }
  rows_ += n;
  return absl::OkStatus();
}

absl::StatusOr<Differentials> DifferentialsReader::Finish() {
  if (!started_) return absl::DataLossError("the response stream carried no chunk");
  if (rows_ != summary_.num_vertices()) {
    return absl::DataLossError(absl::StrCat("the response stream ended after ", rows_, " of ",
                                            summary_.num_vertices(), " vertices"));
  }
  return std::move(out_);
}

}  // namespace geomfit::wire
