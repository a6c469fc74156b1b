"""The C++/OpenMP kernels of ``nvf/csrc``, compiled on first use with ``torch.utils.cpp_extension`` into the
user's cache (a compiler and the ``ninja`` package are needed); ``None`` where one cannot be built, and its
caller then runs its torch path, which computes the same values.

- ``hashgrid()``: the hash-grid gather, scatter and point gradient (``nvf.encoding``), with AVX2/FMA where
  the CPU has them (results differ from the torch path by rounding only).
- ``labels()``: the samples of visibility labels that can have density (``nvf.visibility``), compiled
  without fused multiply-adds so that its samples are bitwise the torch path's.
"""

import functools
import hashlib
import logging
import os
import sys
import warnings
from pathlib import Path
from types import ModuleType

import torch

CSRC = Path(__file__).resolve().parent / "csrc"


def hashgrid_flags() -> list[str]:
    """``-O3 -fopenmp`` (without it ``at::parallel_for`` runs serially), ``-fno-trapping-math`` (lets gcc
    vectorise the clamp and floor of the cell lookup; no value changes, the kernel reads no FP exception
    flags), plus AVX2/FMA where the CPU has them (1.3x on the gather; results differ by rounding only)."""
    simd = torch.backends.cpu.get_cpu_capability() in ("AVX2", "AVX512")
    base = ["-O3", "-fopenmp", "-fno-trapping-math"]
    return [*base, "-mavx2", "-mfma"] if simd else base


LABEL_FLAGS = ["-O3", "-fopenmp", "-ffp-contract=off"]  # no fused multiply-add: the torch path's rounding


def _build_dir(name: str, source: Path, cflags: list[str]) -> Path:
    """Per kernel, torch, Python, flags and source (path and content): two checkouts never rebuild each other's
    kernel (ninja rebuilds whenever the recorded source path changes)."""
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    flags = "".join(flag.lstrip("-") for flag in cflags)
    digest = hashlib.sha256(str(source).encode() + source.read_bytes()).hexdigest()[:12]
    tag = f"torch{torch.__version__}-py{sys.version_info.major}{sys.version_info.minor}-{flags}-{digest}".replace(
        "+", "_"
    )
    path = cache / "nvf-bench" / "torch_extensions" / f"{name}-{tag}"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _quiet_import_load():
    """``torch.utils.cpp_extension.load``, imported without its warning that a CUDA toolkit was found but no
    CUDA runtime (true on a CPU machine with nvcc, and irrelevant to a CPU kernel)."""
    logger = logging.getLogger("torch.utils.cpp_extension")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        from torch.utils.cpp_extension import load
    finally:
        logger.setLevel(level)
    return load


def _build(name: str, source: Path, cflags: list[str]) -> ModuleType | None:
    """Kernel ``name`` compiled from ``source``; ``None`` (with a warning) if it cannot be built."""
    try:
        return _quiet_import_load()(
            name=f"nvf_{name}",
            sources=[str(source)],
            extra_cflags=cflags,
            extra_ldflags=["-fopenmp"],
            build_directory=str(_build_dir(name, source, cflags)),
            verbose=False,
        )
    except Exception as error:  # any build failure (no compiler, no ninja, ...) means fallback
        warnings.warn(
            f"nvf: {name} C++ kernel unavailable ({type(error).__name__}: {error}); using torch", stacklevel=3
        )
        return None


@functools.cache
def hashgrid() -> ModuleType | None:
    """The hash-grid kernels (``csrc/hashgrid.cpp``), built once per process."""
    return _build("hashgrid", CSRC / "hashgrid.cpp", hashgrid_flags())


@functools.cache
def labels() -> ModuleType | None:
    """The label-sample kernel (``csrc/labels.cpp``), built once per process."""
    return _build("labels", CSRC / "labels.cpp", LABEL_FLAGS)
