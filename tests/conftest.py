"""Shared test fixtures: where the development meshes and the LPIPS calibration pairs live.

They are not part of the repository: set NVF_ASSETS to a directory of scene assets and NVF_CALIBRATION
to the LPIPS calibration pairs (README.md); a test that needs one skips, naming the variable, when it is missing.
Such a test is marked ``data`` (``pytest -m data`` runs them alone): CI runs the suite once without the variables,
as a newcomer's ``make test`` does, and the ``data`` tests again with them.
"""

import os
import runpy
import sys
import warnings
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

DATA_FIXTURES = ("assets_dir", "lpips_calibration_dir")  # the fixtures of data outside the repository


def _given(env: str) -> Path | None:
    value = os.environ.get(env)
    return Path(value).resolve() if value else None


@pytest.fixture(scope="session")
def assets_dir() -> Path:
    path = _given("NVF_ASSETS")
    if path is None or not (path / "room").is_dir():
        pytest.skip(f"development meshes not found at {path}; set NVF_ASSETS")
    return path


@pytest.fixture(scope="session")
def lpips_calibration_dir() -> Path:
    path = _given("NVF_CALIBRATION")
    if path is None or not (path / "I03_ref.png").is_file():
        pytest.skip(f"LPIPS calibration pairs not found at {path}; set NVF_CALIBRATION")
    return path


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that takes a data fixture (``DATA_FIXTURES``) is marked ``data``."""
    for item in items:
        if any(name in getattr(item, "fixturenames", ()) for name in DATA_FIXTURES):
            item.add_marker(pytest.mark.data)


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
