"""The episode harness end to end (PROTOCOL 3): records, resume after SIGKILL, bad input."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from pipeline.episode.loop import Episode
from pipeline.metrics.image import LpipsMetric
from pipeline.records.store import RunRecord
from pipeline.repo import CONF, REPO
from pipeline.episode.runner import run_episode
from pipeline.scenes.scene import load_scene

SMOKE = ["budget=smoke", "scene=default"]


def _cfg(tmp_path: Path, *overrides: str):
    with initialize_config_dir(str(CONF), version_base="1.3"):
        return compose("config", overrides=[*SMOKE, f"paths.outputs={tmp_path}", *overrides])


def _cli(tmp_path: Path, *overrides: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(
        [sys.executable, "-m", "pipeline.run", *SMOKE, f"paths.outputs={tmp_path}", *overrides],
        cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw,
    )  # fmt: skip


def test_smoke_episode_writes_complete_records(tmp_path):
    directory = run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2"))
    record = RunRecord(directory)
    assert record.is_done()
    rows = record.completed_steps()
    assert [r["step"] for r in rows] == [0, 1]
    assert [r["n_views"] for r in rows] == [3, 4]  # n_init + step (PROTOCOL 3)
    for row in rows:
        assert len(row["selected_pose"]) == 7
        assert set(row["seconds"]) == {"train", "eval", "plan"}
        for metric in ("psnr", "ssim", "rgb", "vis", "cr"):
            assert isinstance(row["metrics"][metric], float)
    info = json.loads((directory / "run.json").read_text())
    assert info["budget"] == "smoke" and info["field"] in ("hashgrid", "densegrid")
    assert info["git"]["commit"] is None or len(info["git"]["commit"]) == 40
    assert (directory / "images" / "step_01_pred.png").is_file()
    # a finished run is skipped, not re-run; one finished with other settings is refused, untouched
    assert run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2")) == directory
    assert len(RunRecord(directory).completed_steps()) == 2
    before = (directory / "run.json").read_text()
    changed = r"finished with a different config.planner.num_candidates \(8 in the record, 9 now\)"
    with pytest.raises(ValueError, match=changed):
        run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2", "planner.num_candidates=9"))
    assert (directory / "run.json").read_text() == before and RunRecord(directory).is_done()



def test_an_episode_with_a_scorer_saves_its_score_map(tmp_path):
    directory = run_episode(_cfg(tmp_path, "method=wd", "budget.horizon=1", "train.backbone.iters=2"))
    assert RunRecord(directory).is_done()
    assert {"step_00_pred.png", "step_00_score.png"} <= {p.name for p in (directory / "images").iterdir()}


@pytest.mark.slow
def test_sigkill_mid_step_resumes_with_the_same_poses(tmp_path):
    """A run killed mid-step resumes at its last complete step and selects the same poses."""
    reference = _cli(tmp_path / "a", "method=nvf")
    assert reference.wait(timeout=900) == 0, reference.stderr.read()
    killed = _cli(tmp_path / "b", "method=nvf")
    steps = None
    deadline = time.time() + 900
    while time.time() < deadline:
        steps = next((tmp_path / "b").glob("*/*/*/seed_*/steps.jsonl"), None)
        if steps is not None and steps.read_text().count("\n") >= 1:
            break
        time.sleep(0.2)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    partial = RunRecord(steps.parent).completed_steps()
    assert 1 <= len(partial) < 3 and not RunRecord(steps.parent).is_done()
    resumed = _cli(tmp_path / "b", "method=nvf")
    out, err = resumed.communicate(timeout=900)
    assert resumed.returncode == 0, err
    assert "resuming" in out
    a = RunRecord(next((tmp_path / "a").glob("*/*/*/seed_*"))).completed_steps()
    b = RunRecord(steps.parent).completed_steps()
    np.testing.assert_allclose([r["selected_pose"] for r in a], [r["selected_pose"] for r in b], atol=1e-6)


def test_missing_mesh_is_one_line_and_nonzero(tmp_path):
    proc = _cli(tmp_path, "scene=lego", f"paths.assets={tmp_path / 'nowhere'}")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode != 0
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "lego" in lines[0] and "Traceback" not in err
    assert not any(tmp_path.glob("lego/*/*/seed_*/steps.jsonl"))


@pytest.mark.parametrize(
    ("override", "expected"),
    [
        ("scene=atlantis", ("atlantis", "lego_proxy")),
        ("train.backbone.iters=many", ("train.backbone.iters", "Integer")),
    ],
)
def test_a_config_hydra_cannot_compose_is_one_line(tmp_path, override, expected):
    """An unknown group option (with Hydra's list of the available ones) or a value of the wrong type."""
    proc = _cli(tmp_path, override)
    _, err = proc.communicate(timeout=300)
    lines = [line for line in err.splitlines() if line.strip()]
    assert proc.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(word in lines[0] for word in expected) and "search path" not in lines[0]
    assert not any(tmp_path.iterdir())


def test_impossible_value_names_the_key(tmp_path):
    proc = _cli(tmp_path, "planner.num_candidates=-3")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode != 0
    assert "planner.num_candidates" in err and "Traceback" not in err


@pytest.mark.parametrize("samples", [1, 2])
def test_ground_truth_has_budget_gt_samples_per_pixel(tmp_path, samples):
    """Training images (RGBA) and evaluation views are the mean of ``budget.gt_samples^2`` sub-pixel
    samples; with 1, the pixel-centre render every committed record was made with."""
    cfg = _cfg(tmp_path, f"budget.gt_samples={samples}")
    scene = load_scene("default", Path(cfg.paths.assets))
    with pytest.warns(UserWarning, match="LPIPS will be reported as missing"):
        lpips = LpipsMetric(sources=[])
    episode = Episode(cfg, scene, torch.device("cpu"), lpips)
    images = episode.observations().images.numpy()
    renderer, intr = episode.renderer, episode.intrinsics
    want = np.stack([renderer.render_rgba(c2w, intr, samples) for c2w in scene.init_poses])
    np.testing.assert_array_equal(images, want)
    eval_gt = renderer.render_rgba(scene.eval_poses[0], episode.evaluator.intrinsics, samples)[..., :3]
    np.testing.assert_array_equal(episode.evaluator.gt[0], eval_gt)
    centre = [renderer.render(c2w, intr) for c2w in scene.init_poses]
    at_centres = np.stack([np.concatenate([v.rgb, v.mask[..., None].astype(np.float32)], -1) for v in centre])
    assert np.array_equal(images, at_centres) == (samples == 1)  # supersampling changes the edge pixels
    assert all(np.array_equal(ids, v.face_id) for ids, v in zip(episode.face_ids, centre, strict=True))  # Vis.
