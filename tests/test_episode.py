"""The episode harness end to end (PROTOCOL 3): records, resume after SIGKILL, bad input."""

import dataclasses
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from pipeline.config.structured_configs import register_configs
from pipeline.config.typed_run import Run
from pipeline.config.validation import ConfigError, validate
from pipeline.episode.loop import Episode
from pipeline.episode.runner import Outcome, RunRefused, StepFailed, run_episode, run_settings, torch_threads
from pipeline.episode.settings import EpisodeSettings
from pipeline.metrics.image import LpipsMetric
from pipeline.records.lock import RunLock
from pipeline.records.schema import RECORD_VERSION, RunStart, StepRow
from pipeline.records.store import RecordError, RunRecord
from pipeline.records.verify import verified
from pipeline.repo import CONF, REPO
from pipeline.scenes.loading import load_scene
from pipeline.tables.summary import finish_run
from pipeline.tables.trajectory import outline_of_scene

SMOKE = ["budget=smoke", "scene=default"]


def _cfg(tmp_path: Path, *overrides: str) -> Run:
    register_configs()
    with initialize_config_dir(str(CONF), version_base="1.3"):
        return validate(compose("config", overrides=[*SMOKE, f"paths.outputs={tmp_path}", *overrides]))


def _cli(tmp_path: Path, *overrides: str, **kw) -> subprocess.Popen:
    """``python -m pipeline.run`` at the smoke budget; ``-m`` among ``overrides`` makes it a sweep."""
    env = kw.pop("env", {**os.environ, "OMP_NUM_THREADS": "1"})
    flags = [arg for arg in overrides if arg == "-m"]
    overrides = tuple(arg for arg in overrides if arg != "-m")
    return subprocess.Popen(
        [sys.executable, "-m", "pipeline.run", *flags, *SMOKE, f"paths.outputs={tmp_path}", *overrides],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def assert_metrics_in_range(metrics: dict) -> None:
    """Every metric of a step row finite and within its range (NaN fails: ``isinstance(x, float)`` did not).
    PSNR of [0, 1] images lies in (0, 100) here; SSIM in [-1, 1]; RGB (MSE) in [0, 1]; Vis., C.R. and
    LPIPS in [0, 1]; Acc. and Comp. (distances) >= 0."""
    bounds = {
        "psnr": (0.0, 100.0),
        "ssim": (-1.0, 1.0),
        "rgb": (0.0, 1.0),
        "vis": (0.0, 1.0),
        "cr": (0.0, 1.0),
        "acc": (0.0, math.inf),
        "comp": (0.0, math.inf),
        "lpips": (0.0, 1.0),
    }
    for metric, (low, high) in bounds.items():
        value = metrics[metric]
        if metric == "lpips" and value is None:
            continue  # recorded as missing, with the reason in run.json
        assert isinstance(value, float) and math.isfinite(value) and low <= value <= high, (metric, value)
    assert metrics["psnr"] > 5.0  # a flat grey image scores about 6 dB on the default scene


def test_smoke_episode_writes_complete_records(tmp_path):
    outcome = run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2"))
    directory = outcome.directory
    assert outcome.status == "done"
    record = RunRecord(directory)
    assert record.is_done()
    rows = record.completed_steps()
    assert [r["step"] for r in rows] == [0, 1]
    assert [r["n_views"] for r in rows] == [3, 4]  # n_init + step (PROTOCOL 3)
    for row in rows:
        assert len(row["selected_pose"]) == 7 and all(math.isfinite(v) for v in row["selected_pose"])
        assert set(row["seconds"]) == {"train", "eval", "plan"} and all(v > 0 for v in row["seconds"].values())
        assert_metrics_in_range(row["metrics"])
    info = json.loads((directory / "run.json").read_text())
    assert info["budget"] == "smoke" and info["field"] in ("hashgrid", "densegrid")
    assert info["git"]["commit"] is None or len(info["git"]["commit"]) == 40
    assert info["collision_free"] is False and info["record_digest"].startswith("sha256:")
    assert info["record_version"] == RECORD_VERSION  # the schema's keys in its order, the store's after them
    start, columns = ([field.name for field in dataclasses.fields(c)] for c in (RunStart, StepRow))
    assert list(info)[: len(start)] == start and all(list(row) == columns[: len(row)] for row in rows)
    assert verified(record)[1] == rows
    assert (directory / "images" / "step_01_pred.png").is_file()
    # the run's own labelled pictures and table, beside its records (drawn by the entry point, pipeline.run)
    finish_run(directory, outline_of_scene(outcome.scene, outcome.scene_kind))
    assert all(
        (directory / name).stat().st_size > 0 for name in ("grid.png", "psnr.png", "trajectory.png", "summary.md")
    )
    assert RunLock(directory, tmp_path).path.read_text() == ""  # released
    # a finished run is skipped, not re-run; one finished with other settings is refused, untouched
    assert run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2")) == Outcome(directory, "skipped")
    assert len(RunRecord(directory).completed_steps()) == 2
    before = (directory / "run.json").read_text()
    changed = r"finished with a different config.planner.num_candidates \(8 in the record, 9 now\)"
    with pytest.raises(RunRefused, match=changed):
        run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2", "planner.num_candidates=9"))
    assert (directory / "run.json").read_text() == before and RunRecord(directory).is_done()
    # a finished record that lost its last row is not skipped as finished: one line, nothing run
    steps = (directory / "steps.jsonl").read_text().splitlines(keepends=True)
    (directory / "steps.jsonl").write_text(steps[0])
    with pytest.raises(RecordError, match=r"steps.jsonl: 1 rows, but the run is marked done with a horizon of 2"):
        run_episode(_cfg(tmp_path, "method=random", "budget.horizon=2"))


def test_psnr_only_steps_and_label_visibility_keep_the_run_and_its_views(tmp_path):
    """``step_metrics=psnr``: steps before the last record PSNR alone, the last one every metric, with the same
    views and PSNRs as a run recording everything: not another run (the second is skipped as finished).
    ``nvf.entropy.visibility_source=labels`` plans with the labels at the scored samples (METHOD 9.3) and
    records that setting; candidates tied at the maximum are counted in every row."""
    full = run_episode(_cfg(tmp_path / "a", "budget.horizon=2"))
    brief = run_episode(_cfg(tmp_path / "b", "budget.horizon=2", "step_metrics=psnr"))
    rows_full, rows_brief = (RunRecord(o.directory).completed_steps() for o in (full, brief))
    assert [r["selected_pose"] for r in rows_full] == [r["selected_pose"] for r in rows_brief]
    assert [r["metrics"]["psnr"] for r in rows_full] == [r["metrics"]["psnr"] for r in rows_brief]
    assert rows_brief[0]["metrics"]["ssim"] is None and rows_brief[0]["metrics"]["vis"] is None
    assert_metrics_in_range(rows_brief[-1]["metrics"])
    assert run_episode(_cfg(tmp_path / "b", "budget.horizon=2")).status == "skipped"
    assert all(r["candidate_scores"]["ties_at_max"] >= 1 for r in rows_full)
    labels = run_episode(_cfg(tmp_path / "c", "budget.horizon=1", "nvf.entropy.visibility_source=labels"))
    info = json.loads((labels.directory / "run.json").read_text())
    assert labels.status == "done" and info["config"]["nvf"]["entropy"]["visibility_source"] == "labels"


def test_a_collapsed_run_is_recorded_as_failed_and_a_rerun_repeats_the_reason(tmp_path):
    """``train.backbone.lr=1e3`` collapses stage 1 (loss 0.009 -> ~0.1): the run is recorded as failed
    (it used to be recorded as done, PSNR 7.2); a rerun repeats the reason (one line, exit 1)."""
    overrides = ("method=random", "budget.horizon=1", "train.backbone.lr=1e3")
    with pytest.raises(StepFailed, match=r"^step 0: backbone stage collapsed at iteration 4: ") as err:
        run_episode(_cfg(tmp_path, *overrides))
    directory = next(tmp_path.glob("default/*/smoke/seed_100"))
    record = RunRecord(directory)
    assert record.status() == "failed" and record.failure() == str(err.value)
    assert (directory / "FAILED").read_text() == f"{err.value}\n" and not (directory / "steps.jsonl").exists()
    proc = _cli(tmp_path, *overrides)
    _, stderr = proc.communicate(timeout=600)
    lines = [line for line in stderr.splitlines() if line.strip() and "cpp_extension" not in line]
    assert proc.returncode == 1 and lines == [f"error: run {directory} failed: {err.value} (delete it to run it again)"]


def test_a_second_writer_of_a_run_is_one_line_and_exit_2(tmp_path):
    """Two processes on one run directory: the second names the holder and leaves the record alone."""
    directory = tmp_path / "default" / "random-argmax-none" / "smoke" / "seed_100"
    with RunLock(directory, root=tmp_path) as lock:
        directory.mkdir(parents=True)
        (directory / "run.json").write_text("{}")  # what a live writer may have half done: untouched
        proc = _cli(tmp_path, "method=random", "budget.horizon=1")
        _, stderr = proc.communicate(timeout=600)
        holder = lock.path.read_text().strip()
    lines = [line for line in stderr.splitlines() if line.strip() and "cpp_extension" not in line]
    assert proc.returncode == 2 and len(lines) == 1, stderr
    assert lines[0].startswith(f"error: run {directory} is being written by {holder}")
    assert (directory / "run.json").read_text() == "{}"


def test_a_bad_seed_is_one_line_alone_and_inside_a_sweep(tmp_path):
    """``seed=-1`` was a ValueError traceback from records/store.py (also inside sweeps), and
    ``seed=99999999999999999999`` an overflow in torch. Alone: one ``error:`` line, exit 2; in a sweep, each job
    fails with that line as its reason, no traceback."""
    proc = _cli(tmp_path, "seed=-1")
    _, err = proc.communicate(timeout=300)
    lines = [line for line in err.splitlines() if line.strip() and "cpp_extension" not in line]
    assert proc.returncode == 2 and lines == ["error: seed -1 is not an integer from 0 to 2^63-1"], err
    proc = _cli(tmp_path, "-m", "seed=-1,99999999999999999999")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 1 and "Traceback" not in err
    lines = _sweep_lines(out + err)
    assert lines[0] == "sweep: 2 jobs: 0 done, 0 skipped, 2 failed"
    assert lines[2].endswith("): seed 99999999999999999999 is not an integer from 0 to 2^63-1")
    assert not any(p.name != ".hydra" for p in tmp_path.iterdir())  # nothing of a run written


def test_a_malformed_record_is_refused_before_any_work(tmp_path):
    """Rows left without their run.json are never adopted by a new run (they could be another run's)."""
    directory = tmp_path / "default" / "random-argmax-none" / "smoke" / "seed_100"
    directory.mkdir(parents=True)
    (directory / "steps.jsonl").write_text('{"step": 0, "status": "ok"}\n')
    with pytest.raises(RecordError, match=r"seed_100: steps.jsonl without run.json, so the settings .* unknown"):
        run_episode(_cfg(tmp_path, "method=random", "budget.horizon=1"))
    assert sorted(p.name for p in directory.iterdir()) == ["steps.jsonl"]


@pytest.mark.parametrize(
    ("pose", "problem"),
    [
        ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "a quaternion of norm 0"),
        ([0.0, 0.0, 0.0, 1.0, 1e308, 0.0, 1.0], "at (1e+308, 0, 1), not within the scene's camera box"),
    ],
    ids=["zero_quaternion", "translation_1e308"],
)
def test_resuming_a_row_with_an_impossible_pose_is_one_line(tmp_path, pose, problem):
    """Resuming an unfinished record whose step row held a zero quaternion or a 1e308 translation
    was a traceback. Now the record is refused before any work, naming the file, the step and the pose."""
    cfg = _cfg(tmp_path, "method=random", "budget.horizon=2")
    directory = tmp_path / "default" / "random-argmax-none" / "smoke" / "seed_100"
    record = RunRecord(directory)
    record.start(run_settings(cfg))
    record.append_step({"step": 0, "n_views": 3, "status": "ok", "metrics": {"psnr": 10.0}, "selected_pose": pose})
    with pytest.raises(RecordError, match=rf"steps.jsonl: step 0 has selected_pose .*{re.escape(problem)}"):
        run_episode(cfg)
    assert sorted(p.name for p in directory.iterdir()) == ["run.json", "steps.jsonl"]


