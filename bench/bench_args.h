#pragma once
// Command-line helpers shared by the plain bench programs.
#include <sstream>
#include <string>
#include <vector>

namespace geomfit {

/// The comma-separated items of `arg`, or of `fallback` when `arg` is null.
inline std::vector<std::string> SplitList(const char* arg, const char* fallback) {
  std::vector<std::string> out;
  std::stringstream ss(arg ? arg : fallback);
  for (std::string s; std::getline(ss, s, ',');) out.push_back(s);
  return out;
}

}  // namespace geomfit
