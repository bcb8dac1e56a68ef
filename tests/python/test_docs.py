"""docs/user-guide.md runs: its Python blocks in order against a real server, its C++
example is the consumer the install test builds, and it names every option the
programs' --help lists."""
import os
import re
import shutil
import subprocess

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
GUIDE = os.path.join(ROOT, "docs", "user-guide.md")
CLI = os.environ.get("GEOMFIT_CLI_BINARY", "")
SERVER = os.environ.get("GEOMFIT_SERVER_BINARY", "")


def blocks(language):
    return re.findall(r"```%s\n(.*?)```" % language, open(GUIDE).read(), re.S)


def test_python_examples_run(server, tmp_path, monkeypatch, capsys):
    os.makedirs(tmp_path / "data")
    shutil.copy(os.path.join(ROOT, "data", "torus.obj"), tmp_path / "data")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PATH", os.path.dirname(CLI) + os.pathsep + os.environ["PATH"])
    code = blocks("python")
    assert len(code) >= 3
    namespace = {}
    for i, block in enumerate(code):
        exec(compile(block.replace("127.0.0.1:50051", server.address), "%s[python block %d]" % (GUIDE, i), "exec"),
             namespace)
    out = capsys.readouterr().out
    assert "max relative error of H" in out and "exact" in out


def test_cpp_example_is_the_tested_consumer():
    consumer = os.path.join(ROOT, "tests", "install", "consumer")
    assert open(os.path.join(consumer, "main.cc")).read() in blocks("cpp")
    assert open(os.path.join(consumer, "CMakeLists.txt")).read() in blocks("cmake")


def help_options(*argv):
    text = subprocess.run(list(argv) + ["--help"], capture_output=True, text=True).stdout
    return set(re.findall(r"^\s+(--[a-z][a-z0-9-]*)", text, re.M)) - {"--help"}


@pytest.mark.parametrize("command", ["curvature", "generate", "convert", "project", "refine", "nodes", "integrate",
                                     "upload", "update", "info", "list", "delete", "jobs watch", "membrane pressure",
                                     "membrane solve", "server"])
def test_every_option_is_documented(command):
    guide = open(GUIDE).read()
    options = help_options(SERVER) if command == "server" else help_options(CLI, *command.split())
    assert options, command
    missing = sorted(o for o in options if not re.search(r"[` ]%s(?![a-z-])" % re.escape(o), guide))
    assert not missing, "%s: %s" % (command, missing)
