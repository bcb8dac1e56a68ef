// ComputeMembrane (§6.1-6.2): stress and interface pressure of a deformed membrane
// against the cached reference fits.
#include <algorithm>
#include <cmath>
#include <memory>
#include <optional>

#include "absl/strings/str_cat.h"
#include "core/mechanics/membrane.h"
#include "core/util/status_macros.h"
#include "core/util/timer.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"
#include "server/handlers/membrane_job.h"
#include "server/handlers/progress.h"

namespace geomfit::server {
namespace {

enum : uint32_t {
  kPressure = 1,
  kStretches = 2,
  kStrain = 4,
  kStress = 8,
  kVonMises = 16,
  kTraction = 32,
};

absl::StatusOr<uint32_t> MembraneMask(const google::protobuf::RepeatedField<int>& quantities) {
  if (quantities.empty()) return kPressure | kStretches | kVonMises;
  uint32_t mask = 0;
  for (int q : quantities) {
    if (q < v1::MEMBRANE_QUANTITY_PRESSURE || q > v1::MEMBRANE_QUANTITY_TRACTION)
      return absl::InvalidArgumentError(absl::StrCat("quantities: unknown value ", q));
    mask |= 1u << (q - 1);
  }
  return mask;
}

using wire::EncodeRows;

}  // namespace

absl::Status Handlers::ComputeMembrane(const v1::ComputeMembraneRequest& request, const CancellationToken& cancel,
                                       ChunkSink<v1::ComputeMembraneResponse>* sink) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.revision() < 0 || request.chunk_rows() < 0 || request.deformed().revision() < 0)
    return absl::InvalidArgumentError("revision, deformed.revision and chunk_rows must not be negative");
  GF_ASSIGN_OR_RETURN(const MembraneOptions material,
                      MembraneMaterialFromProto(request.young_modulus(), request.poisson_ratio(), ""));
  GF_ASSIGN_OR_RETURN(const FitOptions fit, MembraneFitFromProto(request.has_options(), request.options(), 1, "options"));
  GF_ASSIGN_OR_RETURN(const uint32_t mask, MembraneMask(request.quantities()));
  const bool sent = request.deformed_positions().shape_size() > 0 || !request.deformed_positions().data().empty();
  if (sent == request.has_deformed())
    return absl::InvalidArgumentError(
        "deformed: give exactly one of deformed (a stored mesh) and deformed_positions");
  // Sent arrays are checked before anything is fitted (their lengths once the mesh is known).
  auto decode = [](const v1::DoubleArray& a, const char* field) -> absl::StatusOr<std::optional<wire::RowsXd>> {
    if (a.shape_size() == 0 && a.data().empty()) return std::nullopt;
    GF_ASSIGN_OR_RETURN(wire::RowsXd p, wire::DecodeDoubles(a, field, {3}));
    for (Eigen::Index i = 0; i < p.rows(); ++i)
      if (!p.row(i).allFinite()) return absl::InvalidArgumentError(absl::StrCat(field, ": vertex ", i, " is not finite"));
    return p;
  };
  GF_ASSIGN_OR_RETURN(const std::optional<wire::RowsXd> positions,
                      decode(request.deformed_positions(), "deformed_positions"));
  GF_ASSIGN_OR_RETURN(const std::optional<wire::RowsXd> reference_positions,
                      decode(request.reference_positions(), "reference_positions"));
  // Both held to the end: an update may replace the revisions in the cache meanwhile.
  GF_ASSIGN_OR_RETURN(const Snapshot ref, Acquire(request.mesh_id(), request.revision()));
  const int64_t n = ref.mesh->NumVertices();
  if (reference_positions && reference_positions->rows() != n)
    return absl::InvalidArgumentError(absl::StrCat("reference_positions: ", reference_positions->rows(),
                                                   " rows for a mesh of ", n, " vertices"));
  Positions y;
  int64_t deformed_revision = 0;
  if (positions) {
    if (positions->rows() != n)
      return absl::InvalidArgumentError(absl::StrCat("deformed_positions: ", positions->rows(),
                                                     " rows for a reference of ", n, " vertices"));
    y = *positions;
  } else {
    const bool same = request.deformed().mesh_id().empty() || request.deformed().mesh_id() == ref.mesh_id;
    const std::string& id = same ? ref.mesh_id : request.deformed().mesh_id();
    GF_ASSIGN_OR_RETURN(const Snapshot def, Acquire(id, request.deformed().revision()));
    if (!same && (def.mesh->faces.rows() != ref.mesh->faces.rows() || def.mesh->NumVertices() != n ||
                  def.mesh->faces != ref.mesh->faces))
      return absl::InvalidArgumentError(absl::StrCat(
          "deformed.mesh_id: ", request.deformed().mesh_id(), " has another topology than the reference (",
          def.mesh->NumVertices(), " vertices, ", def.mesh->NumFaces(), " faces against ", n, " and ",
          ref.mesh->NumFaces(), ", or other faces)"));
    y = def.mesh->positions;
    deformed_revision = def.revision;
  }
  // Progress messages (the reference fit's phases, "membrane") before the result chunks.
  ProgressThrottle throttle(ProgressMessages(sink));
  const RunContext ctx = Context(cancel, request.progress() ? throttle.Callback() : nullptr);
  double fit_ms = 0, evaluate_ms = 0;
  MembraneFields f;
  if (reference_positions) {  // a reference of its own: fitted here, not cached
    Mesh mesh;
    mesh.positions = *reference_positions;
    mesh.faces = ref.mesh->faces;
    GF_RETURN_IF_ERROR(ValidateGeometry(mesh));
    const Stopwatch watch;
    GF_ASSIGN_OR_RETURN(f, geomfit::ComputeMembrane(mesh, *ref.topology, y, material, fit, ctx));
    evaluate_ms = watch.Millis();
  } else {
    GF_ASSIGN_OR_RETURN(const Fitted fitted, ws_->Fit(ref, fit, ctx, /*stencils=*/true));
    fit_ms = fitted.ms;
    const Stopwatch watch;
    GF_ASSIGN_OR_RETURN(f, geomfit::ComputeMembrane(*fitted.fits, ref.mesh->positions, y, material, ctx));
    evaluate_ms = watch.Millis();
  }
  const int64_t bytes_per_row = 8 * (1 + 2 + 9 + 9 + 1 + 1);
  const int64_t rows = ChunkRows(request.chunk_rows(), bytes_per_row);
  v1::ComputeMembraneResponse head;  // what the first chunk says of the whole response
  head.set_mesh_id(ref.mesh_id);
  head.set_revision(ref.revision);
  head.set_deformed_revision(deformed_revision);
  head.set_total_vertices(n);
  head.set_fit_ms(fit_ms);
  head.set_evaluate_ms(evaluate_ms);
  auto fields = std::make_shared<const MembraneFields>(std::move(f));
  PushRows(sink, std::move(fields), n, rows, [head, mask](const MembraneFields& f, int64_t b, int64_t m) {
    v1::ComputeMembraneResponse r;
    if (b == 0) r = head;
    r.set_vertex_offset(b);
    r.set_num_vertices(m);
    if (mask & kPressure) EncodeRows(f.pressure, b, m, r.mutable_pressure());
    if (mask & kStretches) EncodeRows(f.stretches, b, m, r.mutable_stretches());
    if (mask & kStrain) EncodeRows(f.strain, b, m, r.mutable_strain());
    if (mask & kStress) EncodeRows(f.stress, b, m, r.mutable_stress());
    if (mask & kVonMises) EncodeRows(f.von_mises, b, m, r.mutable_von_mises());
    if (mask & kTraction) EncodeRows(f.traction, b, m, r.mutable_traction());
    return r;
  });
  return absl::OkStatus();
}

}  // namespace geomfit::server
