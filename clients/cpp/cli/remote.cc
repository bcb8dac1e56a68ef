// Service mode of the `geomfit` tool (--server HOST:PORT): upload, update, info,
// list, delete, and curvature on a geomfit server, with the local output formats.
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "clients/cpp/cli/cli.h"
#include "clients/cpp/cli/progress.h"
#include "clients/cpp/client/client.h"
#include "core/util/status_macros.h"

namespace geomfit::cli {
std::unique_ptr<Client> ConnectTo(const std::string& server) {
  ClientOptions o;
  o.target = server;
  o.tls_ca = Transport().tls_ca;
  o.tls_cert = Transport().tls_cert;
  o.tls_key = Transport().tls_key;
  if (!Transport().token_file.empty()) {
    std::ifstream in(Transport().token_file);
    std::getline(in, o.token);  // an unreadable file sends no token: UNAUTHENTICATED names the problem
  } else if (const char* token = std::getenv("GEOMFIT_TOKEN"); token != nullptr) {
    o.token = token;
  }
  // The server's progress of long calls feeds the bar (its phases: fit, project, ...).
  if (ProgressBar::Get().enabled())
    o.progress = [](const Progress& p) { ProgressBar::Get().Update(p.phase, p.done, p.total); };
  return Client::Connect(o);
}

absl::StatusOr<bool> ParseRemote(ArgParser& p, const std::vector<std::string>& args, const std::string& server) {
  GF_RETURN_IF_ERROR(p.Parse(args));
  if (p.help_requested()) {
    std::fputs(p.Usage().c_str(), stdout);
    return false;
  }
  if (server.empty()) return UsageError("this command needs --server HOST:PORT");
  return true;
}

namespace {

/// One tab-separated line per mesh, under a header line.
std::string MeshTable(const std::vector<RemoteMesh>& meshes) {
  std::string out = "mesh_id\trevision\tvertices\tfaces\tname\tcontent_hash\tbbox_min\tbbox_max\n";
  for (const RemoteMesh& m : meshes) {
    absl::StrAppendFormat(&out, "%s\t%d\t%d\t%d\t%s\t%s\t%.17g,%.17g,%.17g\t%.17g,%.17g,%.17g\n", m.mesh_id,
                          m.revision, m.num_vertices, m.num_faces, m.name, m.content_hash, m.bbox_min.x(),
                          m.bbox_min.y(), m.bbox_min.z(), m.bbox_max.x(), m.bbox_max.y(), m.bbox_max.z());
  }
  return out;
}

absl::Status Print(const std::vector<RemoteMesh>& meshes) {
  std::fputs(MeshTable(meshes).c_str(), stdout);
  return absl::OkStatus();
}

absl::StatusOr<std::map<std::string, std::string>> ParseLabels(const std::string& text) {
  std::map<std::string, std::string> labels;
  if (text.empty()) return labels;
  for (absl::string_view kv : absl::StrSplit(text, ',')) {
    std::pair<std::string, std::string> p = absl::StrSplit(kv, absl::MaxSplits('=', 1));
    if (p.first.empty()) return UsageError(absl::StrCat("--labels: '", kv, "' is not KEY=VALUE"));
    labels[p.first] = p.second;
  }
  return labels;
}

absl::Status Upload(const std::vector<std::string>& args) {
  std::string server, path, name, labels_text;
  ArgParser p("geomfit upload", "--server HOST:PORT MESH [--name NAME] [--labels K=V,...]",
              "Uploads a mesh file; prints its id and info (idempotent for identical content).");
  p.Server(&server, "geomfit server")
      .Positional("MESH", &path, "mesh file (.obj .off .ply .stl)")
      .String("name", &name, "mesh name (default: the file name)", "NAME")
      .String("labels", &labels_text, "comma-separated KEY=VALUE labels", "LABELS");
  GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, args, server));
  if (!run) return absl::OkStatus();
  GF_ASSIGN_OR_RETURN(auto labels, ParseLabels(labels_text));
  GF_ASSIGN_OR_RETURN(const Mesh mesh, ReadMesh(path));
  if (name.empty()) name = std::filesystem::path(path).filename().string();
  GF_ASSIGN_OR_RETURN(RemoteMesh info, ConnectTo(server)->Upload(mesh, name, labels));
  return Print({info});
}

absl::Status Update(const std::vector<std::string>& args) {
  std::string server, id, path;
  int expected = 0;
  ArgParser p("geomfit update", "--server HOST:PORT MESH_ID MESH [--expected-revision R]",
              "Replaces the positions of a stored mesh by those of a mesh file with the same\n"
              "connectivity; prints the new revision.");
  p.Server(&server, "geomfit server")
      .Positional("MESH_ID", &id, "id of the stored mesh")
      .Positional("MESH", &path, "mesh file with the new positions")
      .Int("expected-revision", &expected, "fail (ABORTED) unless the mesh is at this revision; 0 = any");
  GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, args, server));
  if (!run) return absl::OkStatus();
  GF_ASSIGN_OR_RETURN(const Mesh mesh, ReadMesh(path));
  std::optional<int64_t> want;
  if (expected > 0) want = expected;
  GF_ASSIGN_OR_RETURN(RemoteMesh info, ConnectTo(server)->UpdatePositions(id, mesh.positions, want));
  return Print({info});
}

