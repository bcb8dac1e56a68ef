#include "clients/cpp/client/client.h"

#include <atomic>
#include <fstream>
#include <sstream>
#include <thread>

#include <grpcpp/grpcpp.h>
#include <grpcpp/impl/codegen/client_unary_call.h>

#include "absl/strings/str_cat.h"
#include "core/mesh/content_hash.h"
#include "core/util/status_macros.h"
#include "geomfit/v1/geomfit.grpc.pb.h"
#include "proto/wire.h"

namespace geomfit {
namespace {

absl::StatusOr<std::string> ReadCredential(const char* what, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(what, ": cannot read ", path));
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Insecure credentials unless the options ask for TLS.
absl::StatusOr<std::shared_ptr<grpc::ChannelCredentials>> ChannelCredentialsFor(const ClientOptions& o) {
  if (!o.tls && o.tls_ca.empty() && o.tls_cert.empty() && o.tls_key.empty()) {
    return grpc::InsecureChannelCredentials();
  }
  if (o.tls_cert.empty() != o.tls_key.empty()) return absl::InvalidArgumentError("tls_cert and tls_key go together");
  grpc::SslCredentialsOptions ssl;
  if (!o.tls_ca.empty()) {
    GF_ASSIGN_OR_RETURN(ssl.pem_root_certs, ReadCredential("tls_ca", o.tls_ca));
  }
  if (!o.tls_cert.empty()) {
    GF_ASSIGN_OR_RETURN(ssl.pem_cert_chain, ReadCredential("tls_cert", o.tls_cert));
    GF_ASSIGN_OR_RETURN(ssl.pem_private_key, ReadCredential("tls_key", o.tls_key));
  }
  return grpc::SslCredentials(ssl);
}

/// Writes a client stream and finishes it. Every chunk but the last may be buffered,
/// and the last carries the half-close, so a one-chunk update is a single flush.
template <typename Request>
grpc::Status SendAll(grpc::ClientWriter<Request>* writer, const std::vector<Request>& chunks) {
  for (size_t i = 0; i + 1 < chunks.size(); ++i) {
    if (!writer->Write(chunks[i], grpc::WriteOptions().set_buffer_hint())) return writer->Finish();
  }
  // A last-message write half-closes even when it fails: no WritesDone after it.
  if (chunks.empty()) {
    writer->WritesDone();
  } else {
    writer->Write(chunks.back(), grpc::WriteOptions().set_last_message());
  }
  return writer->Finish();
}

absl::Status ToAbsl(const grpc::Status& s) {
  if (s.ok()) return absl::OkStatus();
  return absl::Status(static_cast<absl::StatusCode>(s.error_code()), s.error_message());
}

RemoteMesh FromProto(const v1::MeshInfo& p) {
  RemoteMesh m;
  m.mesh_id = p.mesh_id();
  m.revision = p.revision();
  m.num_vertices = p.num_vertices();
  m.num_faces = p.num_faces();
  m.name = p.name();
  m.content_hash = p.content_hash();
  m.labels.insert(p.labels().begin(), p.labels().end());
  if (p.bounding_box().min_size() == 3 && p.bounding_box().max_size() == 3) {
    for (int i = 0; i < 3; ++i) {
      m.bbox_min[i] = p.bounding_box().min(i);
      m.bbox_max[i] = p.bounding_box().max(i);
    }
  }
  m.num_boundary_edges = p.num_boundary_edges();
  m.num_isolated_vertices = p.num_isolated_vertices();
  return m;
}

FitSummary FromProto(const v1::FitSummary& p) {
  FitSummary s;
  s.revision = p.revision();
  s.degree_requested = p.degree_requested();
  s.min_degree_used = p.min_degree_used();
  s.num_downgraded = p.num_downgraded();
  s.num_too_few_points = p.num_too_few_points();
  s.num_boundary = p.num_boundary();
  s.num_isolated = p.num_isolated();
  s.fit_cache_hit = p.fit_cache_hit();
  s.fit_ms = p.fit_ms();
  s.evaluate_ms = p.evaluate_ms();
  s.joined_compute_ms = p.joined_compute_ms();
  return s;
}

}  // namespace

struct Client::Impl {
  /// What was uploaded through this client, for re-upload after NOT_FOUND.
  struct Kept {
    Mesh mesh;
    std::string name;
    std::map<std::string, std::string> labels;
    std::string remote_id;
  };

  ClientOptions options;
  absl::Status init_error;  ///< Connect's failure, returned by every call
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::GeomFit::Stub> stub;
  std::atomic<bool> stream_updates{false};  ///< the server lacks SetPositions
  std::atomic<bool> unary_only{false};      ///< the server lacks the *Stream variants
  mutable std::mutex mu;
  std::map<std::string, Kept> kept;

