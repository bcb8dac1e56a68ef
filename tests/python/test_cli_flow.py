"""`geomfit flow --server ... --output-series PREFIX` writes a .pvd time series whose
.vtp snapshots VTK reads back (python3-vtk9): the first frame is the input, the last
the mesh's final revision on the server; `geomfit operator` writes Matrix Market."""
import os
import re
import signal
import subprocess
import xml.etree.ElementTree as ET

import numpy as np

import geomfit
from geomfit.v1 import geomfit_pb2 as pb
import vtk  # noqa: E402  (python3-vtk9, installed by scripts/install-deps.sh)
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402

from conftest import torus

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def cli(*args):
    binary = os.environ.get("GEOMFIT_CLI_BINARY")
    assert binary and os.path.exists(binary), "GEOMFIT_CLI_BINARY must name the geomfit binary"
    r = subprocess.run([binary, *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, "geomfit %s failed (%d): %s" % (" ".join(args), r.returncode, r.stderr)
    return r


def read_vtp(path):
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(path)
    reader.Update()
    out = reader.GetOutput()
    return vtk_to_numpy(out.GetPoints().GetData()), out.GetNumberOfPolys()


def test_flow_writes_a_pvd_series(server, data_dir):
    torus_obj = os.path.join(REPO, "data", "torus.obj")
    prefix = os.path.join(data_dir, "mcf")
    r = cli("flow", torus_obj, "--server", server.address, "--dt", "1e-3", "--steps", "4", "--snapshot-every", "2",
            "--degree", "3", "--time-tolerance", "1e-3", "--output-series", prefix)
    assert r.stderr.count("geomfit: step ") == 4, r.stderr
    assert "SUCCEEDED" in r.stderr
    root = ET.parse(prefix + ".pvd").getroot()
    sets = root.find("Collection").findall("DataSet")
    assert [float(s.get("timestep")) for s in sets] == [0.0, 2e-3, 4e-3]
    frames = [read_vtp(os.path.join(data_dir, s.get("file"))) for s in sets]
    with geomfit.Client(server.address) as client:
        mesh = [m for m in client.list_meshes()][0]
        final, faces, info = client.download(mesh.mesh_id)
    assert info.revision == mesh.revision
    points0, polys0 = frames[0]
    assert polys0 == len(faces) and len(points0) == len(final)
    np.testing.assert_array_equal(frames[-1][0], final)  # the last frame is the stored revision
    assert np.abs(frames[1][0] - points0).max() > 0  # it moved


def test_flow_local_and_operator(server, data_dir):
    torus_obj = os.path.join(REPO, "data", "torus.obj")
    prefix = os.path.join(data_dir, "local")
    r = cli("flow", torus_obj, "--local", "--dt", "1e-3", "--steps", "2", "--degree", "3", "--time-tolerance", "0",
            "--output-series", prefix)
    assert r.stderr.count("geomfit: step ") == 2, r.stderr
    bad = subprocess.run([os.environ["GEOMFIT_CLI_BINARY"], "flow", torus_obj, "--local", "--steps", "2",
                          "--time-tolerance", "-1"], capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "--time-tolerance" in bad.stderr, bad.stderr
    sets = ET.parse(prefix + ".pvd").getroot().find("Collection").findall("DataSet")
    assert len(sets) == 3
    mtx = os.path.join(data_dir, "L.mtx")
    cli("operator", torus_obj, "--server", server.address, "--operator", "laplace_beltrami", "--output", mtx)
    lines = open(mtx).read().splitlines()
    assert lines[0].startswith("%%MatrixMarket matrix coordinate real general")
    rows, cols, nnz = map(int, lines[1].split())
    assert rows == cols and nnz == len(lines) - 2
    # Rows of L sum to zero (L 1 = 0).
    sums = np.zeros(rows)
    for line in lines[2:]:
        i, j, v = line.split()
        sums[int(i) - 1] += float(v)
    assert np.abs(sums).max() < 1e-8


def start_cli(*args):
    """The geomfit CLI as a child whose stderr we read line by line."""
    binary = os.environ.get("GEOMFIT_CLI_BINARY")
    assert binary and os.path.exists(binary), "GEOMFIT_CLI_BINARY must name the geomfit binary"
    return subprocess.Popen([binary, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def interrupt_after(proc, stream, marker):
    """Reads `stream` until a line containing `marker`, sends SIGINT, and returns the
    exit code (within 10 s: Ctrl-C must stop the work at once) and every line read."""
    lines = []
    for line in stream:
        lines.append(line)
        if marker in line:
            break
    assert proc.poll() is None, "the command ended before the interrupt: %s" % "".join(lines)
    proc.send_signal(signal.SIGINT)
    try:
        rest = stream.read()
        code = proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return code, "".join(lines) + rest


def test_ctrl_c_cancels_the_remote_flow_job(server, data_dir):
    torus_obj = os.path.join(REPO, "data", "torus.obj")
    prefix = os.path.join(data_dir, "cut")
    proc = start_cli("flow", torus_obj, "--server", server.address, "--dt", "1e-6", "--steps", "100000",
                     "--degree", "3", "--output-series", prefix)
    code, err = interrupt_after(proc, proc.stderr, "geomfit: step 2/")
    assert code == 130, err
    job_id = re.search(r"started flow job (\S+)", err).group(1)
    assert "cancelling job %s" % job_id in err
    with geomfit.Client(server.address) as client:
        job = client.get_job(job_id)
    assert job.state == pb.JOB_STATE_CANCELLED, job
    # The series written so far stays readable.
    sets = ET.parse(prefix + ".pvd").getroot().find("Collection").findall("DataSet")
    assert len(sets) >= 3


def test_ctrl_c_in_jobs_watch_cancels_the_job(server):
    pos, tris = torus(48, 24)
    with geomfit.Client(server.address) as client:
        mesh = client.upload(pos, tris)
        job = client.start_flow(mesh.mesh_id, dt=1e-6, steps=100000, degree=3)
        proc = start_cli("jobs", "watch", "--server", server.address, job.job_id)
        code, out = interrupt_after(proc, proc.stdout, " step 1")
        assert code == 130, out + proc.stderr.read()
        assert client.get_job(job.job_id).state == pb.JOB_STATE_CANCELLED


def test_ctrl_c_stops_a_local_flow(data_dir):
    torus_obj = os.path.join(REPO, "data", "torus.obj")
    prefix = os.path.join(data_dir, "local_cut")
    proc = start_cli("flow", torus_obj, "--local", "--dt", "1e-6", "--steps", "100000", "--degree", "3",
                     "--output-series", prefix)
    code, err = interrupt_after(proc, proc.stderr, "geomfit: step 2/")
    assert code == 130, err
    assert "flow cancelled after" in err
    sets = ET.parse(prefix + ".pvd").getroot().find("Collection").findall("DataSet")
    assert len(sets) >= 3
