"""Shared test fixtures: where the development meshes and the LPIPS calibration pairs live.

Both live outside the project (../shared); set NVF_ASSETS / NVF_CALIBRATION to point elsewhere.
"""

import os
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