  void Authorize(grpc::ClientContext& ctx) const {
    if (!options.token.empty()) ctx.AddMetadata("authorization", "Bearer " + options.token);
  }

  /// Runs one call (a fresh context with the deadline per attempt), retrying
  /// UNAVAILABLE with exponential backoff. A mesh-scoped call names its mesh in
  /// `x-mesh-id` metadata, the key of cache-affine routers (deploy/router).
  absl::Status Call(const std::function<grpc::Status(grpc::ClientContext&)>& fn,
                    const std::string& mesh_id = "") const {
    GF_RETURN_IF_ERROR(init_error);
    auto backoff = options.initial_backoff;
    grpc::Status s;
    for (int attempt = 1; attempt <= std::max(1, options.max_attempts); ++attempt) {
      grpc::ClientContext ctx;
      ctx.set_deadline(std::chrono::system_clock::now() + options.deadline);
      if (!mesh_id.empty()) ctx.AddMetadata(wire::kMeshIdMetadata, mesh_id);
      Authorize(ctx);
      s = fn(ctx);
      if (s.error_code() != grpc::StatusCode::UNAVAILABLE || attempt == options.max_attempts) break;
      std::this_thread::sleep_for(backoff);
      backoff = std::min(options.max_backoff, backoff * 2);
    }
    return ToAbsl(s);
  }

  void Report(const v1::Progress& p) const {
    if (options.progress) options.progress(Progress{p.phase(), p.done(), p.total()});
  }

  /// A long unary call (`unary` fills the response), or with options.progress its
  /// streaming variant `streamed`: progress messages reported, then the response (the
  /// last message). A server without the variant gets the unary call from then on.
  template <typename Request, typename Response>
  absl::StatusOr<Response> Long(std::unique_ptr<grpc::ClientReader<Response>> (v1::GeomFit::Stub::*streamed)(
                                    grpc::ClientContext*, const Request&),
                                const Request& request, const std::string& id,
                                const std::function<grpc::Status(grpc::ClientContext&, Response*)>& unary) {
    Response response;
    if (options.progress && !unary_only.load()) {
      const absl::Status s = Call([&](grpc::ClientContext& ctx) {
        auto reader = (stub.get()->*streamed)(&ctx, request);
        Response message;
        while (reader->Read(&message)) {
          if (message.has_progress()) {
            Report(message.progress());
          } else {
            response = std::move(message);
          }
        }
        return reader->Finish();
      }, id);
      if (!absl::IsUnimplemented(s)) {
        GF_RETURN_IF_ERROR(s);
        return response;
      }
      unary_only = true;
    }
    GF_RETURN_IF_ERROR(Call([&](grpc::ClientContext& ctx) { return unary(ctx, &response); }, id));
    return response;
  }

