// geomfit::Client with ClientOptions::progress: the server's progress reported on the
// calling thread, results identical to the calls without progress.
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

#include "clients/cpp/client/client.h"
#include "proto/wire.h"
#include "tests/server/test_util.h"

namespace geomfit {
namespace {

using server::testing::InProcessServer;

struct Report {
  std::string phase;
  int64_t done, total;
};

class ProgressClientTest : public ::testing::Test {
 protected:
  ProgressClientTest() : mesh_(server::testing::TestTorus(30)) {
    ClientOptions o;
    o.target = "127.0.0.1:" + std::to_string(server_.port());
    plain_ = Client::Connect(o);
    o.progress = [this](const Progress& p) {
      EXPECT_EQ(std::this_thread::get_id(), caller_);
      reports_.push_back({std::string(p.phase), p.done, p.total});
    };
    reporting_ = Client::Connect(o);
    auto info = plain_->Upload(mesh_, "torus");
    EXPECT_TRUE(info.ok()) << info.status();
    id_ = info->mesh_id;
    options_.mutable_fit()->set_degree(4);
  }

  /// The phases reported since the last call, in order; each ends at done = total with
  /// done increasing.
  std::vector<std::string> Phases() {
    std::vector<std::string> phases;
    for (size_t i = 0; i < reports_.size(); ++i) {
      const Report& r = reports_[i];
      const bool first = phases.empty() || phases.back() != r.phase;
      if (first) phases.push_back(r.phase);
      if (!first) EXPECT_GT(r.done, reports_[i - 1].done) << r.phase;
      const bool last = i + 1 == reports_.size() || reports_[i + 1].phase != r.phase;
      if (last) EXPECT_EQ(r.done, r.total) << r.phase;
    }
    reports_.clear();
    return phases;
  }

  InProcessServer server_;
  Mesh mesh_;
  std::unique_ptr<Client> plain_, reporting_;
  std::string id_;
  v1::ReconstructionOptions options_;
  std::vector<Report> reports_;
  const std::thread::id caller_ = std::this_thread::get_id();
};

TEST_F(ProgressClientTest, ChapterFourCallsReportTheServersPhases) {
  const Positions points = mesh_.positions * 0.99;
  auto projected = reporting_->ProjectPoints(id_, points, options_);
  ASSERT_TRUE(projected.ok()) << projected.status();
  EXPECT_EQ(Phases(), (std::vector<std::string>{"fit", "project"}));
  auto plain = plain_->ProjectPoints(id_, points, options_);
  ASSERT_TRUE(plain.ok());
  ASSERT_EQ(plain->size(), projected->size());
  for (size_t i = 0; i < plain->size(); ++i) {
    EXPECT_EQ((*plain)[i].point.position, (*projected)[i].point.position) << i;
    EXPECT_EQ((*plain)[i].where.face, (*projected)[i].where.face) << i;
  }
  EXPECT_TRUE(reports_.empty());  // the plain client asks for none

  auto nodes = reporting_->HighOrderNodes(id_, 2, options_);
  ASSERT_TRUE(nodes.ok()) << nodes.status();
  EXPECT_EQ(Phases(), (std::vector<std::string>{"evaluate points"}));  // the fits are cached now
  auto plain_nodes = plain_->HighOrderNodes(id_, 2, options_);
  ASSERT_TRUE(plain_nodes.ok());
  EXPECT_EQ(nodes->nodes, plain_nodes->nodes);
  EXPECT_EQ(nodes->elements, plain_nodes->elements);

  auto integrals = reporting_->Integrate(id_, IntegrationInput{}, options_);
  ASSERT_TRUE(integrals.ok()) << integrals.status();
  EXPECT_EQ(Phases(), (std::vector<std::string>{"integrate"}));
  auto plain_integrals = plain_->Integrate(id_, IntegrationInput{}, options_);
  ASSERT_TRUE(plain_integrals.ok());
  EXPECT_EQ(integrals->area, plain_integrals->area);
  EXPECT_EQ(integrals->volume, plain_integrals->volume);

  auto refined = reporting_->RefineMesh(id_, 3, options_);
  ASSERT_TRUE(refined.ok()) << refined.status();
  EXPECT_EQ(Phases(), (std::vector<std::string>{"evaluate points"}));
  EXPECT_EQ(refined->num_faces, 9 * mesh_.NumFaces());

  // The server's fit passes; the rows received once the last pass has ended.
  auto d = reporting_->ComputeDifferentials(id_, FitOptions{});
  ASSERT_TRUE(d.ok()) << d.status();
  EXPECT_EQ(Phases(), (std::vector<std::string>{"fit", "compute"}));
  FitOptions noisy;
  noisy.degree = 4;
  noisy.noise = NoiseMode::kOn;
  auto smoothed = reporting_->ComputeDifferentials(id_, noisy);
  ASSERT_TRUE(smoothed.ok()) << smoothed.status();
  // light noise (a clean mesh) at degree 4: two smoothing and two local passes (noise.h)
  EXPECT_EQ(Phases(), (std::vector<std::string>{"smooth 1/4", "smooth 2/4", "smooth 3/4", "smooth 4/4", "fit",
                                                "compute"}));
  auto plain_smoothed = plain_->ComputeDifferentials(id_, noisy);  // cached
  ASSERT_TRUE(plain_smoothed.ok());
  EXPECT_EQ(smoothed->values.mean, plain_smoothed->values.mean);
  EXPECT_EQ(smoothed->values.normals, plain_smoothed->values.normals);
  auto cached = reporting_->ComputeDifferentials(id_, noisy);
  ASSERT_TRUE(cached.ok());
  EXPECT_EQ(Phases(), (std::vector<std::string>{"compute"}));  // no pass runs

  v1::ComputeMembraneRequest membrane;
  membrane.set_mesh_id(id_);
  membrane.set_young_modulus(1.0);
  membrane.set_poisson_ratio(0.3);
  const Positions deformed = mesh_.positions * 1.05;
  wire::EncodeDoubles(deformed.data(), deformed.rows(), 3, membrane.mutable_deformed_positions());
  auto m = reporting_->ComputeMembrane(membrane);
  ASSERT_TRUE(m.ok()) << m.status();
  EXPECT_EQ(Phases(), (std::vector<std::string>{"fit", "membrane"}));
  auto plain_m = plain_->ComputeMembrane(membrane);
  ASSERT_TRUE(plain_m.ok());
  EXPECT_TRUE(m->values.pressure == plain_m->values.pressure);  // bit for bit (no NaN on a torus)
  EXPECT_TRUE(m->values.stretches == plain_m->values.stretches);
  EXPECT_EQ(m->values.pressure.size(), mesh_.NumVertices());
}

TEST_F(ProgressClientTest, StatisticsCountTheStreamingVariants) {
  ASSERT_TRUE(reporting_->Integrate(id_, IntegrationInput{}, options_).ok());
  ASSERT_TRUE(plain_->Integrate(id_, IntegrationInput{}, options_).ok());
  auto stats = plain_->GetStatistics();
  ASSERT_TRUE(stats.ok());
  std::map<std::string, int64_t> calls;
  for (const auto& m : stats->methods()) calls[m.method()] = m.count();
  EXPECT_EQ(calls["IntegrateStream"], 1);
  EXPECT_EQ(calls["Integrate"], 1);
}

}  // namespace
}  // namespace geomfit
