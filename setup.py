"""Builds the native CPU kernels (stereojax/_native*.so) beside the pure-Python package.

Everything else about the package is in pyproject.toml. The kernels are C++17 with a plain C
ABI (XLA FFI handlers, loaded with ctypes by stereojax/kernels.py), compiled against the XLA FFI
headers that ship with jaxlib. STEREOJAX_MARCH_NATIVE=1 tunes the build to this machine's CPU
(otherwise: the baseline of the target, with AVX2 and AVX-512 clones picked at run time on
x86-64). STEREOJAX_SKIP_NATIVE=1 builds no extension (the chain then runs its JAX kernels).
"""

import os
import platform

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

SOURCES = [
    "stereojax/optimization/semi_global.cc",
    "stereojax/aggregation/cross_based.cc",
    "stereojax/matching_cost/census.cc",
    "stereojax/disparity/right_view.cc",
    "stereojax/validation/filling.cc",
    "stereojax/matching_cost/ranking.cc",
    "stereojax/volume.cc",
    "stereojax/disparity/winner_takes_all.cc",
    "stereojax/validation/confidence_measure.cc",
    "stereojax/filters/median.cc",
    "stereojax/matching_cost/head.cc",
]


def _ffi_include() -> str:
    import jaxlib  # a build requirement (pyproject.toml), for its XLA FFI headers

    return os.path.join(os.path.dirname(jaxlib.__file__), "include")


class BuildNative(build_ext):
    """A shared library with no Python module init: the include path is found at build time."""

    def build_extensions(self):
        for ext in self.extensions:
            ext.include_dirs.append(_ffi_include())
        super().build_extensions()

    def get_export_symbols(self, ext):
        return []


flags = ["-std=c++17", "-O3", "-fvisibility=hidden", "-pthread",
         # min reductions and selects vectorise; no reassociation, so sums keep the JAX order
         "-fno-math-errno", "-ffinite-math-only", "-fno-signed-zeros", "-fno-trapping-math"]
if os.environ.get("STEREOJAX_MARCH_NATIVE") == "1":
    flags += ["-march=native", "-DSTEREOJAX_MARCH_NATIVE"]

ext_modules = []
if os.environ.get("STEREOJAX_SKIP_NATIVE") != "1" and platform.system() != "Windows":
    ext_modules = [Extension("stereojax._native", sources=SOURCES, depends=["stereojax/native_common.h"],
                             language="c++", extra_compile_args=flags, extra_link_args=["-pthread"])]

setup(ext_modules=ext_modules, cmdclass={"build_ext": BuildNative})
