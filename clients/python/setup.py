"""Build steps of the geomfit Python package (metadata: pyproject.toml).

build_py  generates the gRPC stubs (protoc + grpc_python_plugin, Debian's
          protobuf-compiler and protobuf-compiler-grpc) from the project's proto/ into
          the package being built: geomfit/_gen/geomfit/v1/*.py in the build folder, or
          in the source folder for an editable install.
build_ext builds the native transport geomfit._native with the project's CMake (target
          geomfit_native, for the interpreter running the install). Without CMake, a
          compiler or the C++ client's dependencies it warns and the package falls back
          to grpcio. Environment: GEOMFIT_NATIVE=0 skips it, =1 makes a failure fatal;
          GEOMFIT_CMAKE_BUILD_DIR reuses a configured build of the project.
"""
import os
import shutil
import subprocess
import sys
import sysconfig

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
PROJECT = os.path.dirname(os.path.dirname(HERE))  # clients/python -> the project root


def _proto_dir() -> str:
    d = os.environ.get("GEOMFIT_PROTO_DIR", os.path.join(PROJECT, "proto"))
    if not os.path.isfile(os.path.join(d, "geomfit", "v1", "geomfit.proto")):
        raise RuntimeError("geomfit: proto files not found in %s (set GEOMFIT_PROTO_DIR)" % d)
    return d


def generate_stubs(package_dir: str) -> None:
    """protoc --python_out and grpc_python_plugin into package_dir/_gen."""
    protoc, plugin = shutil.which("protoc"), shutil.which("grpc_python_plugin")
    if not protoc or not plugin:
        raise RuntimeError("geomfit: protoc and grpc_python_plugin are needed to build the package "
                           "(Debian: protobuf-compiler protobuf-compiler-grpc)")
    proto = _proto_dir()
    out = os.path.join(package_dir, "_gen")
    os.makedirs(out, exist_ok=True)
    files = [os.path.join(proto, "geomfit", "v1", f) for f in sorted(os.listdir(os.path.join(proto, "geomfit", "v1")))
             if f.endswith(".proto")]
    subprocess.check_call([protoc, "-I", proto, "--python_out=" + out, "--grpc_out=" + out,
                           "--plugin=protoc-gen-grpc=" + plugin] + files)


class BuildPy(build_py):
    """build_py that also generates the stubs into the package it builds."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            generate_stubs(os.path.join(HERE, "geomfit"))
        else:
            generate_stubs(os.path.join(self.build_lib, "geomfit"))

    def get_outputs(self, include_bytecode=True):
        outputs = super().get_outputs(include_bytecode)
        gen = os.path.join(self.build_lib, "geomfit", "_gen")
        for root, _, files in os.walk(gen):
            outputs += [os.path.join(root, f) for f in files]
        return outputs


class CMakeExtension(Extension):
    def __init__(self, name: str):
        super().__init__(name, sources=[])


class BuildNative(build_ext):
    """Builds geomfit._native with the project's CMake; optional unless GEOMFIT_NATIVE=1."""

    def build_extension(self, ext):
        mode = os.environ.get("GEOMFIT_NATIVE", "auto")
        stale = self.get_ext_fullpath(ext.name)  # from an earlier build in the same folder
        if os.path.isfile(stale):
            os.remove(stale)
        if mode == "0":
            print("geomfit: GEOMFIT_NATIVE=0: no native transport (grpcio only)")
            return
        try:
            self._cmake_build(ext)
        except Exception as e:  # noqa: BLE001 (any failure means: fall back to grpcio)
            if mode == "1":
                raise
            print("geomfit: WARNING: the native transport was not built (%s); the package uses grpcio "
                  "for every call" % e, file=sys.stderr)

    def _built(self):
        """The extensions whose module was built (a skipped one has no file)."""
        return [e for e in self.extensions if os.path.isfile(self.get_ext_fullpath(e.name))]

    def copy_extensions_to_source(self):  # editable installs: only what was built
        extensions, self.extensions = self.extensions, self._built()
        try:
            super().copy_extensions_to_source()
        finally:
            self.extensions = extensions

    def get_outputs(self):
        return [o for o in super().get_outputs() if os.path.isfile(o)]

    def _cmake_build(self, ext):
        cmake = shutil.which("cmake")
        if not cmake:
            raise RuntimeError("cmake is missing")
        target = os.path.abspath(self.get_ext_fullpath(ext.name))
        out_dir = os.path.join(os.path.abspath(self.build_temp), "python")
        build_dir = os.environ.get("GEOMFIT_CMAKE_BUILD_DIR")
        if build_dir:  # an existing build: its module is for the same interpreter ABI
            subprocess.check_call([cmake, "--build", build_dir, "--target", "geomfit_native"])
            cache = open(os.path.join(build_dir, "CMakeCache.txt")).read()
            py_dir = next((line.split("=", 1)[1] for line in cache.splitlines()
                           if line.startswith("GEOMFIT_PYTHON_DIR:")), os.path.join(build_dir, "python"))
            built = os.path.join(py_dir, "geomfit")
        else:
            if not os.path.isfile(os.path.join(PROJECT, "CMakeLists.txt")):
                raise RuntimeError("the geomfit project's sources are missing in %s" % PROJECT)
            build_dir = os.path.join(os.path.abspath(self.build_temp), "cmake")
            os.makedirs(build_dir, exist_ok=True)
            generator = ["-G", "Ninja"] if shutil.which("ninja") else []
            subprocess.check_call(
                [cmake, "-S", PROJECT, "-B", build_dir, *generator, "-DCMAKE_BUILD_TYPE=Release",
                 "-DGEOMFIT_BUILD_TESTS=OFF", "-DGEOMFIT_BUILD_BENCH=OFF",
                 "-DPython3_EXECUTABLE=" + sys.executable, "-DGEOMFIT_PYTHON_DIR=" + out_dir])
            subprocess.check_call([cmake, "--build", build_dir, "--target", "geomfit_native",
                                   "--parallel", str(os.cpu_count() or 1)])
            built = os.path.join(out_dir, "geomfit")
        suffix = sysconfig.get_config_var("EXT_SUFFIX")
        source = os.path.join(built, "_native" + suffix)
        if not os.path.isfile(source):
            raise RuntimeError("CMake did not produce %s" % source)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copyfile(source, target)
        print("geomfit: native transport built: %s" % target)


setup(
    ext_modules=[CMakeExtension("geomfit._native")],
    cmdclass={"build_py": BuildPy, "build_ext": BuildNative},
)
