// Integrate: surface integrals over the reconstructed surface (§4.3), sharp features
// (feature_angle_deg / feature_edges) included: Workspace::Reconstruct builds the
// FeatureSurface that core Integrate accepts.
#include "absl/strings/str_cat.h"
#include "core/integration/integrate.h"
#include "core/integration/quadrature.h"
#include "core/util/status_macros.h"
#include "proto/wire.h"
#include "server/handlers/handlers.h"

namespace geomfit::server {

absl::StatusOr<v1::IntegrateResponse> Handlers::Integrate(const v1::IntegrateRequest& request,
                                                          const CancellationToken& cancel,
                                                          const RunContext::ProgressFn& progress) {
  GF_RETURN_IF_ERROR(RequireId(request.mesh_id()));
  if (request.options().method() == v1::RECONSTRUCTION_CMF)
    return absl::InvalidArgumentError("options.method: integration supports WALF and LINEAR, not CMF");
  GF_RETURN_IF_ERROR(CheckRange("quadrature_degree", request.quadrature_degree(), 0, kMaxQuadratureDegree));
  IntegrationInput in;
  in.quadrature_degree = request.quadrature_degree();
  const bool fields = request.scalars().shape_size() > 0 || request.vectors().shape_size() > 0;
  if (request.scalars().shape_size() > 0) {
    // One field as a 1-D array, or up to 8 as #V x s.
    const bool one = request.scalars().shape_size() == 1;
    GF_ASSIGN_OR_RETURN(const wire::RowsXd s, one ? wire::DecodeDoubles(request.scalars(), "scalars", {0})
                                                  : wire::DecodeDoubles(request.scalars(), "scalars", {1, 2, 3, 4, 5, 6, 7, 8}));
    in.scalars = s;
  }
  if (request.vectors().shape_size() > 0) {
    GF_ASSIGN_OR_RETURN(const wire::RowsXd v, wire::DecodeDoubles(request.vectors(), "vectors", {3}));
    in.vectors = v;
  }
  const RunContext ctx = Context(cancel, progress);
  GF_ASSIGN_OR_RETURN(auto r, Reconstruct(request.mesh_id(), request.revision(), request.options(), fields, ctx));
  GF_ASSIGN_OR_RETURN(const Integrals result, geomfit::Integrate(*r->surface, in, ctx));
  GF_RETURN_IF_ERROR(cancel.Check());
  v1::IntegrateResponse out;
  out.set_area(result.area);
  out.set_volume(result.volume);
  for (double s : result.scalars) out.add_scalars(s);
  out.set_flux(result.flux);
  out.set_quadrature_points(result.quadrature_points);
  out.set_revision(r->snapshot.revision);
  return out;
}

}  // namespace geomfit::server