def test_a_finished_run_skipped_without_its_pictures_draws_them(tmp_path):
    """A run killed right after its DONE marker was skipped on the next run, which printed the
    paths of grid.png, psnr.png, trajectory.png and summary.md, never drawn. Now the skipped run draws what it lacks
    (the code a finishing run draws them with) and prints only files that are there."""
    cfg = _cfg(tmp_path, "method=random", "budget.horizon=2")
    record = RunRecord(tmp_path / "default" / "random-argmax-none" / "smoke" / "seed_100")
    record.start(run_settings(cfg))
    for step in range(2):
        pose = [0.0, 0.0, 0.0, 1.0, 1.0, -1.0, 1.0 + step / 4]
        row = {"step": step, "n_views": 3 + step, "status": "ok", "metrics": {"psnr": 12.0 + step}}
        record.append_step({**row, "selected_pose": pose, "seconds": {"train": 1.0}})
    record.mark_done()
    proc = _cli(tmp_path, "method=random", "budget.horizon=2")
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 0 and f"skipping finished run {record.directory}" in out, err
    drawn = ("psnr.png", "trajectory.png", "summary.md")  # no grid.png: the record saved no images
    assert all((record.directory / name).stat().st_size > 0 for name in drawn)
    printed = re.findall(r"^\w+: +(\S+)", out, flags=re.MULTILINE)
    assert printed and all(Path(path).is_file() for path in printed) and "grid.png" not in out


