"""Shared test fixtures: where the development meshes and the LPIPS calibration pairs live.

They are not part of the repository: set NVF_ASSETS to a directory of scene assets and NVF_CALIBRATION
to the LPIPS calibration pairs (README.md); a test that needs one skips, naming the variable, when it is missing.
"""

import os
import runpy
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from pipeline.repo import REPO


def _shared(env: str, relative: str) -> Path:
    return Path(os.environ.get(env, REPO.parent / "shared" / relative)).resolve()


@pytest.fixture(scope="session")
def assets_dir() -> Path:
    path = _shared("NVF_ASSETS", "assets")
    if not (path / "room").is_dir():
        pytest.skip(f"development meshes not found at {path}; set NVF_ASSETS")
    return path


@pytest.fixture(scope="session")
def lpips_calibration_dir() -> Path:
    path = _shared("NVF_CALIBRATION", "calibration/lpips")
    if not (path / "I03_ref.png").is_file():
        pytest.skip(f"LPIPS calibration pairs not found at {path}; set NVF_CALIBRATION")
    return path


@pytest.fixture(autouse=True)
def _deterministic_torch():
    torch.manual_seed(0)
    yield


@pytest.fixture
def command(capsys) -> Callable[[str, list[str]], tuple[int, list[str]]]:
    """``command(module, argv)``: ``python -m <module> <argv>`` run in this process as ``-m`` runs it (``runpy``, so
    through the module's own ``__main__`` block); its exit status and its stderr's non-empty lines."""

    def run(module: str, argv: list[str]) -> tuple[int, list[str]]:
        with pytest.MonkeyPatch.context() as patch, warnings.catch_warnings():
            patch.setattr(sys, "argv", [module, *argv])
            warnings.simplefilter("ignore", RuntimeWarning)  # runpy notes that the module is imported already
            try:
                runpy.run_module(module, run_name="__main__", alter_sys=True)
                status = 0
            except SystemExit as done:
                status = int(done.code or 0)
        return status, [line for line in capsys.readouterr().err.splitlines() if line.strip()]

    return run