  absl::StatusOr<v1::MeshInfo> SendUpload(const Mesh& mesh, const std::string& name,
                                          const std::map<std::string, std::string>& labels) const {
    v1::MeshHeader header;
    header.set_name(name);
    header.mutable_labels()->insert(labels.begin(), labels.end());
    const std::vector<v1::UploadMeshRequest> chunks = wire::UploadChunks(mesh, header, options.chunk_rows);
    // The id the server will give this content: the upload reaches the replica that
    // every later call on the mesh is routed to.
    const std::string id = MeshIdOf(MeshContentHash(mesh, name, labels));
    v1::MeshInfo info;
    GF_RETURN_IF_ERROR(Call([&](grpc::ClientContext& ctx) {
      auto writer = stub->UploadMesh(&ctx, &info);
      return SendAll(writer.get(), chunks);
    }, id));
    return info;
  }
};

Client::Client(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Client::~Client() = default;

absl::StatusOr<std::unique_ptr<Client>> Client::Create(const ClientOptions& options) {
  GF_ASSIGN_OR_RETURN(const std::shared_ptr<grpc::ChannelCredentials> credentials, ChannelCredentialsFor(options));
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(static_cast<int>(options.max_message_bytes));
  args.SetMaxSendMessageSize(static_cast<int>(options.max_message_bytes));
  impl->channel = grpc::CreateCustomChannel(options.target, credentials, args);
  impl->stub = v1::GeomFit::NewStub(impl->channel);
  return std::unique_ptr<Client>(new Client(std::move(impl)));
}

std::unique_ptr<Client> Client::Connect(const ClientOptions& options) {
  absl::StatusOr<std::unique_ptr<Client>> client = Create(options);
  if (client.ok()) return *std::move(client);
  ClientOptions plain = options;  // a channel that is never used: every call fails first
  plain.tls = false;
  plain.tls_ca = plain.tls_cert = plain.tls_key = "";
  std::unique_ptr<Client> failed = *Create(plain);
  failed->impl_->init_error = client.status();
  return failed;
}

std::string Client::ResolveId(const std::string& mesh_id) const {
  std::lock_guard<std::mutex> lock(impl_->mu);
  auto it = impl_->kept.find(mesh_id);
  return it == impl_->kept.end() ? mesh_id : it->second.remote_id;
}

template <typename T, typename Fn>
absl::StatusOr<T> Client::WithMesh(const std::string& mesh_id, Fn fn) {
  absl::StatusOr<T> r = fn(ResolveId(mesh_id));
  if (!absl::IsNotFound(r.status()) || !impl_->options.reupload_on_not_found) return r;
  Impl::Kept kept;
  {
    std::lock_guard<std::mutex> lock(impl_->mu);
    auto it = impl_->kept.find(mesh_id);
    if (it == impl_->kept.end()) return r;
    kept = it->second;
  }
  GF_ASSIGN_OR_RETURN(v1::MeshInfo info, impl_->SendUpload(kept.mesh, kept.name, kept.labels));
  {
    std::lock_guard<std::mutex> lock(impl_->mu);
    impl_->kept[mesh_id].remote_id = info.mesh_id();
  }
  return fn(info.mesh_id());
}

absl::StatusOr<RemoteMesh> Client::Upload(const Mesh& mesh, const std::string& name,
                                          const std::map<std::string, std::string>& labels) {
  GF_ASSIGN_OR_RETURN(v1::MeshInfo info, impl_->SendUpload(mesh, name, labels));
  if (impl_->options.reupload_on_not_found) {
    std::lock_guard<std::mutex> lock(impl_->mu);
    impl_->kept[info.mesh_id()] = Impl::Kept{mesh, name, labels, info.mesh_id()};
  }
  return FromProto(info);
}

absl::StatusOr<RemoteMesh> Client::UpdatePositions(const std::string& mesh_id, const Positions& positions,
                                                   std::optional<int64_t> expected_revision) {
  GF_ASSIGN_OR_RETURN(v1::MeshInfo info, UpdatePositionsWire(mesh_id, positions, expected_revision));
  return FromProto(info);
}

absl::StatusOr<v1::MeshInfo> Client::UpdatePositionsWire(const std::string& mesh_id, PositionsRef positions,
                                                         std::optional<int64_t> expected_revision) {
  GF_ASSIGN_OR_RETURN(v1::MeshInfo out, (WithMesh<v1::MeshInfo>(mesh_id, [&](const std::string& id) -> absl::StatusOr<v1::MeshInfo> {
    v1::UpdateHeader header;
    header.set_mesh_id(id);
    if (expected_revision) header.set_expected_revision(*expected_revision);
    v1::MeshInfo info;
    if (positions.rows() <= impl_->options.chunk_rows && !impl_->stream_updates.load()) {
      v1::SetPositionsRequest request;  // one message: no stream to set up
      *request.mutable_header() = header;
      wire::EncodeDoubles(positions.data(), positions.rows(), 3, request.mutable_positions()->mutable_positions());
      const absl::Status s =
          impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->SetPositions(&ctx, request, &info); }, id);
      if (!absl::IsUnimplemented(s)) {
        GF_RETURN_IF_ERROR(s);
        return info;
      }
      impl_->stream_updates = true;  // a server without SetPositions
    }
    const auto chunks = wire::UpdateChunks(positions, header, impl_->options.chunk_rows);
    GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) {
      auto writer = impl_->stub->UpdatePositions(&ctx, &info);
      return SendAll(writer.get(), chunks);
    }, id));
    return info;
  })));
  std::lock_guard<std::mutex> lock(impl_->mu);
  if (auto it = impl_->kept.find(mesh_id); it != impl_->kept.end()) it->second.mesh.positions = positions;
  return out;
}

absl::StatusOr<RemoteMesh> Client::GetMesh(const std::string& mesh_id) {
  v1::GetMeshRequest request;
  request.set_mesh_id(ResolveId(mesh_id));
  v1::MeshInfo info;
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->GetMesh(&ctx, request, &info); },
                                  request.mesh_id()));
  return FromProto(info);
}

