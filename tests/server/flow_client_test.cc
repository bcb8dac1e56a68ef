// The C++ client's flow and operator calls: StartFlow + WatchJob to a stored revision,
// GetOperator equal to core's matrix, ApplyOperator equal to the matrix times the field.
#include <gtest/gtest.h>

#include "clients/cpp/client/client.h"
#include "core/fitting/neighborhood.h"
#include "core/mesh/topology.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

using server::testing::InProcessServer;

std::unique_ptr<Client> ClientFor(int port) {
  ClientOptions o;
  o.target = "127.0.0.1:" + std::to_string(port);
  o.deadline = std::chrono::seconds(30);
  return Client::Connect(o);
}

TEST(FlowClientTest, StartFlowAndOperators) {
  InProcessServer server;
  std::unique_ptr<Client> client = ClientFor(server.port());
  const Mesh sphere = server::testing::TestSphere(6);
  absl::StatusOr<RemoteMesh> info = client->Upload(sphere, "sphere");
  ASSERT_TRUE(info.ok()) << info.status();

  v1::FitOptions fit;
  fit.set_degree(4);
  absl::StatusOr<SparseMatrix> L = client->GetOperator(info->mesh_id, v1::OPERATOR_LAPLACE_BELTRAMI, fit);
  ASSERT_TRUE(L.ok()) << L.status();
  FitOptions o;
  o.degree = 4;
  const Topology topo = ValidateMesh(sphere).value();
  auto nb = std::make_shared<const Neighborhoods>(BuildNeighborhoods(topo, sphere, RingSpecFor(o), 1));
  const SparseMatrix core = OperatorAssembler(nb).Assemble(OperatorKind::kLaplaceBeltrami,
                                                           *FitForOperators(sphere, topo, o, nb, RunContext()).value())
                                .value();
  ASSERT_EQ(L->rows(), core.rows());
  ASSERT_EQ(L->nonZeros(), core.nonZeros());
  EXPECT_EQ((*L - core).cwiseAbs().sum(), 0.0);

  const Eigen::MatrixXd z = sphere.positions.col(2);
  absl::StatusOr<Eigen::MatrixXd> Lz = client->ApplyOperator(info->mesh_id, v1::OPERATOR_LAPLACE_BELTRAMI, z, fit);
  ASSERT_TRUE(Lz.ok()) << Lz.status();
  EXPECT_LE((*Lz - core * z).cwiseAbs().maxCoeff(), 1e-12 * (1 + (core * z).cwiseAbs().maxCoeff()));

  v1::FlowJob spec;
  spec.set_mesh_id(info->mesh_id);
  spec.set_dt(1e-3);
  spec.set_steps(3);
  absl::StatusOr<v1::Job> job = client->StartFlow(spec);
  ASSERT_TRUE(job.ok()) << job.status();
  v1::JobEvent last;
  int steps = 0;
  ASSERT_TRUE(client->WatchJob(job->job_id(), 0, [&](const v1::JobEvent& e) {
                    steps += e.phase() == "step";
                    last = e;
                    return true;
                  }).ok());
  EXPECT_EQ(steps, 3);
  ASSERT_EQ(last.state(), v1::JOB_STATE_SUCCEEDED) << last.message();
  ASSERT_EQ(last.results_size(), 1);
  absl::StatusOr<RemoteMesh> now = client->GetMesh(info->mesh_id);
  ASSERT_TRUE(now.ok());
  EXPECT_EQ(now->revision, last.results(0).revision());
  EXPECT_EQ(now->revision, info->revision + 1);  // snapshot_every 0: only the end
}

}  // namespace
}  // namespace geomfit
