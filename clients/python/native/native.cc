// geomfit._native: geomfit::Client (clients/cpp/client) as a Python extension module.
// The Python client (clients/python/geomfit/client.py, transport "native") sends its
// per-time-step calls through it: SetPositions and ComputeDifferentials. Messages
// cross as serialized protobuf bytes, arrays as numpy arrays without copies: positions
// are read in place, results hand their Eigen storage over to numpy. The GIL is
// released for every call.
#include <algorithm>
#include <cmath>
#include <optional>
#include <stdexcept>
#include <string>
#include <utility>

#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "clients/cpp/client/client.h"
#include "core/mesh/io.h"
#include "core/mesh/content_hash.h"

namespace py = pybind11;
using namespace pybind11::literals;

namespace geomfit {
namespace {

/// geomfit._native.RpcError, args (code, details): the numeric gRPC status code (the
/// same numbers as absl's) and the server's message. Owned by the module.
PyObject* rpc_error = nullptr;

void RaiseIfError(const absl::Status& status) {
  if (status.ok()) return;
  const auto message = status.message();
  py::object details = py::reinterpret_steal<py::object>(
      PyUnicode_DecodeUTF8(message.data(), static_cast<Py_ssize_t>(message.size()), "replace"));
  PyErr_SetObject(rpc_error, py::make_tuple(static_cast<int>(status.code()), details).ptr());
  throw py::error_already_set();
}

/// Seconds as milliseconds; None (or more than 1e9 s) is 1e9 s, "no deadline".
std::chrono::milliseconds Millis(std::optional<double> seconds) {
  const double s = seconds && *seconds < 1e9 ? std::max(0.0, *seconds) : 1e9;
  return std::chrono::milliseconds(static_cast<int64_t>(std::ceil(1e3 * s)));
}

/// Moves an Eigen array into a numpy array (no copy of the data) if it is not empty.
template <typename Array>
void Put(py::dict& out, const char* name, Array&& array) {
  if (array.size() != 0) out[name] = py::cast(std::forward<Array>(array));
}

/// Per-vertex diagnostics as numpy columns (int32 points, degree_used, flags; float64
/// condition), or None when there are none.
py::object DiagnosticsArrays(const std::vector<VertexDiagnostics>& d) {
  if (d.empty()) return py::none();
  const auto n = static_cast<py::ssize_t>(d.size());
  py::array_t<int32_t> points(n), degree(n), flags(n);
  py::array_t<double> condition(n);
  auto p = points.mutable_unchecked<1>(), g = degree.mutable_unchecked<1>(), f = flags.mutable_unchecked<1>();
  auto c = condition.mutable_unchecked<1>();
  for (py::ssize_t i = 0; i < n; ++i) {
    p(i) = d[i].points;
    g(i) = d[i].degree_used;
    f(i) = d[i].flags;
    c(i) = d[i].condition;
  }
  return py::dict("points"_a = points, "degree_used"_a = degree, "flags"_a = flags, "condition"_a = condition);
}

class NativeClient {
 public:
  NativeClient(const std::string& target, std::optional<double> timeout, int max_attempts, double backoff,
               int64_t max_message_bytes, int64_t chunk_rows, bool tls, const std::string& tls_ca,
               const std::string& tls_cert, const std::string& tls_key, const std::string& token) {
    ClientOptions o;
    o.target = target;
    o.deadline = Millis(timeout);
    o.max_attempts = max_attempts;
    o.initial_backoff = Millis(backoff);
    o.max_message_bytes = max_message_bytes;
    o.chunk_rows = chunk_rows;
    o.tls = tls;
    o.tls_ca = tls_ca;
    o.tls_cert = tls_cert;
    o.tls_key = tls_key;
    o.token = token;
    auto client = Client::Create(o);
    if (!client.ok()) throw std::invalid_argument(std::string(client.status().message()));
    client_ = *std::move(client);
  }

  /// UpdatePositions; returns the serialized MeshInfo.
  py::bytes SetPositions(const std::string& mesh_id,
                         const py::array_t<double, py::array::c_style | py::array::forcecast>& positions,
                         std::optional<int64_t> expected_revision) {
    if (positions.ndim() != 2 || positions.shape(1) != 3) {
      throw py::value_error("positions must be #V x 3, got " + std::string(py::str(positions.attr("shape"))));
    }
    const Eigen::Map<const Positions> map(positions.data(), positions.shape(0), 3);
    absl::StatusOr<v1::MeshInfo> info;
    {
      py::gil_scoped_release release;
      info = client_->UpdatePositionsWire(mesh_id, map, expected_revision);
    }
    RaiseIfError(info.status());
    return py::bytes(info->SerializeAsString());
  }