absl::StatusOr<Mesh> Client::Download(const std::string& mesh_id, RemoteMesh* info_out) {
  v1::DownloadMeshRequest request;
  request.set_mesh_id(ResolveId(mesh_id));
  Mesh mesh;
  v1::MeshInfo info;
  absl::Status decode = absl::OkStatus();
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) {
    auto reader = impl_->stub->DownloadMesh(&ctx, request);
    v1::DownloadMeshResponse r;
    decode = absl::OkStatus();
    while (reader->Read(&r)) {
      if (r.has_info()) {
        info = r.info();
        mesh.positions.resize(info.num_vertices(), 3);
        mesh.faces.Mutable().resize(info.num_faces(), 4);
      } else if (r.has_positions() && decode.ok()) {
        auto m = wire::DecodeDoubles(r.positions().positions(), "positions", {3});
        const int64_t off = r.positions().vertex_offset();
        if (!m.ok()) decode = m.status();
        else if (off < 0 || off + m->rows() > mesh.positions.rows()) decode = absl::DataLossError("positions chunk out of range");
        else mesh.positions.middleRows(off, m->rows()) = *m;
      } else if (r.has_faces() && decode.ok()) {
        auto m = wire::DecodeInts(r.faces().faces(), "faces", {4});
        const int64_t off = r.faces().face_offset();
        if (!m.ok()) decode = m.status();
        else if (off < 0 || off + m->rows() > mesh.faces.rows()) decode = absl::DataLossError("faces chunk out of range");
        else mesh.faces.Mutable().middleRows(off, m->rows()) = *m;
      }
    }
    return reader->Finish();
  }, request.mesh_id()));
  GF_RETURN_IF_ERROR(decode);
  if (info_out) *info_out = FromProto(info);
  return mesh;
}

absl::StatusOr<std::vector<RemoteMesh>> Client::ListMeshes() {
  std::vector<RemoteMesh> out;
  v1::ListMeshesRequest request;
  request.set_page_size(1000);
  for (int page = 0; page < 1'000'000; ++page) {
    v1::ListMeshesResponse response;
    GF_RETURN_IF_ERROR(
        impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->ListMeshes(&ctx, request, &response); }));
    for (const auto& m : response.meshes()) out.push_back(FromProto(m));
    if (response.next_page_token().empty()) break;
    request.set_page_token(response.next_page_token());
  }
  return out;
}

absl::Status Client::DeleteMesh(const std::string& mesh_id) {
  v1::DeleteMeshRequest request;
  request.set_mesh_id(ResolveId(mesh_id));
  v1::DeleteMeshResponse response;
  GF_RETURN_IF_ERROR(
      impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->DeleteMesh(&ctx, request, &response); },
                  request.mesh_id()));
  std::lock_guard<std::mutex> lock(impl_->mu);
  impl_->kept.erase(mesh_id);
  return absl::OkStatus();
}

absl::StatusOr<RemoteDifferentials> Client::ComputeDifferentials(const std::string& mesh_id,
                                                                 const FitOptions& options, uint32_t quantities,
                                                                 int64_t revision, bool diagnostics) {
  v1::ComputeDifferentialsRequest request;
  request.set_mesh_id(mesh_id);
  request.set_revision(revision);
  *request.mutable_options() = wire::ToProto(options);
  wire::AddQuantities(quantities, &request);
  request.set_diagnostics(diagnostics);
  return ComputeDifferentials(std::move(request));
}

absl::StatusOr<RemoteDifferentials> Client::ComputeDifferentials(v1::ComputeDifferentialsRequest request) {
  const std::string mesh_id = request.mesh_id();
  return WithMesh<RemoteDifferentials>(mesh_id, [&](const std::string& id) -> absl::StatusOr<RemoteDifferentials> {
    request.set_mesh_id(id);
    request.set_progress(impl_->options.progress != nullptr);
    std::optional<wire::DifferentialsReader> reader;
    absl::Status decode;
    GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) {
      reader.emplace();
      decode = absl::OkStatus();
      auto stream = impl_->stub->ComputeDifferentials(&ctx, request);
      v1::ComputeDifferentialsResponse chunk;
      int64_t total = 0;
      bool fitting = false;  // a server phase is under way (its last message has done < total)
      while (stream->Read(&chunk)) {
        if (chunk.has_progress()) {  // the fit's passes (the last one's among the rows)
          fitting = chunk.progress().done() < chunk.progress().total();
          impl_->Report(chunk.progress());
          continue;
        }
        if (decode.ok()) decode = reader->Add(chunk);
        if (chunk.has_summary() && total == 0) total = chunk.summary().num_vertices();
        if (impl_->options.progress && !fitting)  // the rows received, when the server reports no pass
          impl_->options.progress(Progress{"compute", chunk.vertex_offset() + chunk.num_vertices(), total});
      }
      return stream->Finish();
    }, id));
    GF_RETURN_IF_ERROR(decode);
    RemoteDifferentials out;
    GF_ASSIGN_OR_RETURN(out.values, reader->Finish());
    out.summary = FromProto(reader->summary());
    out.wire_summary = reader->summary();
    return out;
  });
}

absl::StatusOr<v1::ServerInfo> Client::GetServerInfo() {
  v1::ServerInfo info;
  GF_RETURN_IF_ERROR(impl_->Call(
      [&](grpc::ClientContext& ctx) { return impl_->stub->GetServerInfo(&ctx, v1::GetServerInfoRequest(), &info); }));
  return info;
}

