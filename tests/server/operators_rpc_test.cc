// GFD operators over gRPC: ApplyOperator (Laplace-Beltrami of the position on a sphere
// is the mean-curvature vector -2 H n = -2 x), GetOperator's CSR arrays equal core's
// matrix bit for bit, the second call is served from the cache, and bad fields are
// rejected naming the field.
#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "core/operators/operators.h"
#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit::server {
namespace {

using testing::InProcessServer;

absl::Status ToAbsl(const grpc::Status& s) {
  return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
}

v1::ApplyOperatorRequest Apply(const std::string& id, v1::OperatorKind kind, const double* data, int64_t rows,
                               int64_t cols) {
  v1::ApplyOperatorRequest r;
  r.set_mesh_id(id);
  r.set_operator_(kind);
  r.mutable_options()->set_degree(4);
  wire::EncodeDoubles(data, rows, cols, r.mutable_field());
  return r;
}

TEST(OperatorsRpcTest, LaplaceBeltramiOfPositionIsMeanCurvatureVector) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(8);
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(info.ok()) << info.status();
  const int n = sphere.NumVertices();
  double worst = 0;
  for (int c = 0; c < 3; ++c) {
    const Eigen::VectorXd x = sphere.positions.col(c);
    grpc::ClientContext ctx;
    v1::ApplyOperatorResponse out;
    ASSERT_TRUE(server.stub().ApplyOperator(&ctx, Apply(info->mesh_id(), v1::OPERATOR_LAPLACE_BELTRAMI, x.data(), n, 0),
                                            &out).ok());
    absl::StatusOr<wire::RowsXd> lx = wire::DecodeDoubles(out.result(), "result", {1});
    ASSERT_TRUE(lx.ok()) << lx.status();
    ASSERT_EQ(lx->rows(), n);
    EXPECT_EQ(out.revision(), info->revision());
    for (int i = 0; i < n; ++i) worst = std::max(worst, std::abs((*lx)(i, 0) + 2 * sphere.positions(i, c)));
  }
  std::printf("sphere n=8 d=4: |L x + 2 H n|inf = %.2e\n", worst);
  EXPECT_LT(worst, 2e-2);

  // The gradient of the vector field's components: n x 3 in, 3n x 1 out per vertex.
  const Eigen::VectorXd z = sphere.positions.col(2);
  grpc::ClientContext ctx;
  v1::ApplyOperatorResponse grad;
  ASSERT_TRUE(server.stub().ApplyOperator(&ctx, Apply(info->mesh_id(), v1::OPERATOR_GRADIENT, z.data(), n, 0), &grad).ok());
  ASSERT_EQ(grad.result().shape_size(), 2);
  EXPECT_EQ(grad.result().shape(0), n);
  EXPECT_EQ(grad.result().shape(1), 3);
}

TEST(OperatorsRpcTest, GetOperatorEqualsCoreMatrixExactly) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(6);
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(info.ok()) << info.status();
  FitOptions o;
  o.degree = 4;
  const Topology topo = ValidateMesh(sphere).value();
  auto nb = std::make_shared<const Neighborhoods>(BuildNeighborhoods(topo, sphere, RingSpecFor(o), 1));
  auto fits = FitForOperators(sphere, topo, o, nb, RunContext()).value();
  const OperatorAssembler assembler(nb);
  const std::pair<v1::OperatorKind, OperatorKind> kinds[] = {
      {v1::OPERATOR_LAPLACE_BELTRAMI, OperatorKind::kLaplaceBeltrami},
      {v1::OPERATOR_GRADIENT, OperatorKind::kGradient},
      {v1::OPERATOR_DIVERGENCE, OperatorKind::kDivergence},
      {v1::OPERATOR_HESSIAN, OperatorKind::kHessian},
      {v1::OPERATOR_WEINGARTEN, OperatorKind::kWeingarten}};
  for (const auto& [wire_kind, kind] : kinds) {
    const SparseMatrix core = assembler.Assemble(kind, *fits).value();
    for (int call = 0; call < 2; ++call) {  // the second from the cache
      v1::GetOperatorRequest request;
      request.set_mesh_id(info->mesh_id());
      request.set_operator_(wire_kind);
      request.mutable_options()->set_degree(4);
      grpc::ClientContext ctx;
      v1::GetOperatorResponse out;
      ASSERT_TRUE(server.stub().GetOperator(&ctx, request, &out).ok()) << OperatorKindName(kind);
      ASSERT_EQ(out.shape_size(), 2);
      EXPECT_EQ(out.shape(0), core.rows());
      EXPECT_EQ(out.shape(1), core.cols());
      const auto same = [](const std::string& bytes, const void* data, size_t n) {
        return bytes.size() == n && std::memcmp(bytes.data(), data, n) == 0;
      };
      EXPECT_TRUE(same(out.row_offsets().data(), core.outerIndexPtr(), 4 * (core.rows() + 1))) << OperatorKindName(kind);
      EXPECT_TRUE(same(out.columns().data(), core.innerIndexPtr(), 4 * core.nonZeros())) << OperatorKindName(kind);
      EXPECT_TRUE(same(out.values().data(), core.valuePtr(), 8 * core.nonZeros())) << OperatorKindName(kind);
    }
  }
}

TEST(OperatorsRpcTest, BadInputsNameTheirFields) {
  InProcessServer server;
  const Mesh sphere = testing::TestSphere(4);
  absl::StatusOr<v1::MeshInfo> info = testing::UploadMesh(server.stub(), sphere, "sphere");
  ASSERT_TRUE(info.ok());
  const int n = sphere.NumVertices();
  std::vector<double> ok(n, 1.0), short_field(n - 1, 1.0), nan_field(n, 1.0);
  nan_field[5] = std::nan("");
  struct Case {
    v1::ApplyOperatorRequest request;
    std::string field;
  };
  std::vector<Case> cases = {
      {Apply(info->mesh_id(), v1::OPERATOR_LAPLACE_BELTRAMI, short_field.data(), n - 1, 0), "field"},
      {Apply(info->mesh_id(), v1::OPERATOR_LAPLACE_BELTRAMI, nan_field.data(), n, 0), "field"},
      {Apply(info->mesh_id(), v1::OPERATOR_DIVERGENCE, ok.data(), n, 0), "field"},  // needs n x 3
      {Apply(info->mesh_id(), v1::OPERATOR_UNSPECIFIED, ok.data(), n, 0), "operator"},
      {Apply("", v1::OPERATOR_LAPLACE_BELTRAMI, ok.data(), n, 0), "mesh_id"},
  };
  cases.push_back(cases[0]);
  cases.back().request = Apply(info->mesh_id(), v1::OPERATOR_LAPLACE_BELTRAMI, ok.data(), n, 0);
  cases.back().request.mutable_options()->set_degree(7);
  cases.back().field = "degree";
  for (const Case& c : cases) {
    grpc::ClientContext ctx;
    v1::ApplyOperatorResponse out;
    const absl::Status s = ToAbsl(server.stub().ApplyOperator(&ctx, c.request, &out));
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << c.field << ": " << s;
    EXPECT_NE(s.message().find(c.field), std::string::npos) << s;
  }
}

}  // namespace
}  // namespace geomfit::server
