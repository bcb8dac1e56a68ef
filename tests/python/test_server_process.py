"""The geomfit-server binary's process-level options: --log-format=json."""
import json
import os
import signal
import subprocess

from conftest import ServerProcess


def test_json_log_lines_are_json_objects(tmp_path):
    log = tmp_path / "server.log"
    binary = os.environ["GEOMFIT_SERVER_BINARY"]
    with open(log, "w") as err:
        proc = subprocess.Popen([binary, "--host=127.0.0.1", "--port=0", "--store=memory", "--log-format=json"],
                                stdout=subprocess.PIPE, stderr=err, text=True)
        assert "listening on port" in proc.stdout.readline()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
    lines = log.read_text().splitlines()
    assert len(lines) >= 3, lines  # listening, received signal, draining, stopped, exit
    records = [json.loads(line) for line in lines]
    for r in records:
        assert set(r) == {"time", "level", "logger", "thread", "message"}, r
        assert r["time"].endswith("Z") and r["level"] in ("info", "warning") and r["logger"] == "geomfit-server"
    assert any(r["message"].startswith("geomfit-server listening on 127.0.0.1:") for r in records)
    assert records[-1]["message"] == "exit"


def test_version_and_text_logs_unchanged():
    binary = os.environ["GEOMFIT_SERVER_BINARY"]
    out = subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0 and out.stdout.startswith("geomfit-server ")
    s = ServerProcess("--store=memory")
    assert s.kill(signal.SIGTERM) == 0
