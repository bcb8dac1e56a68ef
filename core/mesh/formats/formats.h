#pragma once
// Internal to core/mesh: one reader and one writer per format (io.cc dispatches by
// extension). Readers return meshes that pass CheckFaces (common.h); writers are only
// called with meshes that pass it.
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "core/mesh/mesh.h"

namespace geomfit::mesh_io {

/// `fast_path` false: every line through the general (tokenising) path, for tests that
/// compare the two.
absl::StatusOr<Mesh> ParseObj(absl::string_view bytes, absl::string_view source,
                              bool fast_path = true);
absl::StatusOr<Mesh> ParseOff(absl::string_view bytes, absl::string_view source,
                              bool fast_path = true);
absl::StatusOr<Mesh> ParsePly(absl::string_view bytes, absl::string_view source);
absl::StatusOr<Mesh> ParseStl(absl::string_view bytes, absl::string_view source);

std::string FormatObj(const Mesh& mesh);
std::string FormatOff(const Mesh& mesh);
std::string FormatPly(const Mesh& mesh);
std::string FormatStl(const Mesh& mesh);

}  // namespace geomfit::mesh_io