absl::StatusOr<v1::Statistics> Client::GetStatistics() {
  v1::Statistics stats;
  GF_RETURN_IF_ERROR(impl_->Call(
      [&](grpc::ClientContext& ctx) { return impl_->stub->GetStatistics(&ctx, v1::GetStatisticsRequest(), &stats); }));
  return stats;
}

}  // namespace geomfit

// ---- Chapter 4 ------------------------------------------------------------------------

namespace geomfit {

absl::StatusOr<std::vector<ProjectedPoint>> Client::ProjectPoints(const std::string& mesh_id, const Positions& points,
                                                                  const v1::ReconstructionOptions& options) {
  v1::ProjectPointsRequest request;
  *request.mutable_options() = options;
  wire::EncodeDoubles(points.data(), points.rows(), 3, request.mutable_points());
  return SendProject(mesh_id, std::move(request));
}

absl::StatusOr<std::vector<ProjectedPoint>> Client::EvaluateFacePoints(const std::string& mesh_id,
                                                                       const std::vector<FacePoint>& points,
                                                                       const v1::ReconstructionOptions& options) {
  v1::ProjectPointsRequest request;
  *request.mutable_options() = options;
  std::vector<int32_t> faces(points.size());
  wire::RowsXd natural(points.size(), 2);
  for (size_t i = 0; i < points.size(); ++i) faces[i] = points[i].face, natural.row(i) << points[i].xi, points[i].eta;
  wire::EncodeInts(faces.data(), static_cast<int64_t>(faces.size()), 0, request.mutable_faces());
  wire::EncodeDoubles(natural.data(), natural.rows(), 2, request.mutable_natural());
  return SendProject(mesh_id, std::move(request));
}

absl::StatusOr<std::vector<ProjectedPoint>> Client::SendProject(const std::string& mesh_id,
                                                                v1::ProjectPointsRequest request) {
  return WithMesh<std::vector<ProjectedPoint>>(
      mesh_id, [&](const std::string& id) -> absl::StatusOr<std::vector<ProjectedPoint>> {
        request.set_mesh_id(id);
        request.set_progress(impl_->options.progress != nullptr);
        std::vector<ProjectedPoint> out;
        absl::Status decode;
        GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) {
          out.clear();
          decode = absl::OkStatus();
          auto stream = impl_->stub->ProjectPoints(&ctx, request);
          v1::ProjectPointsResponse c;
          while (stream->Read(&c)) {
            if (c.has_progress()) {
              impl_->Report(c.progress());
              continue;
            }
            if (!decode.ok()) continue;
            auto pos = wire::DecodeDoubles(c.positions(), "positions", {3});
            auto nrm = wire::DecodeDoubles(c.normals(), "normals", {3});
            auto nat = wire::DecodeDoubles(c.natural(), "natural", {2});
            auto dist = wire::DecodeDoubles(c.distances(), "distances", {0});
            auto faces = wire::DecodeInts(c.faces(), "faces", {0});
            for (const absl::Status& s : {pos.status(), nrm.status(), nat.status(), dist.status(), faces.status()})
              if (decode.ok() && !s.ok()) decode = s;
            if (!decode.ok()) continue;
            if (c.offset() != static_cast<int64_t>(out.size()) || nrm->rows() != pos->rows() ||
                nat->rows() != pos->rows() || dist->rows() != pos->rows() || faces->rows() != pos->rows()) {
              decode = absl::DataLossError("ProjectPoints: chunks out of order or of unequal lengths");
              continue;
            }
            for (Eigen::Index i = 0; i < pos->rows(); ++i) {
              ProjectedPoint p;
              p.where = {(*faces)(i, 0), (*nat)(i, 0), (*nat)(i, 1)};
              p.point.position = pos->row(i).transpose();
              p.point.normal = nrm->row(i).transpose();
              p.point.jacobian.setZero();
              p.distance = (*dist)(i, 0);
              out.push_back(p);
            }
          }
          return stream->Finish();
        }, id));
        GF_RETURN_IF_ERROR(decode);
        return out;
      });
}

