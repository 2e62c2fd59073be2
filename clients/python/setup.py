"""Builds spokemesh._core from the repository's core sources (C++20, exact predicates:
-ffp-contract=off, never -ffast-math) and the gRPC stubs from proto/ with Debian's
protoc and grpc_python_plugin. Metadata lives in pyproject.toml."""

import glob
import os
import shutil
import subprocess

import pybind11
from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext
from setuptools.command.build_py import build_py

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.normpath(os.path.join(HERE, "..", ".."))


def rel(path: str) -> str:
    return os.path.relpath(path, HERE)


class BuildWithStubs(build_py):
    """build_py, plus spokemesh/v1/mesher_pb2{,_grpc}.py generated from the contract."""

    def run(self):
        super().run()
        protoc = shutil.which("protoc")
        plugin = shutil.which("grpc_python_plugin")
        if protoc is None or plugin is None:
            raise RuntimeError("protoc and grpc_python_plugin are needed (Debian: protobuf-compiler, "
                               "protobuf-compiler-grpc)")
        out = os.path.abspath(self.build_lib)
        subprocess.run([protoc, f"--proto_path={ROOT}/proto", f"--python_out={out}", f"--grpc_out={out}",
                        f"--plugin=protoc-gen-grpc={plugin}", f"{ROOT}/proto/spokemesh/v1/mesher.proto"], check=True)
        open(os.path.join(out, "spokemesh", "v1", "__init__.py"), "a").close()


class ParallelBuildExt(build_ext):
    """build_ext compiling the core's sources on every core at once."""

    def finalize_options(self):
        super().finalize_options()
        if not self.parallel:
            self.parallel = os.cpu_count() or 1


core = Extension(
    "spokemesh._core",
    sources=[rel(os.path.join(HERE, "src", "core_module.cpp")), rel(f"{ROOT}/clients/cpp/geojson_domain.cpp")]
    + sorted(rel(p) for p in glob.glob(f"{ROOT}/core/src/**/*.cpp", recursive=True)),
    include_dirs=[f"{ROOT}/core/include", f"{ROOT}/core/src", f"{ROOT}/clients/cpp", "/usr/include/eigen3",
                  pybind11.get_include()],
    libraries=["gmpxx", "gmp", "z"],
    extra_compile_args=["-std=c++20", "-O2", "-ffp-contract=off", "-fno-fast-math", "-DNDEBUG", "-fvisibility=hidden"],
    language="c++",
)

os.makedirs(os.path.join(HERE, "spokemesh", "v1"), exist_ok=True)
setup(ext_modules=[core], cmdclass={"build_py": BuildWithStubs, "build_ext": ParallelBuildExt})
