#pragma once
// The `geomfit` command-line tool: shared pieces of the in-process (--local) mode
// (local.cc) and the service mode (--server, remote.cc when built with the client).
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "core/fitting/options.h"
#include "core/mesh/io.h"
#include "core/mesh/mesh.h"
#include "core/quantities/differentials.h"
#include "geomfit/version.h"

namespace geomfit {
struct HighOrderMesh;
}  // namespace geomfit

namespace geomfit::cli {

/// Exit codes: 0 success, 1 runtime error (I/O, invalid mesh, server), 2 usage error.
inline constexpr int kExitOk = 0;
inline constexpr int kExitRuntimeError = 1;
inline constexpr int kExitUsageError = 2;
inline constexpr int kExitInterrupted = 130;  ///< Ctrl-C stopped the work (interrupt.h)

/// An INVALID_ARGUMENT status marked as a usage error (bad command line), so that
/// Main() exits with 2 rather than 1.
absl::Status UsageError(absl::string_view message);
bool IsUsageError(const absl::Status& status);

/// A small command-line parser shared by every subcommand: `--name value`,
/// `--name=value`, boolean `--flag`, positionals in order, `--` ends options,
/// `-h`/`--help`. Values are stored straight into the caller's variables, whose
/// values at registration are shown as defaults in Usage().
/// How the CLI reaches a server: TLS files and the bearer token, shared by every
/// service command (set by the flags ArgParser::Server adds; read by ConnectTo).
struct RemoteTransport {
  std::string tls_ca, tls_cert, tls_key;
  std::string token_file;  ///< else $GEOMFIT_TOKEN
};
RemoteTransport& Transport();

class ArgParser {
 public:
  /// `command` is e.g. "geomfit curvature"; `synopsis` follows it in the usage line.
  ArgParser(std::string command, std::string synopsis, std::string description = "");

  ArgParser& Flag(const std::string& name, bool* out, const std::string& help);
  ArgParser& Int(const std::string& name, int* out, const std::string& help);
  ArgParser& UInt64(const std::string& name, uint64_t* out, const std::string& help);
  ArgParser& Double(const std::string& name, double* out, const std::string& help);
  ArgParser& String(const std::string& name, std::string* out, const std::string& help,
                    const std::string& value_name = "VALUE");
  /// --server HOST:PORT and the transport flags (--tls-ca, --tls-cert, --tls-key,
  /// --token-file) filling Transport().
  ArgParser& Server(std::string* out, const std::string& help);
  /// A required positional argument (in registration order).
  ArgParser& Positional(const std::string& name, std::string* out, const std::string& help);

  /// Parses `args` (everything after the subcommand). Errors are usage errors.
  /// After --help, missing positionals are not an error.
  absl::Status Parse(const std::vector<std::string>& args);
  bool help_requested() const { return help_; }
  /// True if option `name` (without dashes) appeared on the command line.
  bool WasSet(const std::string& name) const;
  std::string Usage() const;

 private:
  enum class Kind { kFlag, kInt, kUInt64, kDouble, kString };
  struct Option {
    std::string name, help, value_name, default_text;
    Kind kind;
    void* out;
    bool set = false;
  };
  struct Arg {
    std::string name, help;
    std::string* out;
  };
  ArgParser& Add(const std::string& name, Kind kind, void* out, const std::string& help,
                 const std::string& value_name, const std::string& default_text);
  absl::Status Store(Option& option, const std::string& value);