absl::StatusOr<HighOrderMesh> Client::HighOrderNodes(const std::string& mesh_id, int order,
                                                     const v1::ReconstructionOptions& options) {
  return WithMesh<HighOrderMesh>(mesh_id, [&](const std::string& id) -> absl::StatusOr<HighOrderMesh> {
    v1::HighOrderNodesRequest request;
    request.set_mesh_id(id);
    request.set_order(order);
    *request.mutable_options() = options;
    GF_ASSIGN_OR_RETURN(const v1::HighOrderNodesResponse response,
                        (impl_->Long<v1::HighOrderNodesRequest, v1::HighOrderNodesResponse>(
                            &v1::GeomFit::Stub::HighOrderNodesStream, request, id,
                            [&](grpc::ClientContext& ctx, v1::HighOrderNodesResponse* r) {
                              return impl_->stub->HighOrderNodes(&ctx, request, r);
                            })));
    HighOrderMesh out;
    out.order = response.order();
    GF_ASSIGN_OR_RETURN(out.nodes, wire::DecodeDoubles(response.nodes(), "nodes", {3}));
    GF_ASSIGN_OR_RETURN(const wire::RowsXi offsets, wire::DecodeInts(response.offsets(), "offsets", {0}));
    GF_ASSIGN_OR_RETURN(const wire::RowsXi elements, wire::DecodeInts(response.elements(), "elements", {0}));
    out.offsets.assign(offsets.data(), offsets.data() + offsets.size());
    out.elements.assign(elements.data(), elements.data() + elements.size());
    return out;
  });
}

absl::StatusOr<RemoteMesh> Client::RefineMesh(const std::string& mesh_id, int factor,
                                              const v1::ReconstructionOptions& options, const std::string& name) {
  return WithMesh<RemoteMesh>(mesh_id, [&](const std::string& id) -> absl::StatusOr<RemoteMesh> {
    v1::RefineMeshRequest request;
    request.set_mesh_id(id);
    request.set_factor(factor);
    request.set_name(name);
    *request.mutable_options() = options;
    GF_ASSIGN_OR_RETURN(const v1::RefineMeshResponse response,
                        (impl_->Long<v1::RefineMeshRequest, v1::RefineMeshResponse>(
                            &v1::GeomFit::Stub::RefineMeshStream, request, id,
                            [&](grpc::ClientContext& ctx, v1::RefineMeshResponse* r) {
                              return impl_->stub->RefineMesh(&ctx, request, r->mutable_mesh());
                            })));
    return FromProto(response.mesh());
  });
}

absl::StatusOr<Integrals> Client::Integrate(const std::string& mesh_id, const IntegrationInput& input,
                                            const v1::ReconstructionOptions& options) {
  return WithMesh<Integrals>(mesh_id, [&](const std::string& id) -> absl::StatusOr<Integrals> {
    v1::IntegrateRequest request;
    request.set_mesh_id(id);
    request.set_quadrature_degree(input.quadrature_degree);
    *request.mutable_options() = options;
    if (input.scalars.size()) {
      const wire::RowsXd s = input.scalars;
      wire::EncodeDoubles(s.data(), s.rows(), s.cols(), request.mutable_scalars());
    }
    if (input.vectors.size()) {
      const wire::RowsXd v = input.vectors;
      wire::EncodeDoubles(v.data(), v.rows(), v.cols(), request.mutable_vectors());
    }
    GF_ASSIGN_OR_RETURN(const v1::IntegrateResponse response,
                        (impl_->Long<v1::IntegrateRequest, v1::IntegrateResponse>(
                            &v1::GeomFit::Stub::IntegrateStream, request, id,
                            [&](grpc::ClientContext& ctx, v1::IntegrateResponse* r) {
                              return impl_->stub->Integrate(&ctx, request, r);
                            })));
    Integrals out;
    out.area = response.area();
    out.volume = response.volume();
    out.scalars.assign(response.scalars().begin(), response.scalars().end());
    out.flux = response.flux();
    out.quadrature_points = response.quadrature_points();
    return out;
  });
}

}  // namespace geomfit

// ---- Jobs ------------------------------------------------------------------------------

namespace geomfit {

absl::StatusOr<v1::Job> Client::StartJob(v1::StartJobRequest request) {
  if (request.has_refine()) request.mutable_refine()->set_mesh_id(ResolveId(request.refine().mesh_id()));
  if (request.has_flow()) request.mutable_flow()->set_mesh_id(ResolveId(request.flow().mesh_id()));
  v1::Job job;
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->StartJob(&ctx, request, &job); }));
  return job;
}

absl::Status Client::WatchJob(const std::string& job_id, int64_t from_event,
                              const std::function<bool(const v1::JobEvent&)>& on_event) {
  GF_RETURN_IF_ERROR(impl_->init_error);
  int64_t next = from_event;
  int failures = 0;
  auto backoff = impl_->options.initial_backoff;
  while (true) {
    grpc::ClientContext ctx;
    impl_->Authorize(ctx);
    v1::WatchJobRequest request;
    request.set_job_id(job_id);
    request.set_from_event(next);
    auto reader = impl_->stub->WatchJob(&ctx, request);
    v1::JobEvent event;
    bool progressed = false;
    while (reader->Read(&event)) {
      progressed = true;
      next = event.seq() + 1;
      if (!on_event(event)) {
        ctx.TryCancel();
        reader->Finish();
        return absl::OkStatus();
      }
    }
    const grpc::Status s = reader->Finish();
    if (s.error_code() != grpc::StatusCode::UNAVAILABLE) return ToAbsl(s);
    failures = progressed ? 1 : failures + 1;
    if (failures >= std::max(1, impl_->options.max_attempts)) return ToAbsl(s);
    std::this_thread::sleep_for(backoff);
    backoff = std::min(impl_->options.max_backoff, backoff * 2);
  }
}

