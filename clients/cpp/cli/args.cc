#include <algorithm>
#include <cmath>
#include <cstdio>
#include <utility>

#include "absl/strings/cord.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "clients/cpp/cli/cli.h"

namespace geomfit::cli {
namespace {

constexpr char kUsagePayload[] = "type.geomfit/cli.usage_error";

std::string FormatDefault(double v) { return absl::StrFormat("%g", v); }

}  // namespace

absl::Status UsageError(absl::string_view message) {
  absl::Status s = absl::InvalidArgumentError(message);
  s.SetPayload(kUsagePayload, absl::Cord("1"));
  return s;
}

RemoteTransport& Transport() {
  static RemoteTransport transport;
  return transport;
}

ArgParser& ArgParser::Server(std::string* out, const std::string& help) {
  RemoteTransport& t = Transport();
  return String("server", out, help, "HOST:PORT")
      .String("tls-ca", &t.tls_ca, "connect with TLS, verifying the server against this PEM CA bundle", "FILE")
      .String("tls-cert", &t.tls_cert, "PEM client certificate for mTLS (with --tls-key; implies TLS)", "FILE")
      .String("tls-key", &t.tls_key, "PEM private key of --tls-cert", "FILE")
      .String("token-file", &t.token_file,
              "file holding the bearer token for a server with --auth-tokens (default: $GEOMFIT_TOKEN)", "FILE");
}

bool IsUsageError(const absl::Status& status) {
  return status.GetPayload(kUsagePayload).has_value();
}

bool HasOption(const std::vector<std::string>& args, const std::string& name) {
  for (const std::string& a : args) {
    if (a == "--") return false;
    if (a == "--" + name || absl::StartsWith(a, "--" + name + "=")) return true;
  }
  return false;
}

ArgParser::ArgParser(std::string command, std::string synopsis, std::string description)
    : command_(std::move(command)),
      synopsis_(std::move(synopsis)),
      description_(std::move(description)) {}

ArgParser& ArgParser::Add(const std::string& name, Kind kind, void* out, const std::string& help,
                          const std::string& value_name, const std::string& default_text) {
  options_.push_back({name, help, value_name, default_text, kind, out});
  return *this;
}

ArgParser& ArgParser::Flag(const std::string& name, bool* out, const std::string& help) {
  return Add(name, Kind::kFlag, out, help, "", "");
}
ArgParser& ArgParser::Int(const std::string& name, int* out, const std::string& help) {
  return Add(name, Kind::kInt, out, help, "N", absl::StrCat(*out));
}
ArgParser& ArgParser::UInt64(const std::string& name, uint64_t* out, const std::string& help) {
  return Add(name, Kind::kUInt64, out, help, "N", absl::StrCat(*out));
}
ArgParser& ArgParser::Double(const std::string& name, double* out, const std::string& help) {
  return Add(name, Kind::kDouble, out, help, "X", FormatDefault(*out));
}
ArgParser& ArgParser::String(const std::string& name, std::string* out, const std::string& help,
                             const std::string& value_name) {
  return Add(name, Kind::kString, out, help, value_name, *out);
}
ArgParser& ArgParser::Positional(const std::string& name, std::string* out,
                                 const std::string& help) {
  positionals_.push_back({name, help, out});
  return *this;
}

bool ArgParser::WasSet(const std::string& name) const {
  for (const Option& o : options_)
    if (o.name == name) return o.set;
  return false;
}

absl::Status ArgParser::Store(Option& option, const std::string& value) {
  const std::string what = absl::StrCat("option --", option.name, ": '", value, "' is not ");
  switch (option.kind) {
    case Kind::kFlag: *static_cast<bool*>(option.out) = true; break;
    case Kind::kInt:
      if (!absl::SimpleAtoi(value, static_cast<int*>(option.out)))
        return UsageError(what + "an integer");
      break;
    case Kind::kUInt64:
      if (!absl::SimpleAtoi(value, static_cast<uint64_t*>(option.out)))
        return UsageError(what + "a non-negative integer");
      break;
    case Kind::kDouble: {
      double* d = static_cast<double*>(option.out);
      if (!absl::SimpleAtod(value, d) || !std::isfinite(*d)) return UsageError(what + "a number");
      break;
    }
    case Kind::kString: *static_cast<std::string*>(option.out) = value; break;
  }
  option.set = true;
  return absl::OkStatus();
}

absl::Status ArgParser::Parse(const std::vector<std::string>& args) {
  size_t next_positional = 0;
  bool options_done = false;
  for (size_t i = 0; i < args.size(); ++i) {
    const std::string& a = args[i];
    if (!options_done && (a == "--help" || a == "-h")) {
      help_ = true;
      continue;
    }
    if (!options_done && a == "--") {
      options_done = true;
      continue;
    }
    if (!options_done && absl::StartsWith(a, "-") && a.size() > 1) {
      const size_t eq = a.find('=');
      const std::string flag = a.substr(0, eq);  // "--degree" of "--degree=3"
      Option* option = nullptr;
      for (Option& o : options_)
        if (flag == "--" + o.name) option = &o;
      if (option == nullptr)
        return UsageError(absl::StrCat("unknown option '", flag, "' for '", command_, "' (see '",
                                       command_, " --help')"));
      const std::string& name = option->name;
      if (option->kind == Kind::kFlag) {
        if (eq != std::string::npos)
          return UsageError(absl::StrCat("option --", name, " takes no value"));
        Store(*option, "").IgnoreError();
        continue;
      }
      std::string value;
      if (eq != std::string::npos) {
        value = a.substr(eq + 1);
      } else if (i + 1 < args.size()) {
        value = args[++i];
      } else {
        return UsageError(absl::StrCat("option --", name, " requires a value"));
      }
      absl::Status s = Store(*option, value);
      if (!s.ok()) return s;
      continue;
    }
    if (next_positional >= positionals_.size())
      return UsageError(absl::StrCat("unexpected argument '", a, "' for '", command_, "'"));
    *positionals_[next_positional++].out = a;
  }
  if (!help_ && next_positional < positionals_.size())
    return UsageError(absl::StrCat("'", command_, "' needs ", positionals_[next_positional].name,
                                   " (see '", command_, " --help')"));
  return absl::OkStatus();
}

std::string ArgParser::Usage() const {
  std::string out = absl::StrCat("usage: ", command_, " ", synopsis_, "\n");
  if (!description_.empty()) absl::StrAppend(&out, "\n", description_, "\n");
  if (!positionals_.empty()) {
    out += "\narguments:\n";
    for (const Arg& p : positionals_) absl::StrAppendFormat(&out, "  %-24s %s\n", p.name, p.help);
  }
  out += "\noptions:\n";
  for (const Option& o : options_) {
    const std::string flag =
        o.kind == Kind::kFlag ? "--" + o.name : absl::StrCat("--", o.name, " ", o.value_name);
    absl::StrAppendFormat(&out, "  %-24s %s", flag, o.help);
    if (o.kind != Kind::kFlag && !o.default_text.empty())
      absl::StrAppend(&out, " (default: ", o.default_text, ")");
    out += '\n';
  }
  absl::StrAppendFormat(&out, "  %-24s %s\n", "-h, --help", "show this help and exit");
  return out;
}

void AddCurvatureOptions(ArgParser* p, CurvatureArgs* a) {
  FitOptions& f = a->fit;
  p->Flag("local", &a->local, "compute in this process (the default without --server)")
      .Server(&a->server, "compute on a geomfit server")
      .Int("degree", &f.degree, "fitting degree, 1..6")
      .Double("rings", &f.rings,
              "starting k-ring size in half steps (1, 1.5, 2, ...); 0 = (degree+1)/2")
      .String("method", &a->method,
              "lhf (local height function), lop (orthogonal projection); comparison methods: xu "
              "(1-ring), lscm (conformal map of the stencil)",
              "lhf|lop|xu|lscm")
      .String("noise", &a->noise,
              "noise-aware fitting for O(h^2)-noisy input: approximating flat-weight fits on "
              "d/2+1 rings after smoothing passes (on), or where the mesh looks noisy (auto)",
              "off|on|auto")
      .Int("smoothing-passes", &f.smoothing_passes,
           "smoothing-by-projection passes before the fit; -1 = automatic (with --noise on: "
           "2-4, chosen from the measured noise; see the user guide)")
      .Int("normal-degree", &f.normal_degree,
           "normal refinement: a first fit of this degree (> --degree) fixes the tangent "
           "plane (--degree 2 --normal-degree 3: O(h^3) normals); 0 = off")
      .Flag("hermite-hessian", &f.hermite_hessian,
            "degree 2: curvatures from the stencil's heights and refined normals jointly "
            "(quartic term cancels: H, K ~0.1-0.4x CGAL's); implies --normal-degree 3")
      .Int("slope-refinement", &f.slope_refinement,
           "degree 2: passes (1-3) refining normals and curvatures from the neighbours' fitted "
           "normals on the same stencils (2: normals, H, K ~0.01-0.49x CGAL's on clean meshes at "
           "~4.8x a plain fit in process, the best clean-mesh accuracy at degree 2; 1: up to 0.48x on "
           "marching-cubes meshes, ~4.4x); 0 = off")
      .Flag("quadratic-hermite", &f.quadratic_hermite,
            "degree 2: refine normals and curvatures by the fit's own operator with the "
            "neighbours' fitted normals (normals ~0.01-0.26x, H, K ~0.12-0.42x CGAL's on clean "
            "meshes at ~2.5x a plain fit; --slope-refinement 2: <= 0.29x at ~4.8x)")
      .Flag("plain-cubic", &a->plain_cubic,
            "degree 3: keep the plain fit's normals and curvatures (by default both are refined "
            "with the neighbours' fitted normals: normals ~0.3x, H, K ~0.5x CGAL's or better, "
            "~1.7x the CPU time)")
      .Flag("plain-plane", &a->plain_plane,
            "degree 1: keep the plain plane fit's normals (by default their O(h) bias, a known "
            "map of the Hessian, is removed with the neighbours' normals: order 2, ~0.3x CGAL's "
            "or better)")
      .Flag("hermite-jets", &a->hermite_jets,
            "degrees 4-5: refit the Hessian and gradient with the neighbours' fitted slopes "
            "(H, K ~0.5x CGAL's or better; on by default at degree 5, ~0.75x a plain degree-4 "
            "fit more)")
      .Flag("plain-jets", &a->plain_jets, "degrees 4-5: keep the plain fit's normals and curvatures")
      .String("solver", &a->solver, "least-squares solver: qr (the default) or svd", "qr|svd")
      .Flag("two-pass", &f.two_pass, "refit in frames from the first pass's fitted normals")
      .Flag("interpolate", &a->interpolate, "the fit passes through the vertex (the default)")
      .Flag("approximate", &a->approximate,
            "the fit need not pass through the vertex (least squares only)")
      .Double("angle", &f.safeguard_angle_deg, "normal-angle safeguard in degrees")
      .Int("threads", &a->threads, "worker threads; 0 = all cores")
      .String("output", &a->output, ".vtp, .vtu, .npy, .tsv or .txt (default: TSV on stdout)",
              "FILE")
      .Flag("ascii", &a->ascii, ".vtp/.vtu arrays as text (default: binary, appended raw)")
      .Flag("zlib", &a->zlib, ".vtp/.vtu appended arrays zlib-compressed (smaller, slower to write)")
      .Flag("verbose", &a->verbose, "print timings to stderr");
}

absl::Status ParseCurvatureArgs(const std::vector<std::string>& argv, CurvatureArgs* a,
                                bool* help) {
  ArgParser p(
      "geomfit curvature", "[--local | --server HOST:PORT] MESH [options]",
      "Per-vertex normals, mean and Gaussian curvature, principal curvatures and\n"
      "directions from weighted-least-squares polynomial fits.\n"
      "Output columns: nx ny nz H K k1 k2 e1x e1y e1z e2x e2y e2z degree_used points flags\n"
      "(.npy: the first 13 columns).");
  p.Positional("MESH", &a->mesh, "mesh file (.obj .off .ply .stl)");
  AddCurvatureOptions(&p, a);
  absl::Status s = p.Parse(argv);
  if (!s.ok()) return s;
  *help = p.help_requested();
  if (*help) {
    std::fputs(p.Usage().c_str(), stdout);
    return absl::OkStatus();
  }
  if (a->local && !a->server.empty()) return UsageError("--local and --server exclude each other");
  if (absl::Status e = VtkEncodingFromFlags(a->ascii, a->zlib).status(); !e.ok()) return e;
  if (a->method == "lhf") {
    a->fit.method = FitMethod::kLHF;
  } else if (a->method == "lop") {
    a->fit.method = FitMethod::kLOP;
  } else if (a->method == "xu") {
    a->fit.method = FitMethod::kXu;
  } else if (a->method == "lscm") {
    a->fit.method = FitMethod::kLSCM;
  } else {
    return UsageError(absl::StrCat("option --method: '", a->method, "' is not lhf, lop, xu or lscm"));
  }
  if (a->noise == "off") {
    a->fit.noise = NoiseMode::kOff;
  } else if (a->noise == "on") {
    a->fit.noise = NoiseMode::kOn;
  } else if (a->noise == "auto") {
    a->fit.noise = NoiseMode::kAuto;
  } else {
    return UsageError(absl::StrCat("option --noise: '", a->noise, "' is not off, on or auto"));
  }
  if (a->solver == "qr") {
    a->fit.solver = WlsSolver::kQR;
  } else if (a->solver == "svd") {
    a->fit.solver = WlsSolver::kSVD;
  } else {
    return UsageError(absl::StrCat("option --solver: '", a->solver, "' is not qr or svd"));
  }
  if (a->interpolate && a->approximate)
    return UsageError("--interpolate and --approximate exclude each other");
  a->fit.interpolate = !a->approximate;
  if (a->plain_cubic) a->fit.cubic_hermite = false;
  if (a->plain_plane) a->fit.plane_hermite = false;
  if (a->hermite_jets && a->plain_jets) return UsageError("--hermite-jets and --plain-jets exclude each other");
  if (a->hermite_jets) a->fit.jet_hermite = JetHermiteMode::kOn;
  if (a->plain_jets) a->fit.jet_hermite = JetHermiteMode::kOff;
  if (a->fit.rings > a->fit.max_rings) a->fit.max_rings = std::min(a->fit.rings, 10.0);
  s = ValidateFitOptions(a->fit);
  if (!s.ok()) return UsageError(s.message());
  if (!a->output.empty()) {
    auto kind = OutputKindFromPath(a->output);
    if (!kind.ok()) return kind.status();
  }
  return absl::OkStatus();
}

}  // namespace geomfit::cli
