// Long runs of the mesh-reader fuzz corpus (tests/mesh/reader_fuzz.h; the test suite
// runs 1500 iterations of it). Usage:
//   reader_fuzz [--iterations N] [--seed S] [--seeds K]
// runs N mutations of each seed file for K consecutive RNG seeds from S, prints the
// outcome counts and the first failures, and exits 1 if any mutation crashed the
// property.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "tests/mesh/reader_fuzz.h"

int main(int argc, char** argv) {
  int64_t iterations = 100000, seeds = 1;
  uint64_t seed = 1;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string flag = argv[i];
    const long long value = std::strtoll(argv[i + 1], nullptr, 10);
    if (flag == "--iterations") {
      iterations = value;
    } else if (flag == "--seed") {
      seed = static_cast<uint64_t>(value);
    } else if (flag == "--seeds") {
      seeds = value;
    } else {
      std::fprintf(stderr, "usage: %s [--iterations N] [--seed S] [--seeds K]\n", argv[0]);
      return 2;
    }
  }
  int failures = 0;
  for (int64_t k = 0; k < seeds; ++k) {
    const auto start = std::chrono::steady_clock::now();
    const geomfit::reader_fuzz::Stats s = geomfit::reader_fuzz::Run(iterations, seed + k);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    std::printf(
        "seed %llu: %lld parses in %.1f s (%.0f/s): rejected %lld, valid %lld, passed on %lld, "
        "failures %zu\n",
        static_cast<unsigned long long>(seed + k), static_cast<long long>(s.parses), seconds,
        s.parses / seconds, static_cast<long long>(s.rejected), static_cast<long long>(s.valid),
        static_cast<long long>(s.passed_on), s.failures.size());
    for (const std::string& f : s.failures) std::printf("  %s\n", f.c_str());
    failures += static_cast<int>(s.failures.size());
  }
  return failures == 0 ? 0 : 1;
}