def _sweep_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith(("sweep: ", "failed: job "))]


# random trains the backbone only; NVF's visibility head at lr 1e3 collapses (BCE 0.69 -> ~1e23)
SWEEP = ("-m", "method=random,nvf", "budget.horizon=1", "train.visibility.lr=1e3")


def _check_sweep(tmp_path: Path, proc: subprocess.Popen) -> None:
    """Job 0 (random) finishes, job 1 (nvf) collapses: exit 1, the summary, a DONE and a FAILED record."""
    out, err = proc.communicate(timeout=900)
    assert proc.returncode == 1, err
    lines = _sweep_lines(out + err)
    assert lines[0] == "sweep: 2 jobs: 1 done, 0 skipped, 1 failed", out + err
    assert len(lines) == 2 and lines[1].startswith("failed: job 1 (") and "method=nvf" in lines[1]
    assert "): step 0: visibility stage collapsed at iteration 4: mean loss " in lines[1]
    records = {d.parts[-3].split("-")[0]: RunRecord(d) for d in tmp_path.glob("*/*/*/seed_*")}
    assert {method: r.status() for method, r in records.items()} == {"random": "done", "nvf": "failed"}
    assert records["nvf"].failure() in lines[1]
    listed = re.search(r"^job 0 \(.*method=random.*\): (\S+)$", out, flags=re.MULTILINE)  # where the finished job went
    assert listed is not None and Path(listed.group(1)) == records["random"].directory
    assert f"the tables of them all: python -m pipeline.tables paths.outputs={tmp_path}" in out


