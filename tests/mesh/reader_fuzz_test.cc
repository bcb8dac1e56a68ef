// Seeded fuzz corpus of the mesh readers (the property is in reader_fuzz.h). The
// default run is small; GEOMFIT_FUZZ_ITERATIONS and GEOMFIT_FUZZ_SEED override it, and
// bench/reader_fuzz runs it for long.
#include <cstdlib>
#include <string>

#include "absl/strings/str_join.h"
#include "gtest/gtest.h"
#include "tests/mesh/reader_fuzz.h"

namespace geomfit {
namespace {

int64_t EnvInt(const char* name, int64_t fallback) {
  const char* v = std::getenv(name);
  return v != nullptr && *v != '\0' ? std::strtoll(v, nullptr, 10) : fallback;
}

TEST(ReaderFuzzTest, SeedsAreValid) {
  for (const reader_fuzz::SeedFile& s : reader_fuzz::SeedFiles()) {
    auto m = ParseMesh(s.bytes, s.format, s.name);
    ASSERT_TRUE(m.ok()) << m.status();
    EXPECT_EQ(m->NumFaces(), s.format == MeshFormat::kStl ? 6 : 5) << s.name;
    EXPECT_EQ(m->NumVertices(), 5) << s.name;
    EXPECT_TRUE(ValidateMesh(*m).ok()) << s.name;
  }
}

TEST(ReaderFuzzTest, MutationsNeverCrashOrYieldBrokenMeshes) {
  const int64_t iterations = EnvInt("GEOMFIT_FUZZ_ITERATIONS", 1500);
  const uint64_t seed = static_cast<uint64_t>(EnvInt("GEOMFIT_FUZZ_SEED", 20261123));
  const reader_fuzz::Stats stats = reader_fuzz::Run(iterations, seed);
  EXPECT_TRUE(stats.failures.empty()) << absl::StrJoin(stats.failures, "\n");
  // The corpus exercises every outcome: rejections, valid meshes, passed-on problems.
  EXPECT_EQ(stats.parses, 7 + 7 * 4 * iterations);
  EXPECT_GT(stats.rejected, stats.parses / 2);
  EXPECT_GT(stats.valid, iterations / 2);
  EXPECT_GT(stats.passed_on, iterations / 20);
  std::printf("parses %lld: rejected %lld, valid %lld, passed on to ValidateMesh %lld\n",
              static_cast<long long>(stats.parses), static_cast<long long>(stats.rejected),
              static_cast<long long>(stats.valid), static_cast<long long>(stats.passed_on));
}

}  // namespace
}  // namespace geomfit
