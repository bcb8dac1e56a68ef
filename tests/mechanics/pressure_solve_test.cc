// The pressure-load solve (6.4.1): the inverse balloon (unit sphere under [p] = 2 expands
// to r1 = 1.0080320, the root of (6.3.4)) with order >= d - 1 and the rigid modes removed;
// a clamped half sphere; Newton's history, failures and bad inputs.
#include <cmath>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/mechanics/pressure_solve.h"
#include "core/surfaces/analytic.h"
#include "core/util/cancel.h"

namespace geomfit {
namespace {

PressureSolveOptions Options(int degree) {
  PressureSolveOptions o;
  o.material.E = 100;
  o.material.nu = 0.2;
  o.fit.degree = degree;
  return o;
}

// r1 with E/(1 - nu) (r1^2 - 1)/r1 = p (6.3.4, r0 = 1).
double BalloonRadius(double E, double nu, double p) {
  const double k = p * (1 - nu) / E;
  return (k + std::sqrt(k * k + 4)) / 2;
}

TEST(PressureSolve, InverseBalloonConvergesAtDegreeMinusOne) {
  const double r1 = BalloonRadius(100, 0.2, 2);
  EXPECT_NEAR(r1, 1.0080320, 1e-7);
  for (int d = 2; d <= 4; ++d) {
    std::vector<double> err;
    for (int n : {5, 10, 20}) {
      GeneratorOptions g;
      g.n = n;
      const Mesh m = GenerateSphereMesh(g);
      const Topology topo = BuildTopology(m).value();
      std::vector<NewtonIteration> seen;
      const PressureSolution s =
          SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), Options(d), RunContext(),
                            [&](const NewtonIteration& it) { seen.push_back(it); })
              .value();
      ASSERT_EQ(seen.size(), s.history.size());
      ASSERT_GE(s.history.size(), 2u);
      EXPECT_LE(s.residual, 1e-10);
      EXPECT_LE(s.history.back().residual, 1e-10);
      double e = 0;
      for (int i = 0; i < m.NumVertices(); ++i)
        e = std::max(e, std::abs(s.deformed.row(i).norm() - r1) / (r1 - 1));  // relative to the displacement
      err.push_back(e);
      // Rigid modes removed: centroid fixed, no mean rotation.
      const Eigen::Vector3d c = m.positions.colwise().mean().transpose();
      EXPECT_LT(s.displacement.colwise().sum().norm(), 1e-10);
      Eigen::Vector3d rot = Eigen::Vector3d::Zero();
      for (int i = 0; i < m.NumVertices(); ++i)
        rot += (m.positions.row(i).transpose() - c).cross(s.displacement.row(i).transpose());
      EXPECT_LT(rot.norm(), 1e-10);
      std::printf("inverse balloon d=%d n=%d: %zu iterations, %d load steps, radius error / (r1 - 1) %.3e\n", d, n,
                  s.history.size(), s.load_steps, e);
    }
    const double order = std::log2(err.front() / err.back()) / (err.size() - 1);
    std::printf("inverse balloon d=%d: order %.2f\n", d, order);
    EXPECT_GE(order, d - 1 - 0.1) << "degree " << d;
  }
}

TEST(PressureSolve, ClampedHalfSphereStaysClamped) {
  GeneratorOptions g;
  g.n = 10;
  const Mesh m = GenerateHemisphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  PressureSolveOptions o = Options(3);
  o.boundary = BoundaryCondition::kClamped;
  const PressureSolution s = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).value();
  EXPECT_LE(s.residual, 1e-10);
  double top = 0;
  for (int i = 0; i < m.NumVertices(); ++i) {
    if (topo.is_boundary[i]) {
      EXPECT_LT(s.displacement.row(i).norm(), 1e-14) << i;
    } else {  // pressure inside: the cap bulges outwards
      EXPECT_GT(s.displacement.row(i).dot(m.positions.row(i)), 0) << i;
    }
    top = std::max(top, s.displacement.row(i).norm());
  }
  std::printf("clamped half sphere: max displacement %.4e, %zu iterations\n", top, s.history.size());
  EXPECT_GT(top, 1e-3);
  EXPECT_LT(top, 2 * (BalloonRadius(100, 0.2, 2) - 1));
}

TEST(PressureSolve, OpenMeshNeedsClampedBoundary) {
  GeneratorOptions g;
  g.n = 4;
  const Mesh m = GenerateHemisphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  PressureSolveOptions o = Options(3);
  const absl::Status s = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("boundary"), std::string::npos) << s;
  o.boundary = BoundaryCondition::kFree;
  EXPECT_EQ(SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).status().code(),
            absl::StatusCode::kUnimplemented);
}

TEST(PressureSolve, NonConvergenceIsFailedPreconditionWithHistory) {
  GeneratorOptions g;
  g.n = 6;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  PressureSolveOptions o = Options(2);
  o.max_iterations = 1;  // Newton cannot reach 1e-10 in one iteration, nor after halving
  o.max_load_cuts = 2;
  const absl::Status s = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
  EXPECT_NE(s.message().find("residual history"), std::string::npos) << s;
  EXPECT_NE(s.message().find("load 0.25"), std::string::npos) << s;
}

TEST(PressureSolve, BadInputs) {
  GeneratorOptions g;
  g.n = 4;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  auto code = [&](const Eigen::VectorXd& p, const PressureSolveOptions& o, const std::string& field) {
    const absl::Status s = SolvePressureLoad(m, topo, p, o).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
    EXPECT_NE(s.message().find(field), std::string::npos) << s;
  };
  code(Eigen::VectorXd::Constant(1, NAN), Options(2), "pressure");
  code(Eigen::VectorXd::Constant(3, 1.0), Options(2), "pressure");
  PressureSolveOptions o = Options(2);
  o.material.nu = 0.5;
  code(Eigen::VectorXd::Constant(1, 1.0), o, "nu");
  o = Options(2);
  o.material.E = 0;
  code(Eigen::VectorXd::Constant(1, 1.0), o, "E");
  o = Options(1);
  code(Eigen::VectorXd::Constant(1, 1.0), o, "fit.degree");
  // Zero load: the reference is the answer, no iteration.
  const PressureSolution s = SolvePressureLoad(m, topo, Eigen::VectorXd::Zero(1), Options(2)).value();
  EXPECT_TRUE(s.history.empty());
  EXPECT_EQ(s.displacement.cwiseAbs().maxCoeff(), 0.0);
}

TEST(PressureSolve, Cancellation) {
  GeneratorOptions g;
  g.n = 6;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  CancellationToken token;
  token.Cancel();
  const absl::Status s =
      SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), Options(2), RunContext(&token)).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kCancelled) << s;
}

}  // namespace
}  // namespace geomfit