def test_a_sweep_with_a_failed_job_exits_nonzero_with_a_summary(tmp_path):
    """The basic launcher: every job runs; the failure is recorded, listed with its reason, and the
    sweep's exit status is 1 (it was 0 with 21 of 21 jobs failed)."""
    _check_sweep(tmp_path, _cli(tmp_path, *SWEEP))


@pytest.mark.slow
def test_a_joblib_sweep_with_a_failed_job_exits_nonzero_with_a_summary(tmp_path):
    """The same sweep with two joblib workers: the reports come back from other processes."""
    _check_sweep(tmp_path, _cli(tmp_path, *SWEEP, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"))


def test_an_episode_with_a_scorer_saves_its_score_map(tmp_path):
    directory = run_episode(_cfg(tmp_path, "method=wd", "budget.horizon=1", "train.backbone.iters=2")).directory
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
    assert proc.returncode == 2
    lines = [line for line in err.splitlines() if line.strip() and "cpp_extension" not in line]
    assert len(lines) == 1 and "lego" in lines[0] and "Traceback" not in err
    assert not (tmp_path / "lego").exists()  # refused before the record started: no run directory left


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
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(word in lines[0] for word in expected) and "search path" not in lines[0]
    assert not any(tmp_path.iterdir())


def test_impossible_value_names_the_key(tmp_path):
    proc = _cli(tmp_path, "planner.num_candidates=-3")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 2
    assert "planner.num_candidates" in err and "Traceback" not in err


def test_torch_threads_follow_omp_num_threads_else_cores_per_job(monkeypatch):
    """Two sweeps side by side share the cores only if each can be told its threads: an explicit
    ``OMP_NUM_THREADS`` wins over cores / jobs (which gave a one-job sweep every core); the cores are those this
    process may run on (its affinity), not the machine's."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2})
    monkeypatch.setattr(os, "cpu_count", lambda: 64)
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert torch_threads() == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert torch_threads() == 3
    monkeypatch.delenv("OMP_NUM_THREADS")
    assert torch_threads() == 3


@pytest.mark.parametrize("value", ["4", "4097", "-1"])
def test_omp_num_threads_beyond_the_cores_is_refused(monkeypatch, value):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2})
    monkeypatch.setenv("OMP_NUM_THREADS", value)
    with pytest.raises(ConfigError, match=rf"OMP_NUM_THREADS='{value}' must be a whole number 1\.\.3 \(the cores"):
        torch_threads()


@pytest.mark.parametrize("value", ["0", "two"])
def test_a_bad_omp_num_threads_is_one_line_before_anything_is_written(tmp_path, value):
    proc = _cli(tmp_path, env={**os.environ, "OMP_NUM_THREADS": value})
    _, err = proc.communicate(timeout=300)
    ours = [line for line in err.splitlines() if line.strip() and "cpp_extension" not in line and "libgomp" not in line]
    assert proc.returncode == 2 and len(ours) == 1 and ours[0].startswith(f"error: OMP_NUM_THREADS='{value}'"), err
    assert not any(p.name != ".hydra" for p in tmp_path.iterdir())


def test_an_outputs_path_that_is_a_file_is_one_line_before_anything_is_written(tmp_path):
    """Checked before Hydra creates its own directory under paths.outputs (a traceback before)."""
    a_file = tmp_path / "outputs"
    a_file.write_text("not a directory")
    proc = _cli(tmp_path, f"paths.outputs={a_file}")
    _, err = proc.communicate(timeout=300)
    lines = [line for line in err.splitlines() if line.strip() and "cpp_extension" not in line]
    assert proc.returncode == 2 and lines == [
        f"error: paths.outputs={a_file} is a file, not a directory; pass paths.outputs=DIR"
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outputs"] and a_file.read_text() == "not a directory"


@pytest.mark.parametrize("samples", [1, 2])
def test_ground_truth_has_budget_gt_samples_per_pixel(tmp_path, samples):
    """Training images (RGBA) and evaluation views are the mean of ``budget.gt_samples^2`` sub-pixel
    samples; with 1, the pixel-centre render every committed record was made with."""
    cfg = _cfg(tmp_path, f"budget.gt_samples={samples}")
    scene = load_scene("default", Path(cfg.paths.assets))
    with pytest.warns(UserWarning, match="LPIPS will be reported as missing"):
        lpips = LpipsMetric(sources=[])
    episode = Episode(EpisodeSettings.of(cfg, scene), scene, torch.device("cpu"), lpips)
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


@pytest.mark.slow
def test_a_sweep_through_the_submitit_local_launcher(tmp_path):
    """Hydra's submitit launcher on this machine (a real submitit executor, the code path of
    submitit_slurm): two smoke jobs run as submitit jobs, report back and are summarised."""
    proc = _cli(
        tmp_path,
        "-m",
        "method=random,wd",
        "budget.horizon=1",
        "hydra/launcher=submitit_local",
        f"hydra.launcher.submitit_folder={tmp_path / 'submitit'}",
        "hydra.launcher.timeout_min=20",
    )
    out, err = proc.communicate(timeout=1500)
    assert proc.returncode == 0, err
    assert _sweep_lines(out + err) == ["sweep: 2 jobs: 2 done, 0 skipped, 0 failed"]
    directories = sorted(tmp_path.glob("default/*/smoke/seed_100"))
    assert [d.parts[-3] for d in directories] == ["random-argmax-none", "wd-argmax-none"]
    for directory in directories:
        info, rows = verified(RunRecord(directory))
        assert info["status"] == "done" and len(rows) == 1
        assert_metrics_in_range(rows[0]["metrics"])
    assert list((tmp_path / "submitit").rglob("*_result.pkl"))  # submitit's own job results


CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device: torch.cuda.is_available() is False")


@pytest.mark.cuda
@CUDA
@pytest.mark.parametrize("planner", ["argmax", "opt"])
def test_a_smoke_episode_on_cuda(tmp_path, planner):
    """The GPU path end to end: training, evaluation, planning (and -OPT's gradients) with ``device=cuda``,
    recorded as a CUDA run that verifies, with every metric finite and in range. (Not compared with a
    CPU run: the seeded generators live on the device, so the two draw different batches.)"""
    directory = run_episode(
        _cfg(tmp_path, "method=nvf", f"planner={planner}", "budget.horizon=2", "device=cuda")
    ).directory
    info, rows = verified(RunRecord(directory))
    assert info["status"] == "done" and info["device"].startswith("cuda") and len(rows) == 2
    for row in rows:
        assert_metrics_in_range(row["metrics"])
        assert all(math.isfinite(v) for v in row["selected_pose"])
    assert all(("opt" in row) == (planner == "opt") for row in rows)  # -OPT recorded its refinement


def test_a_run_made_on_another_build_of_its_scene_is_not_resumed_on_this_one(tmp_path, monkeypatch):
    """A record says which build of its scene it was made on (run.json's scene_source and ground_truth.asset;
    ``pipeline.scenes.ground_truth.built_differently``): an unfinished record of the default scene marked as
    built from a mesh file is refused, naming both sources and scene.asset, rather than finished on the
    procedural scene."""
    cfg = _cfg(tmp_path, "method=random", "budget.horizon=2")
    directory = tmp_path / "default" / "random-argmax-none" / "smoke" / "seed_100"
    record = RunRecord(directory)
    record.start(run_settings(cfg) | {"torch_threads": 1, "scene_source": "mesh"})
    pose = [0.0, 0.0, 0.0, 1.0, 1.0, -1.0, 1.0]
    record.append_step({"step": 0, "n_views": 3, "status": "ok", "metrics": {"psnr": 10.0}, "selected_pose": pose})
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    with pytest.raises(RunRefused, match=r"scene source \(mesh in the record, procedural now\); set scene.asset"):
        run_episode(cfg)
    assert len(record.completed_steps()) == 1


def test_a_run_started_with_other_threads_is_not_resumed_with_these(tmp_path, monkeypatch):
    """A record's numbers depend on its thread count (one and two threads gave 16.57 and 15.60 dB at one step), so
    an unfinished record started with 7 threads is refused, naming the count, rather than finished with 1."""
    cfg = _cfg(tmp_path, "method=random", "budget.horizon=2")
    directory = tmp_path / "default" / "random-argmax-none" / "smoke" / "seed_100"
    record = RunRecord(directory)
    record.start(run_settings(cfg) | {"torch_threads": 7})
    pose = [0.0, 0.0, 0.0, 1.0, 1.0, -1.0, 1.0]
    record.append_step({"step": 0, "n_views": 3, "status": "ok", "metrics": {"psnr": 10.0}, "selected_pose": pose})
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    with pytest.raises(RunRefused, match="started with 7 torch threads .* OMP_NUM_THREADS=7"):
        run_episode(cfg)
    assert len(record.completed_steps()) == 1


def test_a_whole_view_methods_score_column_shows_its_candidates_from_above(tmp_path):
    """The grid said "no score map: this method scores no views" for FVS, FisherRF, Bayes' Rays and every method
    that scores whole views, as if it ran as Random; its score image is now each candidate's score at its camera
    centre seen from above, with the range and unit its colour bar reads."""
    import numpy as np

    from pipeline.episode.evaluation import candidate_score_map
    from pipeline.records.images import map_range

    box = np.array([[-1.0, -1.0, 0.0], [1.0, 1.0, 1.0]])
    image = candidate_score_map(np.array([[-1.0, 1.0, 0.5], [1.0, -1.0, 0.5]]), np.array([2.0, 5.0]), box, 40)
    assert image[0, 0] == 2.0 and image[39, 39] == 5.0 and np.isnan(image[20, 20])
    outcome = run_episode(_cfg(tmp_path, "method=fvs", "budget.horizon=1"))
    low, high, unit = map_range(outcome.directory / "images" / "step_00_score.png")
    assert low < high and unit == "radians, candidates from above"
