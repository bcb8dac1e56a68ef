#include "proto/wire.h"

#include <gtest/gtest.h>

namespace geomfit::wire {
namespace {

TEST(WireTest, FitOptionsRoundTripAndUnsetMeansDefault) {
  FitOptions o;
  o.degree = 4;
  o.rings = 2.5;
  o.method = FitMethod::kLOP;
  o.interpolate = false;
  o.two_pass = true;
  o.oscillation_safeguard = true;
  o.frame_normals = NormalWeighting::kAngle;
  o.cond_threshold[3] = 42;
  o.noise = NoiseMode::kAuto;
  o.smoothing_passes = 3;
  o.solver = WlsSolver::kSVD;
  o.normal_degree = 5;
  o.hermite_hessian = true;
  o.slope_refinement = 2;
  o.cubic_hermite = false;
  o.jet_hermite = JetHermiteMode::kOn;
  o.plane_hermite = false;
  o.quadratic_hermite = true;
  auto back = FromProto(ToProto(o));
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->normal_degree, 5);
  EXPECT_TRUE(back->hermite_hessian);
  EXPECT_EQ(back->slope_refinement, 2);
  EXPECT_FALSE(back->cubic_hermite);
  EXPECT_FALSE(back->plane_hermite);
  EXPECT_EQ(back->jet_hermite, JetHermiteMode::kOn);
  EXPECT_TRUE(back->quadratic_hermite);
  o.jet_hermite = JetHermiteMode::kOff;
  EXPECT_EQ(FromProto(ToProto(o))->jet_hermite, JetHermiteMode::kOff);
  EXPECT_FALSE(ToProto(FitOptions()).has_jet_hermite());  // auto stays unset
  EXPECT_FALSE(ToProto(FitOptions()).has_quadratic_hermite());  // off stays unset
  FitOptions q;  // degree 2, where it runs: the server's cache key tells it from the plain fit
  q.quadratic_hermite = true;
  EXPECT_EQ(FitOptionsKey(*FromProto(ToProto(q))), FitOptionsKey(q));
  EXPECT_NE(FitOptionsKey(q), FitOptionsKey(FitOptions()));
  EXPECT_EQ(FitOptionsKey(*back), FitOptionsKey(o));
  EXPECT_EQ(FitOptionsIdentity(*back), FitOptionsIdentity(o));
  for (FitMethod m : {FitMethod::kLHF, FitMethod::kLOP, FitMethod::kXu, FitMethod::kLSCM}) {
    o.method = m;
    EXPECT_EQ(FromProto(ToProto(o))->method, m);
  }
  auto defaults = FromProto(v1::FitOptions());
  ASSERT_TRUE(defaults.ok());
  EXPECT_EQ(FitOptionsKey(*defaults), FitOptionsKey(FitOptions()));
  EXPECT_EQ(defaults->normal_degree, 0);
  EXPECT_FALSE(defaults->hermite_hessian);
  EXPECT_EQ(defaults->slope_refinement, 0);
  EXPECT_TRUE(defaults->cubic_hermite);
  EXPECT_TRUE(defaults->plane_hermite);
  EXPECT_EQ(defaults->jet_hermite, JetHermiteMode::kAuto);
  EXPECT_FALSE(defaults->quadratic_hermite);
  v1::FitOptions bad;
  bad.set_degree(7);
  EXPECT_EQ(FromProto(bad).status().code(), absl::StatusCode::kInvalidArgument);
  v1::FitOptions low;  // a normal pre-fit below the fit's degree
  low.set_degree(2);
  low.set_normal_degree(1);
  EXPECT_EQ(FromProto(low).status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(FromProto(low).status().message().find("normal_degree = 1"), std::string::npos)
      << FromProto(low).status();
}

TEST(WireTest, ArraysRoundTripAndBadShapesAreNamed) {
  const double values[6] = {1, 2, 3, 4, 5, 6};
  v1::DoubleArray a;
  EncodeDoubles(values, 2, 3, &a);
  auto m = DecodeDoubles(a, "positions", {3});
  ASSERT_TRUE(m.ok());
  EXPECT_EQ((*m)(1, 2), 6);
  auto wrong_cols = DecodeDoubles(a, "positions", {4});
  EXPECT_NE(wrong_cols.status().message().find("positions: shape[1] is 3, expected 4"), std::string::npos)
      << wrong_cols.status();
  a.mutable_data()->resize(40);
  auto short_data = DecodeDoubles(a, "positions", {3});
  EXPECT_NE(short_data.status().message().find("40 bytes"), std::string::npos) << short_data.status();
  a.set_shape(0, -1);
  EXPECT_FALSE(DecodeDoubles(a, "positions", {3}).ok());
}

TEST(WireTest, QuantitiesMask) {
  v1::ComputeDifferentialsRequest r;
  AddQuantities(kMeanCurvature | kCurvatureTensor, &r);
  auto mask = QuantityMask(r.quantities());
  ASSERT_TRUE(mask.ok());
  EXPECT_EQ(*mask, static_cast<uint32_t>(kMeanCurvature | kCurvatureTensor));
  r.add_quantities(static_cast<v1::Quantity>(40));
  EXPECT_NE(QuantityMask(r.quantities()).status().message().find("quantities[2]"), std::string::npos);
}

TEST(WireTest, DifferentialsReaderRejectsGapsAndShortStreams) {
  v1::ComputeDifferentialsResponse first;
  first.mutable_summary()->set_num_vertices(4);
  first.set_num_vertices(2);
  const double mean[2] = {1, 2};
  EncodeDoubles(mean, 2, 0, first.mutable_mean());
  DifferentialsReader reader;
  ASSERT_TRUE(reader.Add(first).ok());
  v1::ComputeDifferentialsResponse gap;
  gap.set_vertex_offset(3);
  gap.set_num_vertices(1);
  EXPECT_EQ(reader.Add(gap).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(reader.Finish().status().code(), absl::StatusCode::kDataLoss);
}

TEST(WireTest, DifferentialsReaderTakesTheLastChunksSummary) {
  const double mean[2] = {1, 2};
  v1::ComputeDifferentialsResponse first, last;
  first.mutable_summary()->set_num_vertices(4);
  first.set_num_vertices(2);
  EncodeDoubles(mean, 2, 0, first.mutable_mean());
  last = first;
  last.set_vertex_offset(2);
  last.mutable_summary()->set_min_degree_used(3);
  DifferentialsReader reader;
  ASSERT_TRUE(reader.Add(first).ok());
  ASSERT_TRUE(reader.Add(last).ok());
  EXPECT_EQ(reader.summary().min_degree_used(), 3);
  auto d = reader.Finish();
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(d->mean(3), 2);

  DifferentialsReader other;  // a last summary that disagrees on the vertex count
  last.mutable_summary()->set_num_vertices(5);
  ASSERT_TRUE(other.Add(first).ok());
  EXPECT_EQ(other.Add(last).code(), absl::StatusCode::kDataLoss);
}

}  // namespace
}  // namespace geomfit::wire
