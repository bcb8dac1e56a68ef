"""progress= on the Client's long methods: the server's progress messages reach a
callable(phase, done, total) monotonically, results are those of the calls without it,
and progress=True draws tqdm bars."""
import os
import subprocess

import numpy as np

import geomfit
from conftest import torus


class Recorder:
    def __init__(self):
        self.calls = []

    def __call__(self, phase, done, total):
        self.calls.append((phase, done, total))

    def phases(self):
        """Phases in order; within each, done increases strictly and ends at total."""
        out = []
        for i, (phase, done, total) in enumerate(self.calls):
            if not out or out[-1] != phase:
                out.append(phase)
            else:
                assert done > self.calls[i - 1][1], self.calls
            if i + 1 == len(self.calls) or self.calls[i + 1][0] != phase:
                assert total == 0 or done == total, self.calls
        self.calls = []
        return out


def test_long_methods_report_progress_and_match_the_plain_calls(server, transport):
    positions, faces = torus(96, 48)
    seen = Recorder()
    with geomfit.Client(server.address, transport=transport) as c:
        mesh_id = c.upload(positions, faces).mesh_id
        d = c.curvature(mesh_id, degree=4, progress=seen)
        assert seen.phases() == ["fit", "compute"]  # the last rows come after the fit's end
        plain_d = c.curvature(mesh_id, degree=4)
        np.testing.assert_array_equal(d.mean, plain_d.mean)

        points = 1.02 * positions[::3]
        p = c.project(mesh_id, points, degree=4, progress=seen)
        assert seen.phases() == ["fit", "project"]
        plain_p = c.project(mesh_id, points, degree=4)
        for key in ("positions", "normals", "faces", "natural", "distances"):
            np.testing.assert_array_equal(p[key], plain_p[key])

        nodes, elements = c.high_order_nodes(mesh_id, order=3, degree=4, progress=seen)
        assert seen.phases() == ["evaluate points"]  # fitted by project already
        plain_nodes, plain_elements = c.high_order_nodes(mesh_id, order=3, degree=4)
        np.testing.assert_array_equal(nodes, plain_nodes)
        assert all((a == b).all() for a, b in zip(elements, plain_elements))

        r = c.integrate(mesh_id, scalars=np.ones(len(positions)), degree=4, progress=seen)
        assert seen.phases() == ["fit", "integrate: fields", "integrate"]  # fields need stencils: a new fit
        plain_r = c.integrate(mesh_id, scalars=np.ones(len(positions)), degree=4)
        assert (r.area, r.volume, list(r.scalars)) == (plain_r.area, plain_r.volume, list(plain_r.scalars))
        assert not r.HasField("progress")

        refined = c.refine(mesh_id, degree=4, progress=seen)
        assert seen.phases() == ["evaluate points"]
        assert refined.num_faces == 4 * len(faces)
        assert refined.content_hash == c.refine(mesh_id, degree=4).content_hash


def test_noise_passes_and_membrane_report_their_phases(server, transport):
    positions, faces = torus(64, 30)
    seen = Recorder()
    with geomfit.Client(server.address, transport=transport) as c:
        mesh_id = c.upload(positions, faces).mesh_id
        d = c.curvature(mesh_id, degree=4, noise="on", diagnostics=True, progress=seen)
        # a clean torus: light noise, two smoothing and two local passes at degree 4 (noise.h)
        assert seen.phases() == ["smooth 1/4", "smooth 2/4", "smooth 3/4", "smooth 4/4", "fit", "compute"]
        plain = c.curvature(mesh_id, degree=4, noise="on", diagnostics=True)  # cached; native if available
        for key in ("normals", "mean", "gaussian", "k1", "k2"):
            np.testing.assert_array_equal(getattr(d, key), getattr(plain, key))
        np.testing.assert_array_equal(d.diagnostics["degree_used"], plain.diagnostics["degree_used"])

        deformed = 1.05 * positions
        p = c.membrane_pressure(mesh_id, deformed, young_modulus=1.0, poisson_ratio=0.3, progress=seen)
        assert seen.phases() == ["fit", "membrane"]
        again = c.membrane_pressure(mesh_id, deformed, young_modulus=1.0, poisson_ratio=0.3, progress=seen)
        assert seen.phases() == ["membrane"]  # the reference fits are cached
        np.testing.assert_array_equal(p, again)
        np.testing.assert_array_equal(p, c.membrane_pressure(mesh_id, deformed, young_modulus=1.0, poisson_ratio=0.3))


def test_flow_and_membrane_solve_report_their_job_events(server, data_dir):
    sphere = os.path.join(data_dir, "sphere.obj")
    subprocess.run([os.environ["GEOMFIT_CLI_BINARY"], "generate", "sphere", "--level", "8", "--output", sphere],
                   check=True, timeout=60)
    seen = Recorder()
    with geomfit.Client(server.address) as c:
        mesh_id = c.upload_file(sphere).mesh_id
        events = list(c.flow(mesh_id, dt=1e-4, steps=4, progress=seen))
        assert events[-1].final
        steps = [(done, total) for phase, done, total in seen.calls if phase == "step"]
        assert steps == [(k, 4) for k in range(1, 5)], seen.calls
        seen.calls = []
        events = list(c.membrane_solve(mesh_id, 2.0, young_modulus=100.0, poisson_ratio=0.2, new_mesh=True,
                                       progress=seen))
        assert events[-1].final
        assert "newton" in [phase for phase, _, _ in seen.calls], seen.calls


def test_progress_true_draws_a_tqdm_bar_per_phase(server, capsys):
    positions, faces = torus(48, 24)
    with geomfit.Client(server.address) as c:
        mesh_id = c.upload(positions, faces).mesh_id
        c.project(mesh_id, 1.01 * positions, progress=True)
        c.integrate(mesh_id, progress=True)
        c.wait_job(c.refine_job(mesh_id, levels=1).job_id, progress=True)
    err = capsys.readouterr().err
    for phase in ("fit", "project", "integrate", "refine 1"):
        assert phase + ":" in err, err  # tqdm's "desc: 100%|..." lines
    assert "100%" in err


def test_text_progress_without_tqdm(server, monkeypatch):
    import io
    import sys

    import geomfit.progress
    monkeypatch.setitem(sys.modules, "tqdm", None)  # import tqdm fails
    out = io.StringIO()
    bars = geomfit.progress.PhaseBars(stream=out)
    positions, faces = torus(24, 12)
    with geomfit.Client(server.address) as c:
        c.integrate(c.upload(positions, faces).mesh_id, progress=bars)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("geomfit: fit ") and lines[-1].startswith("geomfit: integrate "), lines
    done, total = lines[-1].split()[-1].split("/")
    assert done == total


def test_bad_progress_argument_is_a_type_error(server):
    positions, faces = torus(24, 12)
    with geomfit.Client(server.address) as c:
        mesh_id = c.upload(positions, faces).mesh_id
        try:
            c.integrate(mesh_id, progress="yes")
        except TypeError as e:
            assert "callable(phase, done, total)" in str(e)
        else:
            raise AssertionError("progress='yes' was accepted")