  /// ComputeDifferentials of a serialized request: (serialized FitSummary, {name:
  /// array} of the requested arrays, diagnostics {name: array} or None).
  py::tuple Compute(const py::bytes& serialized) {
    char* data = nullptr;
    Py_ssize_t size = 0;
    if (PyBytes_AsStringAndSize(serialized.ptr(), &data, &size) != 0) throw py::error_already_set();
    v1::ComputeDifferentialsRequest request;
    if (!request.ParseFromArray(data, static_cast<int>(size))) {
      throw py::value_error("compute: not a serialized ComputeDifferentialsRequest");
    }
    absl::StatusOr<RemoteDifferentials> r;
    {
      py::gil_scoped_release release;
      r = client_->ComputeDifferentials(std::move(request));
    }
    RaiseIfError(r.status());
    Differentials& v = r->values;
    py::dict arrays;
    Put(arrays, "normals", std::move(v.normals));
    Put(arrays, "mean", std::move(v.mean));
    Put(arrays, "gaussian", std::move(v.gaussian));
    Put(arrays, "k1", std::move(v.k1));
    Put(arrays, "k2", std::move(v.k2));
    Put(arrays, "dir1", std::move(v.dir1));
    Put(arrays, "dir2", std::move(v.dir2));
    Put(arrays, "tensor", std::move(v.tensor));
    return py::make_tuple(py::bytes(r->wire_summary.SerializeAsString()), arrays, DiagnosticsArrays(v.diagnostics));
  }

 private:
  std::unique_ptr<Client> client_;
};

/// core's ReadMesh (OBJ, OFF, PLY, STL): (positions #V x 3 float64, faces #F x 3 int32,
/// or #F x 4 with -1 padding when there are quads). Errors raise ValueError with the
/// reader's message (file, line or face).
py::tuple ReadMeshFile(const std::string& path) {
  absl::StatusOr<Mesh> mesh;
  {
    py::gil_scoped_release release;
    mesh = ReadMesh(path);
  }
  if (!mesh.ok()) throw py::value_error(std::string(mesh.status().message()));
  const Faces& all = mesh->faces;
  const bool quads = mesh->HasQuads();
  Eigen::Matrix<int32_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> faces =
      quads ? all.leftCols(4) : all.leftCols(3);
  return py::make_tuple(py::cast(std::move(mesh->positions)), py::cast(std::move(faces)));
}

/// The mesh id the server gives an upload (MeshContentHash): the routing key.
std::string UploadMeshId(const py::array_t<double, py::array::c_style | py::array::forcecast>& positions,
                     const py::array_t<int32_t, py::array::c_style | py::array::forcecast>& faces,
                     const std::string& name, const std::map<std::string, std::string>& labels) {
  if (positions.ndim() != 2 || positions.shape(1) != 3) throw py::value_error("positions must be #V x 3");
  if (faces.ndim() != 2 || (faces.shape(1) != 3 && faces.shape(1) != 4))
    throw py::value_error("faces must be #F x 3 or #F x 4");
  Mesh mesh;
  mesh.positions = Eigen::Map<const Positions>(positions.data(), positions.shape(0), 3);
  Faces& mf = mesh.faces.Mutable();
  mf.setConstant(faces.shape(0), 4, -1);
  const auto in = faces.unchecked<2>();
  for (py::ssize_t f = 0; f < in.shape(0); ++f)
    for (py::ssize_t c = 0; c < in.shape(1); ++c) mf(f, c) = in(f, c);
  return MeshIdOf(MeshContentHash(mesh, name, labels));
}

}  // namespace
}  // namespace geomfit

PYBIND11_MODULE(_native, m) {
  using geomfit::NativeClient;
  m.doc() = "geomfit::Client (C++) for the Python client's transport=\"native\"; see geomfit.Client.";
  geomfit::rpc_error = PyErr_NewExceptionWithDoc(
      "geomfit._native.RpcError", "A failed call: args = (numeric gRPC status code, details).", nullptr, nullptr);
  if (!geomfit::rpc_error) throw py::error_already_set();
  m.add_object("RpcError", py::handle(geomfit::rpc_error));  // the module holds a reference too

  py::class_<NativeClient>(m, "Client")
      .def(py::init<const std::string&, std::optional<double>, int, double, int64_t, int64_t, bool, const std::string&,
                    const std::string&, const std::string&, const std::string&>(),
           "target"_a, "timeout"_a, "max_attempts"_a, "backoff"_a, "max_message_bytes"_a, "chunk_rows"_a = 16384,
           "tls"_a = false, "tls_ca"_a = "", "tls_cert"_a = "", "tls_key"_a = "", "token"_a = "",
           "Creates the channel (does not wait for the server). Per-attempt deadline `timeout` "
           "seconds (None: none); UNAVAILABLE is retried max_attempts times from `backoff` seconds on. "
           "TLS when any tls_* PEM path is given (tls_ca: the server's CA; tls_cert/tls_key: mTLS).")
      .def("set_positions", &NativeClient::SetPositions, "mesh_id"_a, "positions"_a,
           "expected_revision"_a = py::none(),
           "New positions (#V x 3 float64, read in place when C-contiguous: do not modify the "
           "array from another thread during the call); returns the serialized MeshInfo.")
      .def("compute", &NativeClient::Compute, "request"_a,
           "ComputeDifferentials of a serialized ComputeDifferentialsRequest: (serialized "
           "FitSummary, dict of the requested arrays, dict of diagnostics or None).");
  m.def("read_mesh", &geomfit::ReadMeshFile, "path"_a,
        "Reads OBJ, OFF, PLY (ascii, binary) or STL (ascii, binary) with geomfit's C++ readers: "
        "(positions #V x 3 float64, faces #F x 3 int32, or #F x 4 with -1 padding).");
  m.def("mesh_id_of", &geomfit::UploadMeshId, "positions"_a, "faces"_a, "name"_a, "labels"_a,
        "The mesh_id the server gives this upload (content, name, labels).");
}
