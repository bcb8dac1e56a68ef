// Membrane stress and interface pressure (§6.1-6.3): the balloon (6.3.4), the open
// cylinder (6.3.7) and the torus expansion of §6.4.1 against closed forms, with
// convergence orders >= d - 1; rigid motions are stress free; option validation.
#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/mechanics/membrane.h"
#include "core/operators/operators.h"
#include "core/surfaces/analytic.h"

namespace geomfit {
namespace {

MembraneOptions Material() {
  MembraneOptions m;
  m.E = 100;
  m.nu = 0.2;
  return m;
}

struct Errors {
  double linf = 0, l2 = 0;
  int vertices = 0;
};

// Pressure of `deformed(x)` against the reference mesh, relative errors against exact(x)
// over the vertices `use` accepts.
Errors PressureErrors(const Mesh& ref, int degree, const std::function<Eigen::Vector3d(const Eigen::Vector3d&)>& deform,
                      const std::function<double(const Eigen::Vector3d&)>& exact,
                      const std::function<bool(const Eigen::Vector3d&)>& use = nullptr) {
  const Topology topo = BuildTopology(ref).value();
  Positions y(ref.NumVertices(), 3);
  for (int i = 0; i < ref.NumVertices(); ++i) y.row(i) = deform(ref.positions.row(i).transpose()).transpose();
  FitOptions fit;
  fit.degree = degree;
  const MembraneFields f = ComputeMembrane(ref, topo, y, Material(), fit).value();
  Errors e;
  double num = 0, den = 0;
  for (int i = 0; i < ref.NumVertices(); ++i) {
    const Eigen::Vector3d x = ref.positions.row(i).transpose();
    if (use && !use(x)) continue;
    const double p = exact(x);
    e.linf = std::max(e.linf, std::abs(f.pressure(i) - p) / std::abs(p));
    num += (f.pressure(i) - p) * (f.pressure(i) - p);
    den += p * p;
    ++e.vertices;
  }
  e.l2 = std::sqrt(num / den);
  return e;
}

double Order(const std::vector<double>& e) { return std::log2(e.front() / e.back()) / (e.size() - 1); }

constexpr double kBalloon = 100 / 0.8 * (1.21 - 1) / 1.1;             // (6.3.4): 23.8636
constexpr double kCylinder = 100 / (2 * (1 - 0.04)) * (1.21 - 1) / 1.1;  // (6.3.7): 9.94318

TEST(Membrane, ClosedFormsMatchTheText) {
  EXPECT_NEAR(kBalloon, 23.8636, 1e-4);
  EXPECT_NEAR(kCylinder, 9.94318, 1e-5);
}

TEST(Membrane, BalloonConvergesAtDegreeMinusOne) {
  for (int d = 2; d <= 4; ++d) {
    std::vector<double> err;
    for (int n : {6, 12, 24, 48}) {
      GeneratorOptions g;
      g.n = n;
      const Errors e = PressureErrors(
          GenerateSphereMesh(g), d, [](const Eigen::Vector3d& x) { return (1.1 * x).eval(); },
          [](const Eigen::Vector3d&) { return kBalloon; });
      err.push_back(e.linf);
    }
    const double order = Order(err);
    std::printf("balloon d=%d: L-inf rel. errors %.3e %.3e %.3e %.3e, order %.2f\n", d, err[0], err[1], err[2],
                err[3], order);
    EXPECT_GE(order, d - 1 - 0.1) << "degree " << d;
    EXPECT_LT(err.back(), 0.05) << "degree " << d;
  }
}

TEST(Membrane, OpenCylinderInteriorPressure) {
  GeneratorOptions g;
  g.n = 24;
  const Errors e = PressureErrors(
      GenerateOpenCylinderMesh(g), 4,
      [](const Eigen::Vector3d& x) { return Eigen::Vector3d(1.1 * x.x(), 1.1 * x.y(), x.z()); },
      [](const Eigen::Vector3d&) { return kCylinder; }, [](const Eigen::Vector3d& x) { return std::abs(x.z()) < 0.6; });
  std::printf("cylinder: %d interior vertices, L-inf rel. error %.3e\n", e.vertices, e.linf);
  EXPECT_GT(e.vertices, 1000);
  EXPECT_LT(e.linf, 1e-4);
}

// The torus of §6.4.1: R = 1, r = 0.3 -> R' = 1.05, r' = 0.32 with the same (theta, phi).
double TorusPhi(const Eigen::Vector3d& x) { return std::atan2(x.z(), std::hypot(x.x(), x.y()) - 1.0); }
Eigen::Vector3d TorusDeform(const Eigen::Vector3d& x) {
  const double t = std::atan2(x.y(), x.x()), f = TorusPhi(x);
  const double A = 1.05 + 0.32 * std::cos(f);
  return Eigen::Vector3d(A * std::cos(t), A * std::sin(t), 0.32 * std::sin(f));
}
double TorusPressure(const Eigen::Vector3d& x) {
  const MembraneOptions m = Material();
  const double f = TorusPhi(x), A = 1 + 0.3 * std::cos(f), A1 = 1.05 + 0.32 * std::cos(f);
  const double lt = A1 / A, lp = 0.32 / 0.3;
  const double et = (lt * lt - 1) / 2, ep = (lp * lp - 1) / 2;
  const double tt = m.Lambda() * (et + ep) + 2 * m.Mu() * et, tp = m.Lambda() * (et + ep) + 2 * m.Mu() * ep;
  return tt * std::cos(f) / A1 + tp / 0.32;
}

TEST(Membrane, TorusExpansionConvergesAtDegreeMinusOne) {
  for (int d = 2; d <= 4; ++d) {
    std::vector<double> linf, l2;
    for (int n : {16, 32, 64}) {
      GeneratorOptions g;
      g.n = n;
      const Errors e = PressureErrors(GenerateTorusMesh(g), d, TorusDeform, TorusPressure);
      linf.push_back(e.linf);
      l2.push_back(e.l2);
    }
    std::printf("torus d=%d: L2 %.3e %.3e %.3e (order %.2f), L-inf %.3e %.3e %.3e (order %.2f)\n", d, l2[0], l2[1],
                l2[2], Order(l2), linf[0], linf[1], linf[2], Order(linf));
    EXPECT_GE(Order(l2), d - 1 - 0.1) << "degree " << d;
    EXPECT_GE(Order(linf), d - 1 - 0.1) << "degree " << d;
  }
}

TEST(Membrane, RigidMotionIsStressFree) {
  GeneratorOptions g;
  g.n = 10;
  const Mesh m = GenerateEllipsoidMesh(g, 1.0, 0.8, 0.6);
  const Topology topo = BuildTopology(m).value();
  const Eigen::Matrix3d Q = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  Positions y(m.NumVertices(), 3);
  for (int i = 0; i < m.NumVertices(); ++i)
    y.row(i) = (Q * m.positions.row(i).transpose() + Eigen::Vector3d(0.3, -1, 2)).transpose();
  FitOptions fit;
  fit.degree = 3;
  const MembraneFields f = ComputeMembrane(m, topo, y, Material(), fit).value();
  EXPECT_LT(f.pressure.cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT(f.stress.cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT(f.strain.cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((f.stretches.array() - 1).abs().maxCoeff(), 1e-12);
}

TEST(Membrane, BalloonFieldsAreExact) {
  // r0 = 1 -> 1.1: stretches 1.1, strain 0.105 T_ref, stress (lambda* + mu) 0.21 T,
  // von Mises equal to the (equal) principal stresses; the traction n . div sigma = -p.
  GeneratorOptions g;
  g.n = 16;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  const Positions y = 1.1 * m.positions;
  FitOptions fit;
  fit.degree = 4;
  const MembraneFields f = ComputeMembrane(m, topo, y, Material(), fit).value();
  const double s = (Material().Lambda() + Material().Mu()) * 0.21;
  for (int i = 0; i < m.NumVertices(); ++i) {
    const Eigen::Vector3d n = m.positions.row(i).transpose();
    const Eigen::Matrix3d T = Eigen::Matrix3d::Identity() - n * n.transpose();
    Eigen::Matrix3d strain, stress;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) strain(r, c) = f.strain(i, 3 * r + c), stress(r, c) = f.stress(i, 3 * r + c);
    ASSERT_NEAR(f.stretches(i, 0), 1.1, 1e-4);
    ASSERT_NEAR(f.stretches(i, 1), 1.1, 1e-4);
    ASSERT_LT((strain - 0.105 * T).norm(), 1e-4);
    ASSERT_LT((stress - s * T).norm(), 1e-3 * s);
    ASSERT_NEAR(f.von_mises(i), s, 1e-3 * s);
    ASSERT_LT(std::abs(n.dot(stress * n)), 1e-3 * s);  // n^T sigma n = 0 (Proposition 6.1.2)
    // n^T div sigma in full (6.2.9) = -tr(W tau^) = -p: the balance the pressure stands for.
    ASSERT_NEAR(f.traction(i), -kBalloon, 2e-3 * kBalloon) << i;
  }
}

TEST(Membrane, OptionsAreRequiredAndValidated) {
  auto code = [](double E, double nu) {
    MembraneOptions m;
    m.E = E;
    m.nu = nu;
    return ValidateMembraneOptions(m);
  };
  EXPECT_TRUE(code(100, 0.2).ok());
  EXPECT_TRUE(code(1, -0.99).ok());
  const MembraneOptions unset;
  const absl::Status none = ValidateMembraneOptions(unset);
  EXPECT_EQ(none.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(none.message().find("E:"), std::string::npos) << none;
  for (auto [E, nu, field] : std::vector<std::tuple<double, double, std::string>>{
           {0, 0.2, "E:"}, {-1, 0.2, "E:"}, {NAN, 0.2, "E:"}, {INFINITY, 0.2, "E:"},
           {100, 0.5, "nu:"}, {100, -1, "nu:"}, {100, NAN, "nu:"}, {100, 0.7, "nu:"}}) {
    const absl::Status s = code(E, nu);
    EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << E << " " << nu;
    EXPECT_NE(s.message().find(field), std::string::npos) << s;
  }
  // Deformed positions of the wrong length or not finite.
  GeneratorOptions g;
  g.n = 4;
  const Mesh m = GenerateSphereMesh(g);
  const Topology topo = BuildTopology(m).value();
  Positions y = m.positions.topRows(m.NumVertices() - 1);
  absl::Status s = ComputeMembrane(m, topo, y, Material(), FitOptions()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("deformed"), std::string::npos) << s;
  y = m.positions;
  y(5, 1) = NAN;
  s = ComputeMembrane(m, topo, y, Material(), FitOptions()).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("vertex 5"), std::string::npos) << s;
}

}  // namespace
}  // namespace geomfit
