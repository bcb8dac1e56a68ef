// GFD surface operators (§5.1): ApplyOperator and GetOperator on Workspace::Operator.
#include <cmath>

#include "absl/strings/str_cat.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"

namespace geomfit::server {
namespace {

absl::StatusOr<OperatorKind> FromProto(v1::OperatorKind k) {
  switch (k) {
    case v1::OPERATOR_GRADIENT: return OperatorKind::kGradient;
    case v1::OPERATOR_DIVERGENCE: return OperatorKind::kDivergence;
    case v1::OPERATOR_LAPLACE_BELTRAMI: return OperatorKind::kLaplaceBeltrami;
    case v1::OPERATOR_HESSIAN: return OperatorKind::kHessian;
    case v1::OPERATOR_WEINGARTEN: return OperatorKind::kWeingarten;
    default:
      return absl::InvalidArgumentError(
          absl::StrCat("operator: ", k == v1::OPERATOR_UNSPECIFIED ? "unset" : absl::StrCat("unknown value ", k),
                       " (gradient, divergence, laplace_beltrami, hessian, weingarten)"));
  }
}

}  // namespace

absl::StatusOr<Handlers::OperatorMatrix> Handlers::Operator(const std::string& mesh_id, int64_t revision,
                                                            v1::OperatorKind kind, const v1::FitOptions& options,
                                                            const CancellationToken& cancel) {
  GF_RETURN_IF_ERROR(RequireId(mesh_id));
  GF_ASSIGN_OR_RETURN(const OperatorKind op, FromProto(kind));
  GF_ASSIGN_OR_RETURN(const FitOptions fit, wire::FromProto(options));
  if (fit.method != FitMethod::kLHF)
    return absl::InvalidArgumentError("options.method: the GFD operators need LHF fits (height functions)");
  GF_ASSIGN_OR_RETURN(Snapshot s, Acquire(mesh_id, revision));
  GF_ASSIGN_OR_RETURN(auto m, ws_->Operator(s, fit, op, ws_->Context(&cancel)));
  GF_RETURN_IF_ERROR(cancel.Check());
  return OperatorMatrix{std::move(m), s.revision, s.mesh->NumVertices()};
}

absl::StatusOr<v1::GetOperatorResponse> Handlers::GetOperator(const v1::GetOperatorRequest& request,
                                                              const CancellationToken& cancel) {
  GF_ASSIGN_OR_RETURN(const OperatorMatrix op,
                      Operator(request.mesh_id(), request.revision(), request.operator_(), request.options(), cancel));
  const SparseMatrix& m = *op.matrix;
  const int64_t bytes = 12 * static_cast<int64_t>(m.nonZeros()) + 4 * (m.rows() + 1);
  if (bytes > options_.max_message_bytes)
    return absl::ResourceExhaustedError(absl::StrCat("the operator takes ", bytes, " bytes, above the message limit ",
                                                     options_.max_message_bytes));
  v1::GetOperatorResponse out;
  wire::EncodeInts(m.outerIndexPtr(), m.rows() + 1, 0, out.mutable_row_offsets());
  wire::EncodeInts(m.innerIndexPtr(), m.nonZeros(), 0, out.mutable_columns());
  wire::EncodeDoubles(m.valuePtr(), m.nonZeros(), 0, out.mutable_values());
  out.add_shape(m.rows());
  out.add_shape(m.cols());
  out.set_revision(op.revision);
  return out;
}

absl::StatusOr<v1::ApplyOperatorResponse> Handlers::ApplyOperator(const v1::ApplyOperatorRequest& request,
                                                                  const CancellationToken& cancel) {
  // The field is checked before anything is fitted (its length once the mesh is known).
  GF_ASSIGN_OR_RETURN(const wire::RowsXd field,
                      request.field().shape_size() == 1 ? wire::DecodeDoubles(request.field(), "field", {0})
                                                        : wire::DecodeDoubles(request.field(), "field", {1, 3}));
  for (Eigen::Index i = 0; i < field.size(); ++i)
    if (!std::isfinite(field.data()[i]))
      return absl::InvalidArgumentError(absl::StrCat("field: value ", i, " is not finite"));
  GF_ASSIGN_OR_RETURN(const OperatorMatrix op,
                      Operator(request.mesh_id(), request.revision(), request.operator_(), request.options(), cancel));
  const SparseMatrix& m = *op.matrix;
  const int64_t n = op.num_vertices;
  const int64_t cols = m.cols() / n;  // 1: scalar operand, 3: vector operand
  if (field.size() != m.cols())
    return absl::InvalidArgumentError(absl::StrCat("field: ", field.size(), " values; the ",
                                                   v1::OperatorKind_Name(request.operator_()), " of ", n,
                                                   " vertices takes ", n, " x ", cols));
  const Eigen::VectorXd x = Eigen::Map<const Eigen::VectorXd>(field.data(), field.size());
  const Eigen::VectorXd y = m * x;
  v1::ApplyOperatorResponse out;
  const int64_t k = m.rows() / n;
  wire::EncodeDoubles(y.data(), n, k, out.mutable_result());
  out.set_revision(op.revision);
  return out;
}

}  // namespace geomfit::server
