"""Builds sim2real's two optional C extensions (everything else is in pyproject.toml).

``noise_models._hot`` and ``sim2real.wrappers._hotstep`` run the single-env hot step of the fused wrapper layer in C
(see ``noise_models.compiled``). They are optional: where no C compiler, Python headers or numpy are found at build
time, the install goes on without them and the same steps run in Python (bitwise the same results, slower).
"""

from __future__ import annotations

from setuptools import Extension, setup


def _extensions() -> list[Extension]:
    try:
        import numpy
    except ImportError:  # built without numpy (an isolated build without it): the Python path only
        return []
    # No FMA contraction or fast-math: the adds and clips must round as numpy's loops do (bitwise the same steps).
    flags = ["-O2", "-ffp-contract=off", "-fno-fast-math", "-std=c11"]
    include = [numpy.get_include()]
    return [
        Extension(
            "noise_models._hot", ["noise_models/_hot.c"], include_dirs=include, extra_compile_args=flags, optional=True
        ),
        Extension(
            "sim2real.wrappers._hotstep",
            ["sim2real/wrappers/_hotstep.c"],
            include_dirs=include,
            extra_compile_args=flags,
            optional=True,
        ),
    ]


setup(ext_modules=_extensions())
