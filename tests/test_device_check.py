"""scripts/device_check.sh: its ``--dry`` run on this CPU at smoke sizes (slow: every step of the GPU check,
a few minutes on two cores) writes its flat JSON files and passes; bad arguments are one line and exit 2."""

import json
import os
import subprocess
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "device_check.sh"
FILES = ["cuda_tests.json", "device.json", "field.json", "paper_shape.json", "plan.json", "summary.json", "train.json"]


def run(*args: str, timeout: float = 60, **env: str) -> subprocess.CompletedProcess:
    base = {key: value for key, value in os.environ.items() if key != "NVF_ASSETS"}  # Room's step only on a GPU
    return subprocess.run(
        [str(SCRIPT), *args], capture_output=True, text=True, timeout=timeout, env=base | env, cwd=REPO
    )


@pytest.mark.parametrize(("args", "needle"), [((), "--out DIR is missing"), (("--out",), "--out DIR is missing")])
def test_bad_arguments_are_one_line(args, needle):
    result = run(*args)
    assert result.returncode == 2 and result.stderr.startswith("error: ") and needle in result.stderr
    assert result.stderr.count("\n") == 1


def test_an_unknown_argument_is_one_line(tmp_path):
    result = run("--dry", "--fast", "--out", str(tmp_path))
    assert result.returncode == 2 and result.stderr.strip() == (
        "error: unknown argument '--fast'; usage: scripts/device_check.sh [--dry] [--force] --out DIR"
    )
    assert not any(tmp_path.iterdir())


def test_a_folder_holding_reports_is_refused_without_force(tmp_path):
    (tmp_path / "device.json").write_text("{}")
    result = run("--dry", "--out", str(tmp_path))
    assert result.returncode == 2 and "already holds reports (device.json); pass --force" in result.stderr
    assert result.stderr.count("\n") == 1 and (tmp_path / "device.json").read_text() == "{}"


@pytest.mark.slow
def test_dry_run_passes_and_writes_its_reports(tmp_path):
    """The dry check passes, Room's step recorded as skipped where its asset is a .blend and Blender is missing;
    a second run into the same folder needs --force."""
    out = tmp_path / "check"
    assets = tmp_path / "assets" / "room"
    assets.mkdir(parents=True)
    (assets / "room.blend").write_bytes(b"")
    result = run(
        "--dry", "--out", str(out), timeout=900, NVF_ASSETS=str(assets.parent), NVF_BLENDER_PYTHON="/nonexistent"
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]
    assert sorted(path.name for path in out.iterdir()) == FILES and all(path.is_file() for path in out.iterdir())
    summary = json.loads((out / "summary.json").read_text())
    assert summary["passed"] is True and summary["mode"] == "dry: CPU, smoke sizes"
    assert [row["step"] for row in summary["steps"]] == [
        "device",
        "cuda_tests",
        "paper_shape",
        "paper_shape_room",
        "field",
        "train",
        "plan",
    ]
    room = summary["steps"][3]
    assert room["exit_status"] == 0 and "room.blend" in room["skipped"] and "make blender" in room["skipped"]
    tests = json.loads((out / "cuda_tests.json").read_text())
    outcome = "passed" if torch.cuda.is_available() else "skipped"
    assert tests["tests"] and all(test["outcome"] == outcome for test in tests["tests"])
    shape = json.loads((out / "paper_shape.json").read_text())
    assert shape["budget"] == "smoke" and len(shape["stages"]) == 9 and shape["problems"] == {"default": []}
    assert json.loads((out / "device.json").read_text())["device_auto"] == (
        "cuda" if torch.cuda.is_available() else "cpu"
    )
