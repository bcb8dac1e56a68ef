// Uses the installed geomfit: curvature of a generated torus in-process (geomfit::core),
// and a client object (geomfit::client). Prints the max error of H at degree 4.
#include <cmath>
#include <cstdio>

#include "clients/cpp/client/client.h"
#include "core/quantities/differentials.h"
#include "core/surfaces/analytic.h"

int main() {
  geomfit::GeneratorOptions g;
  g.n = 24;
  const geomfit::Mesh mesh = geomfit::GenerateTorusMesh(g);
  geomfit::FitOptions fit;
  fit.degree = 4;
  const auto d = geomfit::ComputeDifferentials(mesh, fit, geomfit::kMeanCurvature);
  if (!d.ok()) return 1;
  const auto torus = geomfit::MakeTorus();
  double err = 0;
  for (int v = 0; v < mesh.NumVertices(); ++v) {
    err = std::max(err, std::abs(d->mean(v) - torus->At(mesh.positions.row(v).transpose()).mean));
  }
  geomfit::ClientOptions o;
  o.target = "127.0.0.1:1";
  const auto client = geomfit::Client::Connect(o);  // a channel; nothing is sent
  std::printf("consumer: %d vertices, max |H - H_exact| = %.3g, server %s, client %s\n", mesh.NumVertices(), err,
              GEOMFIT_SERVER_PATH, client ? "ok" : "missing");
  return err < 0.05 && client ? 0 : 1;
}
