"""pipeline/records/store.py: run directories, atomic run.json / steps.jsonl, resume, DONE and FAILED markers."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from nvf.cameras import Intrinsics
from pipeline.records.store import RunRecord, check_key, read_steps, run_dir, to_jsonable
from pipeline.repo import REPO


def _info(**overrides) -> dict:
    info = {
        "scene": "lego_proxy",
        "scene_source": "proxy",
        "method": "nvf",
        "planner": "argmax",
        "ablation": "none",
        "budget": "smoke",
        "seed": 100,
        "field": "densegrid",
        "device": "cpu",
        "config": {"train": {"iters": 10}, "seed": 100},
        "lpips_missing_reason": None,
    }
    return {**info, **overrides}


def _row(step: int, psnr: float = 20.0) -> dict:
    return {"step": step, "n_views": 3 + step, "status": "ok", "metrics": {"psnr": psnr, "lpips": None}}


def _started(tmp_path: Path) -> RunRecord:
    record = RunRecord(run_dir(tmp_path, "lego_proxy", "nvf", "argmax", "none", "smoke", 100))
    record.start(_info(), repo=tmp_path)
    return record


def test_run_dir_layout_is_readable(tmp_path):
    path = run_dir(tmp_path, "lego_proxy", "nvf", "opt", "wo_vis", "cpu", 101)
    assert path == tmp_path / "lego_proxy" / "nvf-opt-wo_vis" / "cpu" / "seed_101"


@pytest.mark.parametrize("bad", ["../x", "a/b", "", ".", "..", "a b", "x\\y", "/abs"])
def test_run_dir_rejects_path_traversal(tmp_path, bad):
    with pytest.raises(ValueError, match="not a plain name"):
        run_dir(tmp_path, bad, "nvf", "argmax", "none", "cpu", 100)
    with pytest.raises(ValueError, match="not a plain name"):
        run_dir(tmp_path, "lego", "nvf", "argmax", "none", bad, 100)


def test_run_dir_rejects_ambiguous_group_and_negative_seed(tmp_path):
    with pytest.raises(ValueError, match="must not contain '-'"):
        run_dir(tmp_path, "lego", "nvf-x", "argmax", "none", "cpu", 100)
    with pytest.raises(ValueError, match="non-negative"):
        run_dir(tmp_path, "lego", "nvf", "argmax", "none", "cpu", -1)
    assert check_key("scene", "room.v2") == "room.v2"


def test_to_jsonable_converts_numpy_torch_and_nan():
    value = {"a": np.float32(1.5), "b": np.int64(3), "c": torch.tensor(2.0), "d": math.nan}
    value |= {"e": np.array([1.0, np.inf]), "f": (True, None)}
    assert to_jsonable(value) == {"a": 1.5, "b": 3, "c": 2.0, "d": None, "e": [1.0, None], "f": [True, None]}
    with pytest.raises(TypeError, match="cannot record"):
        to_jsonable({"x": object()})


def test_to_jsonable_accepts_configs():
    config = OmegaConf.create({"train": {"iters": 5, "lrs": [0.1, 0.2]}, "path": "${train.iters}"})
    assert to_jsonable(config) == {"train": {"iters": 5, "lrs": [0.1, 0.2]}, "path": 5}
    assert to_jsonable(Intrinsics(4, 2, 2.0)) == {"width": 4, "height": 2, "focal": 2.0}


def test_start_writes_provenance(tmp_path):
    record = _started(tmp_path)
    info = json.loads(record.run_json.read_text())
    assert info["seed"] == 100 and info["budget"] == "smoke" and info["field"] == "densegrid"
    assert info["git"] == {"commit": None, "dirty": None}  # tmp_path is not a git checkout
    assert info["versions"]["numpy"] == np.__version__ and "pyrender" in info["versions"]
    assert "psnr" in info["metric_definitions"]
    assert info["status"] == "running" and info["timings"]["ended"] is None
    assert [p.name for p in record.directory.iterdir()] == ["run.json"]  # no temp files left


def test_start_records_git_commit_of_the_project(tmp_path):
    record = RunRecord(tmp_path / "run")
    record.start(_info(), repo=REPO)
    git = record.info()["git"]
    if git["commit"] is None:
        pytest.skip("the project is not a git checkout here")
    assert re.fullmatch(r"[0-9a-f]{40}", git["commit"]) and isinstance(git["dirty"], bool)


def test_resume_keeps_start_time_and_refuses_other_config(tmp_path):
    record = _started(tmp_path)
    first = record.info()["timings"]["started"]
    (record.directory / ".steps.jsonl.abc.tmp").write_text('{"step": 0')  # left by a kill
    record.start(_info(), repo=tmp_path)
    assert not list(record.directory.glob(".*.tmp"))
    timings = record.info()["timings"]
    assert timings["started"] == first and len(timings["resumed"]) == 1
    with pytest.raises(ValueError, match=r"different config.train.iters \(10 in the record, 11 now\)"):
        record.start(_info(config={"train": {"iters": 11}, "seed": 100}), repo=tmp_path)
    with pytest.raises(ValueError, match="different budget"):
        record.start(_info(budget="cpu"), repo=tmp_path)
    moved = {"train": {"iters": 10}, "seed": 100, "paths": {"assets": "/elsewhere"}}
    record.start(_info(config=moved), repo=tmp_path)  # paths only say where files live
    assert "paths" not in record.info()["config"]  # and are not recorded: records are machine-independent
    with pytest.raises(ValueError, match="lacks config"):
        record.start({k: v for k, v in _info().items() if k != "config"}, repo=tmp_path)


def test_steps_round_trip_with_null_for_nan(tmp_path):
    record = _started(tmp_path)
    record.append_step(_row(0, psnr=np.float64(18.5)))
    record.append_step({**_row(1), "metrics": {"psnr": math.nan}, "extra": np.arange(2)})
    rows = record.completed_steps()
    assert [r["step"] for r in rows] == [0, 1]
    assert rows[0]["metrics"] == {"psnr": 18.5, "lpips": None}
    assert rows[1]["metrics"]["psnr"] is None and rows[1]["extra"] == [0, 1]
    assert "NaN" not in record.steps_path.read_text()
    with pytest.raises(ValueError, match="already recorded"):
        record.append_step(_row(1))
    with pytest.raises(ValueError, match="integer 'step'"):
        record.append_step({"step": "2"})


def test_truncated_trailing_line_is_dropped_rewritten_and_reported(tmp_path):
    record = _started(tmp_path)
    record.append_step(_row(0))
    record.append_step(_row(1))
    with record.steps_path.open("a") as f:
        f.write('{"step": 2, "n_views": 5, "metr')  # killed mid-write
    assert len(read_steps(record.steps_path)[0]) == 2  # read-only view ignores it
    with pytest.warns(RuntimeWarning, match="truncated last line.*restarting from step 2"):
        rows = record.completed_steps()
    assert [r["step"] for r in rows] == [0, 1]
    assert record.steps_path.read_text().count("\n") == 2 and record.steps_path.read_text().endswith("\n")
    record.append_step(_row(2))
    assert [r["step"] for r in record.completed_steps()] == [0, 1, 2]


def test_corrupt_complete_last_line_is_dropped(tmp_path):
    record = _started(tmp_path)
    record.append_step(_row(0))
    with record.steps_path.open("a") as f:
        f.write('{"n_views": 4}\n')  # valid JSON but not a step row
    with pytest.warns(RuntimeWarning, match="corrupt last line"):
        assert len(record.completed_steps()) == 1


def test_corrupt_middle_line_is_an_error(tmp_path):
    record = _started(tmp_path)
    record.steps_path.write_text('{"step": 0}\n{oops\n{"step": 2}\n')
    with pytest.raises(ValueError, match="line 2 is corrupt"):
        record.completed_steps()


def test_done_marker(tmp_path):
    record = _started(tmp_path)
    record.append_step(_row(0))
    assert not record.is_done()
    record.mark_done()
    assert record.is_done() and (record.directory / "DONE").is_file()
    info = record.info()
    assert info["status"] == "done" and info["timings"]["ended"] is not None
    (record.directory / "DONE").unlink()  # a committed copy holds run.json + steps.jsonl only
    assert record.is_done()
    with pytest.raises(ValueError, match="already done"):
        record.start(_info(), repo=tmp_path)


def test_failed_record(tmp_path):
    record = _started(tmp_path)
    assert record.failure() is None
    record.mark_failed("step 3: training diverged (NaN loss)")
    assert record.status() == "failed" and not record.is_done()
    assert record.failure() == "step 3: training diverged (NaN loss)"
    assert (record.directory / "FAILED").read_text().strip() == "step 3: training diverged (NaN loss)"


def test_finish_before_start_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="call start"):
        RunRecord(tmp_path / "x").mark_done()
