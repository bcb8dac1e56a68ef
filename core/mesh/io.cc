// Mesh IO entry points: dispatch by format to core/mesh/formats/.
#include "core/mesh/io.h"

#include <exception>
#include <new>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "core/mesh/formats/common.h"
#include "core/mesh/formats/formats.h"
#include "core/util/status_macros.h"

namespace geomfit {
namespace {

absl::Status OutputOnlyError(absl::string_view source, MeshFormat format) {
  const char* name = MeshFormatName(format);
  return absl::InvalidArgumentError(absl::StrCat(source, ": reading ", name,
                                                 " is not supported (", name,
                                                 " is an output format)"));
}

absl::StatusOr<Mesh> Parse(absl::string_view bytes, MeshFormat format, absl::string_view source) {
  switch (format) {
    case MeshFormat::kObj: return mesh_io::ParseObj(bytes, source);
    case MeshFormat::kOff: return mesh_io::ParseOff(bytes, source);
    case MeshFormat::kPly: return mesh_io::ParsePly(bytes, source);
    case MeshFormat::kStl: return mesh_io::ParseStl(bytes, source);
    case MeshFormat::kVtp:
    case MeshFormat::kVtu: break;
  }
  return OutputOnlyError(source, format);
}

absl::StatusOr<std::string> Format(const Mesh& mesh, MeshFormat format) {
  switch (format) {
    case MeshFormat::kObj: return mesh_io::FormatObj(mesh);
    case MeshFormat::kOff: return mesh_io::FormatOff(mesh);
    case MeshFormat::kPly: return mesh_io::FormatPly(mesh);
    case MeshFormat::kStl: return mesh_io::FormatStl(mesh);
    case MeshFormat::kVtp: return FormatVtp(mesh, {}, VtkOptions{});
    case MeshFormat::kVtu: return FormatVtu(mesh, {}, VtkOptions{});
  }
  return absl::InvalidArgumentError("unknown mesh format");
}

}  // namespace

absl::StatusOr<MeshFormat> FormatFromPath(std::string_view path_in) {
  const absl::string_view path(path_in.data(), path_in.size());
  const size_t dot = path.rfind('.');
  const size_t slash = path.find_last_of("/\\");
  const std::string ext =
      dot == absl::string_view::npos || (slash != absl::string_view::npos && dot < slash)
          ? ""
          : absl::AsciiStrToLower(path.substr(dot + 1));
  if (ext == "obj") return MeshFormat::kObj;
  if (ext == "off") return MeshFormat::kOff;
  if (ext == "ply") return MeshFormat::kPly;
  if (ext == "stl") return MeshFormat::kStl;
  if (ext == "vtp") return MeshFormat::kVtp;
  if (ext == "vtu") return MeshFormat::kVtu;
  return absl::InvalidArgumentError(
      absl::StrCat(path, ": unknown mesh file extension '", ext,
                   "' (expected .obj, .off, .ply, .stl, .vtp or .vtu)"));
}

const char* MeshFormatName(MeshFormat format) {
  switch (format) {
    case MeshFormat::kObj: return "OBJ";
    case MeshFormat::kOff: return "OFF";
    case MeshFormat::kPly: return "PLY";
    case MeshFormat::kStl: return "STL";
    case MeshFormat::kVtp: return "VTP";
    case MeshFormat::kVtu: return "VTU";
  }
  return "?";
}

bool IsOutputOnly(MeshFormat format) {
  return format == MeshFormat::kVtp || format == MeshFormat::kVtu;
}

absl::StatusOr<Mesh> ParseMesh(std::string_view bytes_in, MeshFormat format,
                               std::string_view source_in) {
  // Debian's Abseil is built with its own absl::string_view, distinct from std's.
  const absl::string_view bytes(bytes_in.data(), bytes_in.size());
  const absl::string_view source_name(source_in.data(), source_in.size());
  try {
    absl::StatusOr<Mesh> mesh = Parse(bytes, format, source_name);
    // The readers check indices as they read them (naming the line or element); this
    // guards the contract.
    if (mesh.ok()) {
      absl::Status faces = mesh_io::CheckFaces(*mesh);
      if (!faces.ok())
        return absl::InternalError(absl::StrCat(source_name, ": reader bug: ", faces.message()));
    }
    return mesh;
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(absl::StrCat(source_name, ": out of memory while reading"));
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrCat(source_name, ": ", e.what()));
  }
}

absl::StatusOr<Mesh> ReadMesh(const std::string& path) {
  GF_ASSIGN_OR_RETURN(const MeshFormat format, FormatFromPath(path));
  if (IsOutputOnly(format)) return OutputOnlyError(path, format);
  GF_ASSIGN_OR_RETURN(const FileBytes bytes, ReadFileBytes(path));
  return ParseMesh(bytes.view(), format, path);
}

absl::StatusOr<std::string> FormatMesh(const Mesh& mesh, MeshFormat format) {
  GF_RETURN_IF_ERROR(mesh_io::CheckWritable(mesh));
  try {
    return Format(mesh, format);
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError("out of memory while formatting a mesh");
  }
}

absl::Status WriteMesh(const Mesh& mesh, const std::string& path, const VtkOptions& vtk) {
  GF_ASSIGN_OR_RETURN(const MeshFormat format, FormatFromPath(path));
  if (format == MeshFormat::kVtp) return WriteVtp(path, mesh, {}, vtk);
  if (format == MeshFormat::kVtu) return WriteVtu(path, mesh, {}, vtk);
  return WriteMesh(mesh, path);
}

absl::Status WriteMesh(const Mesh& mesh, const std::string& path) {
  GF_ASSIGN_OR_RETURN(const MeshFormat format, FormatFromPath(path));
  absl::StatusOr<std::string> bytes = FormatMesh(mesh, format);
  if (!bytes.ok())
    return absl::Status(bytes.status().code(), absl::StrCat(path, ": ", bytes.status().message()));
  return WriteFileAtomically(path, *bytes);
}

}  // namespace geomfit