absl::StatusOr<v1::Job> Client::CancelJob(const std::string& job_id) {
  v1::CancelJobRequest request;
  request.set_job_id(job_id);
  v1::Job job;
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->CancelJob(&ctx, request, &job); }));
  return job;
}

absl::StatusOr<v1::Job> Client::GetJob(const std::string& job_id) {
  v1::GetJobRequest request;
  request.set_job_id(job_id);
  v1::Job job;
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->GetJob(&ctx, request, &job); }));
  return job;
}

absl::StatusOr<std::vector<v1::Job>> Client::ListJobs() {
  std::vector<v1::Job> out;
  v1::ListJobsRequest request;
  request.set_page_size(1000);
  while (true) {
    v1::ListJobsResponse response;
    GF_RETURN_IF_ERROR(
        impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->ListJobs(&ctx, request, &response); }));
    for (const v1::Job& j : response.jobs()) out.push_back(j);
    if (response.next_page_token().empty()) return out;
    request.set_page_token(response.next_page_token());
  }
}

}  // namespace geomfit

// ---- grpc.health.v1 -------------------------------------------------------------------

namespace geomfit {

absl::StatusOr<std::string> Client::CheckHealth(const std::string& service) {
  // HealthCheckRequest {string service = 1} and HealthCheckResponse {enum status = 1}
  // are encoded by hand: Debian ships no health.proto to generate them from.
  if (service.size() > 127) return absl::InvalidArgumentError("health: service name too long");
  std::string request_bytes;
  if (!service.empty()) request_bytes = std::string("\x0a", 1) + static_cast<char>(service.size()) + service;
  const grpc::internal::RpcMethod method("/grpc.health.v1.Health/Check", grpc::internal::RpcMethod::NORMAL_RPC);
  std::string response_bytes;
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) {
    grpc::Slice slice(request_bytes);
    grpc::ByteBuffer request(&slice, 1), response;
    grpc::Status s = grpc::internal::BlockingUnaryCall<grpc::ByteBuffer, grpc::ByteBuffer>(
        impl_->channel.get(), method, &ctx, request, &response);
    std::vector<grpc::Slice> slices;
    response_bytes.clear();
    if (s.ok() && response.Dump(&slices).ok()) {
      for (const grpc::Slice& piece : slices) response_bytes.append(reinterpret_cast<const char*>(piece.begin()), piece.size());
    }
    return s;
  }));
  int status = 0;  // an empty message is status 0 (UNKNOWN)
  if (response_bytes.size() >= 2 && response_bytes[0] == '\x08') status = static_cast<unsigned char>(response_bytes[1]);
  static const char* const kNames[] = {"UNKNOWN", "SERVING", "NOT_SERVING", "SERVICE_UNKNOWN"};
  return status >= 0 && status < 4 ? std::string(kNames[status]) : absl::StrCat("STATUS_", status);
}

absl::StatusOr<v1::Job> Client::StartFlow(v1::FlowJob spec) {
  spec.set_mesh_id(ResolveId(spec.mesh_id()));
  v1::Job job;
  GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->StartFlow(&ctx, spec, &job); }));
  return job;
}

absl::StatusOr<SparseMatrix> Client::GetOperator(const std::string& mesh_id, v1::OperatorKind kind,
                                                 const v1::FitOptions& options) {
  return WithMesh<SparseMatrix>(mesh_id, [&](const std::string& id) -> absl::StatusOr<SparseMatrix> {
    v1::GetOperatorRequest request;
    request.set_mesh_id(id);
    request.set_operator_(kind);
    *request.mutable_options() = options;
    v1::GetOperatorResponse r;
    GF_RETURN_IF_ERROR(
        impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->GetOperator(&ctx, request, &r); }, id));
    if (r.shape_size() != 2) return absl::DataLossError("GetOperator: the response has no 2-D shape");
    GF_ASSIGN_OR_RETURN(const wire::RowsXi offsets, wire::DecodeInts(r.row_offsets(), "row_offsets", {0}));
    GF_ASSIGN_OR_RETURN(const wire::RowsXi columns, wire::DecodeInts(r.columns(), "columns", {0}));
    GF_ASSIGN_OR_RETURN(const wire::RowsXd values, wire::DecodeDoubles(r.values(), "values", {0}));
    const int64_t rows = r.shape(0), cols = r.shape(1), nnz = values.size();
    if (offsets.size() != rows + 1 || columns.size() != nnz || offsets(offsets.size() - 1) != nnz)
      return absl::DataLossError("GetOperator: inconsistent CSR arrays");
    SparseMatrix m(rows, cols);
    m.resizeNonZeros(nnz);
    std::copy(offsets.data(), offsets.data() + rows + 1, m.outerIndexPtr());
    std::copy(columns.data(), columns.data() + nnz, m.innerIndexPtr());
    std::copy(values.data(), values.data() + nnz, m.valuePtr());
    return m;
  });
}

