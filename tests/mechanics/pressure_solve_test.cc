// The pressure-load solve (6.4.1): the inverse balloon (unit sphere under [p] = 2 expands
// to r1 = 1.0080320, the root of (6.3.4)) with order >= d - 1 and the rigid modes removed;
// a clamped half sphere; a free-ended cylinder; Newton's history, failures and bad inputs.
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

// Free ends (the natural condition sigma m = 0): an open cylinder under [p] expands
// uniaxially, hoop stretch l with p = E (l^2 - 1)/(2 l), axial stretch sqrt(1 - nu (l^2 - 1)).
// Its axial stress is zero, so axial wrinkles have no geometric stiffness and Newton
// needs load steps from n = 10 on: kept small ([p] = 0.5, two coarse levels).
TEST(PressureSolve, FreeEndedCylinderExpandsWithoutAxialStress) {
  const double E = 100, nu = 0.2, p = 0.5;
  const double l = p / E + std::sqrt(p * p / (E * E) + 1), lz = std::sqrt(1 - nu * (l * l - 1));
  std::vector<double> hoop_err, axial_err;
  for (int n : {8, 10}) {
    GeneratorOptions g;
    g.n = n;
    const Mesh m = GenerateOpenCylinderMesh(g);
    const Topology topo = BuildTopology(m).value();
    PressureSolveOptions o = Options(4);
    o.boundary = BoundaryCondition::kFree;
    const PressureSolution s = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, p), o).value();
    EXPECT_LE(s.residual, 1e-10);
    double eh = 0, ez = 0;
    for (int i = 0; i < m.NumVertices(); ++i) {
      const Eigen::Vector3d x = m.positions.row(i).transpose(), y = s.deformed.row(i).transpose();
      eh = std::max(eh, std::abs(std::hypot(y.x(), y.y()) - l * std::hypot(x.x(), x.y())));
      ez = std::max(ez, std::abs(y.z() - lz * x.z()));
    }
    const Eigen::Vector3d c = s.deformed.colwise().mean().transpose() - m.positions.colwise().mean().transpose();
    std::printf("free-ended cylinder n=%d (%d vertices): %zu iterations, %d load steps, %d factorizations, max "
                "hoop error %.3e, axial %.3e, centroid shift %.1e\n", n, m.NumVertices(), s.history.size(),
                s.load_steps, s.factorizations, eh, ez, c.norm());
    EXPECT_LT(c.norm(), 1e-12);
    hoop_err.push_back(eh);
    axial_err.push_back(ez);
  }
  // Relative to the displacements (l - 1 = 5e-3, 1 - lz = 5e-4), converging at order >= d - 1.
  EXPECT_LT(hoop_err.back(), 0.03 * (l - 1));
  EXPECT_LT(axial_err.back(), 0.05 * (1 - lz));
  const double order = std::log(hoop_err.front() / hoop_err.back()) / std::log(10.0 / 8.0);
  std::printf("free-ended cylinder: hoop error order %.2f\n", order);
  EXPECT_GE(order, 3);
}

// GMRES reaches the direct solve's answer with either preconditioner (the compact 1-ring
// discretization with Gauss-Seidel sweeps, the default; the Jacobian's 1-ring part), with
// Eisenstat-Walker forcing or fixed tolerances; the direct solve with METIS's ordering
// (the default) and UMFPACK's own agree.
TEST(PressureSolve, KrylovMatchesTheDirectSolve) {
  GeneratorOptions g;
  g.n = 8;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  PressureSolveOptions o = Options(3);
  EXPECT_TRUE(o.solver.umfpack_metis);
  const PressureSolution direct = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).value();
  EXPECT_LE(direct.residual, 1e-10);
  PressureSolveOptions amd = o;
  amd.solver.umfpack_metis = false;
  const PressureSolution plain = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), amd).value();
  EXPECT_LT((plain.deformed - direct.deformed).cwiseAbs().maxCoeff(), 1e-9);
  ASSERT_TRUE(SetPressureSolver("gmres", &o).ok());
  EXPECT_TRUE(o.krylov);
  EXPECT_EQ(o.krylov_preconditioner, KrylovPreconditioner::kCompact);
  std::vector<int> its;  // (compact, 1-ring) x (forcing, fixed)
  for (const KrylovPreconditioner pre : {KrylovPreconditioner::kCompact, KrylovPreconditioner::kOneRing}) {
    for (const bool forcing : {true, false}) {
      o.krylov_preconditioner = pre;
      o.krylov_forcing = forcing;
      const PressureSolution krylov = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).value();
      std::printf("krylov (%s, %s): %zu Newton iterations, %d GMRES iterations, residual %.2e\n",
                  pre == KrylovPreconditioner::kCompact ? "compact" : "1-ring", forcing ? "forcing" : "fixed",
                  krylov.history.size(), krylov.krylov_iterations, krylov.residual);
      EXPECT_LE(krylov.residual, 1e-10);
      EXPECT_GT(krylov.krylov_iterations, 0);
      int sum = 0;
      for (const NewtonIteration& it : krylov.history) sum += it.krylov_iterations;
      EXPECT_EQ(sum, krylov.krylov_iterations);
      its.push_back(krylov.krylov_iterations);
      EXPECT_LT((krylov.deformed - direct.deformed).cwiseAbs().maxCoeff(), 1e-9);
    }
  }
  // The compact preconditioner and the forcing terms each save iterations.
  EXPECT_LT(its[0], its[2]);
  EXPECT_LT(its[0], its[1]);
  EXPECT_LT(its[2], its[3]);
  EXPECT_EQ(SetPressureSolver("cholesky", &o).code(), absl::StatusCode::kInvalidArgument);
}

TEST(PressureSolve, OpenMeshNeedsABoundaryCondition) {
  GeneratorOptions g;
  g.n = 4;
  const Mesh m = GenerateHemisphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  PressureSolveOptions o = Options(3);
  const absl::Status s = SolvePressureLoad(m, topo, Eigen::VectorXd::Constant(1, 2.0), o).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("boundary"), std::string::npos) << s;
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
