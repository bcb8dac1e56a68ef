#pragma once
#include <Eigen/Core>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"

namespace geomfit {

struct VtkOptions;

/// Mesh file formats. VTP (VTK XML PolyData) and VTU (VTK XML UnstructuredGrid) are
/// write-only.
enum class MeshFormat { kObj, kOff, kPly, kStl, kVtp, kVtu };

/// The format named by a path's extension (.obj .off .ply .stl .vtp .vtu, any case).
absl::StatusOr<MeshFormat> FormatFromPath(std::string_view path);
const char* MeshFormatName(MeshFormat format);
/// True for the formats geomfit writes but does not read (VTP, VTU).
bool IsOutputOnly(MeshFormat format);

/// Parses a mesh held in memory (an uploaded file, a test's bytes). Readers check
/// syntax, counts, face sizes (3 or 4) and that every face index names an existing
/// vertex, and never trust a count further than the bytes that follow it; what they
/// return always has valid connectivity arrays. Non-finite coordinates, zero-area and
/// non-manifold faces are passed through for ValidateMesh to reject. Errors
/// (INVALID_ARGUMENT) start with `source_name` and give the line (text) or the face
/// and byte offset (binary).
///  - OBJ: `v` and `f` lines (v, v/vt, v/vt/vn, v//vn; negative = relative); rest ignored.
///  - OFF: optional [ST][C][N]OFF keyword, `#` comments; one vertex or face per line,
///    extra fields (colours) ignored.
///  - PLY: ascii and binary_little_endian; x, y, z of any numeric type; other
///    properties and elements skipped; faces from `vertex_indices` / `vertex_index`.
///  - STL: binary when the size is 84 + 50 n, else ascii; vertices with bitwise-equal
///    coordinates are welded.
absl::StatusOr<Mesh> ParseMesh(std::string_view bytes, MeshFormat format,
                               std::string_view source_name = "mesh");

/// Reads a mesh file; the format comes from the extension.
absl::StatusOr<Mesh> ReadMesh(const std::string& path);

/// Serializes a mesh; every writer (VTP too) refuses, with INVALID_ARGUMENT naming the
/// face, a mesh whose faces are not 3 or 4 indices of existing vertices (a triangle
/// carries -1 last). OBJ and OFF as text with %.17g (exact round trip), PLY as
/// binary little endian with double coordinates and int indices, STL as binary
/// (float32 coordinates; quads split along their 0-2 diagonal).
absl::StatusOr<std::string> FormatMesh(const Mesh& mesh, MeshFormat format);

/// Writes a mesh in the format named by the extension (.vtp and .vtu: no point data,
/// binary appended; see VtkOptions).
/// Like every writer here it writes `path + ".tmp"` and renames it, so a failed write
/// never leaves a partial file under `path`.
absl::Status WriteMesh(const Mesh& mesh, const std::string& path);
/// The same; `vtk` applies to .vtp and .vtu (e.g. ASCII).
absl::Status WriteMesh(const Mesh& mesh, const std::string& path, const VtkOptions& vtk);

/// The VTK type a point field is stored as. Integer types need integral values in range.
enum class VtkType { kFloat64, kInt32, kUInt8 };

/// A per-vertex array for VTK output: rows = #V, cols = components (1, 3, 9, ...).
struct PointField {
  std::string name;
  Eigen::MatrixXd values;
  VtkType type = VtkType::kFloat64;
};

/// How VTK XML files store their arrays.
enum class VtkEncoding {
  /// Text, %.17g (an array holding a NaN or infinity, which VTK's ASCII parser cannot
  /// read, goes inline base64 instead, bit-exact).
  kAscii,
  /// Raw little-endian bytes in one <AppendedData> block (UInt64 size headers), as
  /// VTK's own writers do: about a quarter of the ASCII size, read several times faster.
  kAppended,
  /// As kAppended, each array zlib-compressed in 32 KiB blocks (VTK's
  /// vtkZLibDataCompressor layout: UInt64 block count, block size, last block's size and
  /// every block's compressed size, then the blocks): smaller files, slower to write.
  kAppendedZlib,
};

struct VtkOptions {
  VtkEncoding encoding = VtkEncoding::kAppended;
  /// Fields made the active attributes of <PointData> (`Normals="..."`, `Scalars="..."`:
  /// viewers smooth-shade with the normals and colour by the scalars); empty = none.
  /// Must name a field with 3 components (normals) or 1 (scalars).
  std::string normals, scalars;
};

/// VTK XML PolyData (.vtp): Points, Polys (triangles and quads) and one PointData
/// array per field. The two-argument forms write ASCII without active attributes.
absl::StatusOr<std::string> FormatVtp(const Mesh& mesh, const std::vector<PointField>& fields);
absl::StatusOr<std::string> FormatVtp(const Mesh& mesh, const std::vector<PointField>& fields,
                                      const VtkOptions& options);
absl::Status WriteVtp(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields);
absl::Status WriteVtp(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields, const VtkOptions& options);

/// VTK XML UnstructuredGrid (.vtu, read by meshio too): the same points and fields,
/// faces as VTK_TRIANGLE / VTK_QUAD cells.
absl::StatusOr<std::string> FormatVtu(const Mesh& mesh, const std::vector<PointField>& fields,
                                      const VtkOptions& options = {});
absl::Status WriteVtu(const std::string& path, const Mesh& mesh,
                      const std::vector<PointField>& fields, const VtkOptions& options = {});

/// Cells of any VTK type (Lagrange elements, say) for .vtu output.
struct VtkCells {
  std::vector<int64_t> offsets = {0};  ///< cell c: connectivity[offsets[c] .. offsets[c + 1])
  std::vector<int32_t> connectivity;   ///< point ids
  std::vector<uint8_t> types;          ///< VTK cell type of each cell
};
/// Errors name the cell whose point id is out of range, or the sizes that disagree.
absl::StatusOr<std::string> FormatVtu(const Positions& points, const VtkCells& cells,
                                      const std::vector<PointField>& fields,
                                      const VtkOptions& options = {});
absl::Status WriteVtu(const std::string& path, const Positions& points, const VtkCells& cells,
                      const std::vector<PointField>& fields, const VtkOptions& options = {});

using RowMajorMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

/// NumPy .npy v1.0: '<f8', fortran_order False, shape (rows, cols).
std::string FormatNpy(const Eigen::Ref<const RowMajorMatrixXd>& a);
absl::Status WriteNpy(const std::string& path, const Eigen::Ref<const RowMajorMatrixXd>& a);
/// WriteNpy of a rows x cols table made a block of rows at a time: fill(begin, end, out)
/// stores rows [begin, end) row-major at out. Each block (~256 KB: it stays in the
/// cache) is written as it is made; the table is never whole in memory.
absl::Status WriteNpy(const std::string& path, int64_t rows, int64_t cols,
                      const std::function<void(int64_t begin, int64_t end, double* out)>& fill);

/// Whole-file helpers shared by the writers and the CLI. Errors name the path and
/// the errno text.
absl::StatusOr<std::string> ReadFileToString(const std::string& path);
/// A whole file's bytes, read into memory that is not zeroed first (ReadMesh: a
/// std::string would first fill its ~9 MB with zeros only to overwrite them).
struct FileBytes {
  std::unique_ptr<char[]> data;
  size_t size = 0;
  std::string_view view() const { return {data.get(), size}; }
};
absl::StatusOr<FileBytes> ReadFileBytes(const std::string& path);
/// Writes `path + ".tmp"`, then renames it to `path`. "-" writes to standard output,
/// and an existing file that is not a regular file (/dev/null, a FIFO, /dev/stdout)
/// is written in place.
absl::Status WriteFileAtomically(const std::string& path, std::string_view contents);
/// The same for contents produced in pieces: `next()` returns each piece in turn (valid
/// until the next call), then an empty one. Each piece is one write() to the file.
absl::Status WriteFileAtomicallyInPieces(const std::string& path,
                                         const std::function<std::string_view()>& next);
/// True for "-" and for existing paths that are not regular files (see above).
bool IsStreamPath(const std::string& path);

}  // namespace geomfit