absl::StatusOr<Eigen::MatrixXd> Client::ApplyOperator(const std::string& mesh_id, v1::OperatorKind kind,
                                                      const Eigen::MatrixXd& field, const v1::FitOptions& options) {
  return WithMesh<Eigen::MatrixXd>(mesh_id, [&](const std::string& id) -> absl::StatusOr<Eigen::MatrixXd> {
    v1::ApplyOperatorRequest request;
    request.set_mesh_id(id);
    request.set_operator_(kind);
    *request.mutable_options() = options;
    const wire::RowsXd f = field;
    wire::EncodeDoubles(f.data(), f.rows(), f.cols(), request.mutable_field());
    v1::ApplyOperatorResponse r;
    GF_RETURN_IF_ERROR(
        impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->ApplyOperator(&ctx, request, &r); }, id));
    GF_ASSIGN_OR_RETURN(const wire::RowsXd out, wire::DecodeDoubles(r.result(), "result", {1, 3, 9}));
    return Eigen::MatrixXd(out);
  });
}

absl::StatusOr<RemoteMembrane> Client::ComputeMembrane(v1::ComputeMembraneRequest request) {
  return WithMesh<RemoteMembrane>(request.mesh_id(), [&](const std::string& id) -> absl::StatusOr<RemoteMembrane> {
    request.set_mesh_id(id);
    request.set_progress(impl_->options.progress != nullptr);
    RemoteMembrane out;
    absl::Status decode;
    GF_RETURN_IF_ERROR(impl_->Call([&](grpc::ClientContext& ctx) {
      out = RemoteMembrane();
      decode = absl::OkStatus();
      auto stream = impl_->stub->ComputeMembrane(&ctx, request);
      v1::ComputeMembraneResponse c;
      int64_t n = 0;
      MembraneFields& f = out.values;
      // Rows of chunk c's `a` (cols 0: 1-D) into rows [offset, offset + rows) of `dst`.
      auto take = [&](const v1::DoubleArray& a, const char* name, int64_t cols, auto* dst) {
        if (!decode.ok() || a.data().empty()) return;
        absl::StatusOr<wire::RowsXd> m = wire::DecodeDoubles(a, name, {cols});
        if (!m.ok()) {
          decode = m.status();
          return;
        }
        if (m->rows() != c.num_vertices() || c.vertex_offset() + m->rows() > n) {
          decode = absl::DataLossError(absl::StrCat("ComputeMembrane: chunk ", name, " of the wrong length"));
          return;
        }
        if (dst->rows() != n) dst->resize(n, dst->cols());
        for (int64_t r = 0; r < m->rows(); ++r)
          for (int64_t k = 0; k < m->cols(); ++k) (*dst)(c.vertex_offset() + r, k) = (*m)(r, k);
      };
      while (stream->Read(&c)) {
        if (c.has_progress()) {  // the reference fit's phases, "membrane"
          impl_->Report(c.progress());
          continue;
        }
        if (n == 0) {  // the first chunk
          n = c.total_vertices();
          out.revision = c.revision();
          out.deformed_revision = c.deformed_revision();
          out.fit_ms = c.fit_ms();
          out.evaluate_ms = c.evaluate_ms();
        }
        take(c.pressure(), "pressure", 0, &f.pressure);
        take(c.stretches(), "stretches", 2, &f.stretches);
        take(c.strain(), "strain", 9, &f.strain);
        take(c.stress(), "stress", 9, &f.stress);
        take(c.von_mises(), "von_mises", 0, &f.von_mises);
        take(c.traction(), "traction", 0, &f.traction);
      }
      return stream->Finish();
    }, id));
    GF_RETURN_IF_ERROR(decode);
    return out;
  });
}

absl::StatusOr<v1::Job> Client::StartMembraneSolve(v1::MembraneSolveJob spec) {
  spec.set_mesh_id(ResolveId(spec.mesh_id()));
  v1::Job job;
  GF_RETURN_IF_ERROR(
      impl_->Call([&](grpc::ClientContext& ctx) { return impl_->stub->StartMembraneSolve(&ctx, spec, &job); }));
  return job;
}

}  // namespace geomfit