absl::Status Info(const std::vector<std::string>& args) {
  std::string server, id;
  ArgParser p("geomfit info", "--server HOST:PORT MESH|MESH_ID",
              "Prints what the server stores about a mesh: a stored mesh's id, or a mesh file\n"
              "(uploaded, idempotently, as every command taking MESH does).");
  p.Server(&server, "geomfit server")
      .Positional("MESH", &id, "mesh file (.obj .off .ply .stl) or id of a stored mesh");
  GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, args, server));
  if (!run) return absl::OkStatus();
  std::unique_ptr<Client> client = ConnectTo(server);
  Mesh mesh;
  GF_ASSIGN_OR_RETURN(id, RemoteMeshId(*client, id, false, &mesh));
  GF_ASSIGN_OR_RETURN(RemoteMesh info, client->GetMesh(id));
  return Print({info});
}

absl::Status List(const std::vector<std::string>& args) {
  std::string server;
  ArgParser p("geomfit list", "--server HOST:PORT", "Lists the stored meshes.");
  p.Server(&server, "geomfit server");
  GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, args, server));
  if (!run) return absl::OkStatus();
  GF_ASSIGN_OR_RETURN(std::vector<RemoteMesh> meshes, ConnectTo(server)->ListMeshes());
  return Print(meshes);
}

absl::Status Delete(const std::vector<std::string>& args) {
  std::string server, id;
  ArgParser p("geomfit delete", "--server HOST:PORT MESH_ID", "Deletes a stored mesh.");
  p.Server(&server, "geomfit server").Positional("MESH_ID", &id, "id of the stored mesh");
  GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, args, server));
  if (!run) return absl::OkStatus();
  return ConnectTo(server)->DeleteMesh(id);
}

/// grpc.health.v1 Check: prints the status; OK only when SERVING (container
/// HEALTHCHECKs and readiness scripts run it).
absl::Status Health(const std::vector<std::string>& args) {
  std::string server, service;
  double timeout = 5;
  ArgParser p("geomfit health", "--server HOST:PORT [--service NAME] [--timeout SECONDS]",
              "Asks the server's grpc.health.v1 service; prints SERVING, NOT_SERVING (draining), ...\n"
              "Exit status 0 only when SERVING.");
  p.Server(&server, "geomfit server")
      .String("service", &service, "service name; empty = the whole server (geomfit.v1.GeomFit also works)", "NAME")
      .Double("timeout", &timeout, "seconds to wait for the answer");
  GF_ASSIGN_OR_RETURN(bool run, ParseRemote(p, args, server));
  if (!run) return absl::OkStatus();
  if (!(timeout > 0)) return UsageError("--timeout must be positive");
  ClientOptions o;
  o.target = server;
  o.deadline = std::chrono::milliseconds(static_cast<int64_t>(timeout * 1e3));
  o.max_attempts = 1;
  GF_ASSIGN_OR_RETURN(const std::string status, Client::Connect(o)->CheckHealth(service));
  std::printf("%s\n", status.c_str());
  if (status != "SERVING") return absl::UnavailableError(absl::StrCat(server, " is ", status));
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::string> RemoteMeshId(Client& client, const std::string& mesh_arg, bool verbose, Mesh* mesh) {
  if (!std::filesystem::exists(mesh_arg)) return mesh_arg;
  ProgressBar::Get().Begin("read");
  GF_ASSIGN_OR_RETURN(*mesh, ReadMesh(mesh_arg));
  ProgressBar::Get().Begin("upload");
  GF_ASSIGN_OR_RETURN(RemoteMesh info, client.Upload(*mesh, std::filesystem::path(mesh_arg).filename().string()));
  if (verbose) std::fprintf(stderr, "geomfit: uploaded %s as %s\n", mesh_arg.c_str(), info.mesh_id.c_str());
  return info.mesh_id;
}

absl::Status RunCurvatureRemote(const CurvatureArgs& a) {
  std::unique_ptr<Client> client = ConnectTo(a.server);
  // MESH is a file (uploaded first; idempotent) or the id of a stored mesh.
  Mesh mesh;
  GF_ASSIGN_OR_RETURN(const std::string id, RemoteMeshId(*client, a.mesh, a.verbose, &mesh));
  if (mesh.NumVertices() == 0 && OutputNeedsMesh(a.output)) {
    ProgressBar::Get().Begin("download");
    GF_ASSIGN_OR_RETURN(mesh, client->Download(id));  // VTP/VTU need the mesh
  }
  ProgressBar::Get().Begin("compute");
  GF_ASSIGN_OR_RETURN(RemoteDifferentials d, client->ComputeDifferentials(id, a.fit, kAllQuantities, 0, true));
  if (a.verbose) {
    std::fprintf(stderr, "geomfit: revision %lld, degree %d (min used %d), fit %s %.3f ms, evaluate %.3f ms\n",
                 static_cast<long long>(d.summary.revision), d.summary.degree_requested, d.summary.min_degree_used,
                 d.summary.fit_cache_hit ? "cached" : "computed", d.summary.fit_ms, d.summary.evaluate_ms);
  }
  ProgressBar::Get().Begin("write");
  GF_ASSIGN_OR_RETURN(const VtkEncoding encoding, VtkEncodingFromFlags(a.ascii, a.zlib));
  return WriteDifferentials(a.output, mesh, d.values, encoding);
}

absl::Status RunRemoteCommand(const std::string& command, const std::vector<std::string>& args) {
  if (command == "upload") return Upload(args);
  if (command == "update") return Update(args);
  if (command == "info") return Info(args);
  if (command == "list") return List(args);
  if (command == "delete") return Delete(args);
  if (command == "jobs") return RunJobs(args);
  if (command == "health") return Health(args);
  return UsageError(absl::StrCat("unknown service command '", command, "'"));
}

}  // namespace geomfit::cli