  std::string command_, synopsis_, description_;
  std::vector<Option> options_;
  std::vector<Arg> positionals_;
  bool help_ = false;
};

/// True if `args` contains `--name` or `--name=...` before any `--`.
bool HasOption(const std::vector<std::string>& args, const std::string& name);

/// Arguments of `geomfit curvature`, shared by --local and --server.
struct CurvatureArgs {
  std::string mesh;    ///< mesh file (local) or mesh file / id (remote)
  bool local = false;  ///< --local: in-process (the default without --server)
  std::string server;  ///< --server HOST:PORT
  FitOptions fit;      ///< --degree, --rings, --method, --two-pass, --approximate, ...
  std::string method = "lhf";
  bool interpolate = false;  ///< --interpolate: explicit default
  bool approximate = false;  ///< --approximate: fit need not pass through the vertex
  bool plain_cubic = false;  ///< --plain-cubic: FitOptions::cubic_hermite off
  bool plain_plane = false;  ///< --plain-plane: FitOptions::plane_hermite off
  bool hermite_jets = false;  ///< --hermite-jets: FitOptions::jet_hermite on (degrees 4-5)
  bool plain_jets = false;    ///< --plain-jets: FitOptions::jet_hermite off
  std::string noise = "off";  ///< --noise off|on|auto
  std::string solver = "qr";  ///< --solver qr|svd
  std::string output;        ///< .vtp, .vtu, .npy, .tsv / .txt; empty = TSV on stdout
  bool ascii = false;        ///< --ascii: .vtp/.vtu arrays as text (default binary appended)
  bool zlib = false;         ///< --zlib: .vtp/.vtu appended arrays zlib-compressed
  bool verbose = false;
  int threads = 0;           ///< --threads; 0 = all cores
};

/// Registers the curvature options on `parser`, writing into `args`.
void AddCurvatureOptions(ArgParser* parser, CurvatureArgs* args);
/// Parses the curvature command line and checks everything that needs no mesh
/// (option ranges via ValidateFitOptions, output extension): usage errors. With
/// --help it prints the usage to stdout and sets *help.
absl::Status ParseCurvatureArgs(const std::vector<std::string>& argv, CurvatureArgs* args,
                                bool* help);

// ---- Output of per-vertex differential quantities (output.cc) ----

enum class OutputKind { kTsv, kNpy, kVtp, kVtu };
/// By extension: .tsv/.txt, .npy, .vtp, .vtu (any case). Unknown: a usage error.
absl::StatusOr<OutputKind> OutputKindFromPath(const std::string& path);
/// True if writing `path` needs the mesh (VTK outputs).
bool OutputNeedsMesh(const std::string& path);

/// The mesh format of an output path by extension; "-" and other streams (/dev/null)
/// without one get OBJ. Unknown extension: a usage error.
absl::StatusOr<MeshFormat> MeshOutputFormat(const std::string& path);
/// WriteMesh, or for "-" / a stream path its bytes written there (text formats).
absl::Status WriteMeshOutput(const Mesh& mesh, const std::string& path, const VtkOptions& vtk = {});

/// Column names of the table (the TSV header); the first 13 are the NPY columns.
const std::vector<std::string>& DifferentialsColumns();
/// #V x 13: nx ny nz H K k1 k2 e1x e1y e1z e2x e2y e2z (NaN where not computed).
RowMajorMatrixXd DifferentialsTable(const Differentials& d);
/// Header line ("# nx\tny...", a comment for numpy.loadtxt), then one tab-separated line per vertex (%.17g; then degree_used,
/// points, flags from the diagnostics, 0 when absent).
std::string DifferentialsTsv(const Differentials& d);
/// VTK point arrays: Normals, MeanCurvature, GaussianCurvature, k1, k2, Direction1,
/// Direction2, CurvatureTensor (Float64), DegreeUsed, StencilPoints (Int32), Flags
/// (UInt8) (those present).
std::vector<PointField> DifferentialsFields(const Differentials& d);
/// Writes by extension; an empty path writes TSV to stdout. `mesh` is needed for
/// .vtp/.vtu, written in `encoding` with Normals and MeanCurvature as the active normals
/// and scalars.
absl::Status WriteDifferentials(const std::string& path, const Mesh& mesh, const Differentials& d,
                                VtkEncoding encoding = VtkEncoding::kAppended);
/// The quantities an output to `path` shows: all but the curvature tensor, which only
/// the VTK outputs (.vtp, .vtu) carry.
uint32_t OutputQuantities(const std::string& path);
/// `d` with its rows moved to source order: row i is vertex source[i]'s (a fit on the
/// mesh relabelled for locality); empty `source`: `d` as it is.
Differentials InSourceOrder(Differentials d, const std::vector<int32_t>& source);
/// WriteDifferentials(path, mesh, InSourceOrder(d, source), encoding); a .npy table is
/// gathered from `d`'s rows block by block as it is written instead (the same bytes).
absl::Status WriteRelabelledDifferentials(const std::string& path, const Mesh& mesh, Differentials d,
                                          const std::vector<int32_t>& source, VtkEncoding encoding);
/// The VTK encoding the --ascii and --zlib flags ask for (usage error when both).
absl::StatusOr<VtkEncoding> VtkEncodingFromFlags(bool ascii, bool zlib);

/// High-order elements (`geomfit nodes`) as VTK Lagrange triangles and quadrilaterals
/// (binary appended), which ParaView draws curved.
absl::Status WriteLagrangeVtu(const std::string& path, const HighOrderMesh& ho);

// ---- Commands: each returns OK, a usage error or a runtime error ----

absl::Status RunCurvature(const std::vector<std::string>& args);  ///< local.cc
absl::Status RunGenerate(const std::vector<std::string>& args);   ///< local.cc
absl::Status RunConvert(const std::vector<std::string>& args);    ///< local.cc
absl::Status RunProject(const std::vector<std::string>& args);    ///< reconstruct.cc
absl::Status RunRefine(const std::vector<std::string>& args);     ///< reconstruct.cc
absl::Status RunNodes(const std::vector<std::string>& args);      ///< reconstruct.cc
absl::Status RunIntegrate(const std::vector<std::string>& args);  ///< reconstruct.cc
absl::Status RunFlowCommand(const std::vector<std::string>& args);      ///< flow.cc
absl::Status RunOperatorCommand(const std::vector<std::string>& args);  ///< flow.cc
absl::Status RunMembraneCommand(const std::vector<std::string>& args);  ///< membrane.cc

#ifdef GEOMFIT_WITH_CLIENT
}  // namespace geomfit::cli
#include "clients/cpp/client/client.h"
namespace geomfit::cli {
/// A client of the server at HOST:PORT (remote.cc).
std::unique_ptr<Client> ConnectTo(const std::string& server);
/// Parses a service subcommand that takes --server and positionals; false with OK =
/// --help was printed.
absl::StatusOr<bool> ParseRemote(ArgParser& p, const std::vector<std::string>& args, const std::string& server);
/// MESH on the command line is a file (uploaded, idempotently; read into *mesh) or the
/// id of a stored mesh (*mesh left empty). Returns the mesh id.
absl::StatusOr<std::string> RemoteMeshId(Client& client, const std::string& mesh_arg, bool verbose, Mesh* mesh);
/// Service mode (remote.cc): `curvature --server ...` with parsed arguments.
absl::Status RunCurvatureRemote(const CurvatureArgs& args);
/// Service-only commands (remote.cc): upload, update, info, list, delete, health.
/// Returns a usage error for a command it does not know.
absl::Status RunRemoteCommand(const std::string& command, const std::vector<std::string>& args);
/// `geomfit jobs list|get|watch|cancel` (jobs.cc).
absl::Status RunJobs(const std::vector<std::string>& args);
/// One line per job event: "job ID #SEQ STATE step N PHASE done/total counts values results: message".
std::string FormatJobEvent(const v1::JobEvent& event);
/// Starts a refine job and watches it (progress lines on stderr) to its end: the level
/// meshes (coarsest first), or the job's error.
absl::StatusOr<std::vector<v1::JobResultMesh>> RunRefineJob(Client& client, const v1::RefineJob& spec);
/// Client::WatchJob with Ctrl-C cancelling the job on the server (the watch then ends
/// with the job's final CANCELLED event; see InterruptHandler). `*last` gets the last
/// event seen.
absl::Status WatchJobCancellingOnInterrupt(Client& client, const std::string& job_id, int64_t from_event,
                                           const std::function<bool(const v1::JobEvent&)>& on_event,
                                           v1::JobEvent* last);
/// OK for a SUCCEEDED final event; CANCELLED for a job cancelled (e.g. by Ctrl-C);
/// else a runtime error naming the job's end. `what` names the job ("job", "flow job").
absl::Status JobOutcome(const v1::JobEvent& last, const std::string& what = "job");
#endif

/// Names of the service-only commands (for help text and a clear error when the
/// client is not built in).
inline const std::vector<std::string>& RemoteCommandNames() {
  static const std::vector<std::string> names = {"upload", "update", "info", "list", "delete", "jobs", "health"};
  return names;
}
inline constexpr char kNoClientMessage[] = "this geomfit was built without the service client";

#ifdef GEOMFIT_CLI_FRONT
/// The lean front end (front.cc): Main saves argv; RunInFullCli replaces the process
/// by `geomfit-full` (next to this binary) with that command line, returning only
/// when it cannot.
void SaveCommandLine(char** argv);
absl::Status RunInFullCli();
#endif

/// The whole program: returns the exit code. Errors go to stderr as ONE line
/// `geomfit: error: <message>`.
int Main(int argc, char** argv);

}  // namespace geomfit::cli
