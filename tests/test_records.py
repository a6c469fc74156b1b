"""pipeline/records: run directories, atomic run.json / steps.jsonl, resume, DONE and FAILED markers, the
writer lock, verification on read and the legacy defaults of keys added after records were written."""

import hashlib
import json
import math
import multiprocessing
import os
import re
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from nvf.cameras import Intrinsics
from pipeline.atomic_write import atomic_write_text, temp_file
from pipeline.config.settings_beyond_groups import NamedConfigs
from pipeline.config.structured_configs import register_configs
from pipeline.records.compat import LEGACY_DEFAULTS, with_legacy_defaults
from pipeline.records.lock import RunLock, RunLocked
from pipeline.records.store import (
    DIGEST_KEY,
    IDENTITY_KEYS,
    LEGACY_DIGEST_KEY,
    RecordError,
    RunRecord,
    check_key,
    read_steps,
    run_difference,
    run_dir,
    to_jsonable,
)
from pipeline.records.verify import verified
from pipeline.repo import CONF, REPO


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
    metrics = {"psnr": psnr, "lpips": None}
    return {
        "step": step,
        "n_views": 3 + step,
        "status": "ok",
        "metrics": metrics,
        "selected_pose": [0.0, 0, 0, 1, 0, 0, 2],
    }


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
    for seed in (-1, 2**63):
        with pytest.raises(ValueError, match=r"is not an integer from 0 to 2\^63-1"):
            run_dir(tmp_path, "lego", "nvf", "argmax", "none", "cpu", seed)
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


# ------------------------------------------------------------------------- one writer per run


def test_a_second_writer_is_refused_naming_the_holder(tmp_path):
    out = tmp_path / "out"
    directory = out / "lego_proxy" / "nvf-argmax-none" / "smoke" / "seed_100"
    lock = out / ".locks" / "lego_proxy" / "nvf-argmax-none" / "smoke" / "seed_100.lock"
    with RunLock(directory, root=out) as held:
        assert held.path == lock
        assert re.fullmatch(rf"host \S+ pid {os.getpid()} started \S+\n", lock.read_text())
        with pytest.raises(RunLocked, match=rf"run {directory} is being written by host \S+ pid {os.getpid()} started"):
            with RunLock(directory, root=out):
                pass
    assert not (out / "lego_proxy").exists()  # nothing was written: no run directory left
    assert lock.read_text() == ""  # the lock file stays, emptied on release: it names no holder
    with RunLock(directory, root=out):  # released: the next writer gets it
        directory.mkdir(parents=True)
        (directory / "run.json").write_text("{}")
    assert [p.name for p in directory.iterdir()] == ["run.json"]  # the lock lives outside the run directory


def test_the_lock_dies_with_its_process(tmp_path):
    """A writer killed with SIGKILL releases its lock (the kernel does): the run can be resumed."""
    run = tmp_path / "run"
    code = (
        "import sys, time; from pathlib import Path; from pipeline.records.lock import RunLock\n"
        f"with RunLock(Path({str(run)!r}), Path({str(tmp_path)!r})):\n"
        "    print('locked', flush=True); time.sleep(600)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RunLocked, match=f"pid {holder.pid} "):
            with RunLock(run, tmp_path):
                pass
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    with RunLock(run, tmp_path) as lock:
        assert f"pid {os.getpid()} " in lock.path.read_text()


def _take_and_release(root: Path, seconds: float, results) -> None:
    """Take and release the lock of one run for ``seconds``; inside it, claim the run with an O_EXCL file
    (a second holder at the same time would find it). Puts (held, refused, overlaps, errors) on ``results``."""
    directory = root / "scene" / "nvf-argmax-none" / "smoke" / "seed_1"
    held = refused = overlaps = 0
    errors = []
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            with RunLock(directory, root):
                directory.mkdir(parents=True, exist_ok=True)
                try:
                    os.close(os.open(directory / "holder", os.O_CREAT | os.O_EXCL | os.O_WRONLY))
                except FileExistsError:
                    overlaps += 1
                    continue
                held += 1
                os.unlink(directory / "holder")
        except RunLocked:
            refused += 1
        except Exception as err:  # noqa: BLE001 - what the race raised: counted and shown
            errors.append(f"{type(err).__name__}: {err}")
    results.put((held, refused, overlaps, errors))


def test_six_processes_racing_for_one_lock_never_fail_nor_overlap(tmp_path):
    """Six processes taking and releasing RunLock on one run folder raised FileExistsError
    from mkdir (a releaser removed the folder between another's mkdir and its check). Now nothing is ever
    removed: every attempt either holds the lock alone or is refused with RunLocked."""
    context = multiprocessing.get_context("fork")
    results = context.Queue()
    workers = [context.Process(target=_take_and_release, args=(tmp_path, 3.0, results)) for _ in range(6)]
    for worker in workers:
        worker.start()
    outcomes = [results.get(timeout=120) for _ in workers]
    for worker in workers:
        worker.join(timeout=60)
    errors = [error for outcome in outcomes for error in outcome[3]]
    assert errors == [] and sum(outcome[2] for outcome in outcomes) == 0
    assert sum(outcome[0] for outcome in outcomes) > 0 and sum(outcome[1] for outcome in outcomes) > 0


def test_a_symlinked_lock_file_is_refused_never_followed(tmp_path):
    """With the lock file a symbolic link to another file, pipeline.run exited 0 and the
    target's contents were replaced by the holder's line. Now the lock is opened with O_NOFOLLOW: one line."""
    victim = tmp_path / "precious.txt"
    victim.write_text("precious\n")
    out, directory = tmp_path / "out", tmp_path / "out" / "default" / "nvf-argmax-none" / "smoke" / "seed_100"
    lock = RunLock(directory, out).path
    lock.parent.mkdir(parents=True)
    for target in (victim, out / "inside.txt"):  # a link out of the root, and one inside it: neither followed
        lock.unlink(missing_ok=True)
        lock.symlink_to(target)
        with pytest.raises(RecordError, match=rf"^{re.escape(str(lock))}: a symbolic link, not the run's lock file"):
            with RunLock(directory, out):
                pass
    assert victim.read_text() == "precious\n" and not (out / "inside.txt").exists()


def test_a_hard_linked_lock_file_is_refused_never_truncated(tmp_path):
    """A lock file hard-linked to a file outside paths.outputs was opened and truncated (O_NOFOLLOW
    stops symbolic links, not hard links): the file under its other name was emptied. Now it is one line."""
    victim = tmp_path / "precious.txt"
    victim.write_text("precious\n")
    out, directory = tmp_path / "out", tmp_path / "out" / "default" / "nvf-argmax-none" / "smoke" / "seed_100"
    lock = RunLock(directory, out).path
    lock.parent.mkdir(parents=True)
    os.link(victim, lock)
    with pytest.raises(RecordError, match=rf"^{re.escape(str(lock))}: a file with 1 other name\(s\) \(a hard link\)"):
        with RunLock(directory, out):
            pass
    assert victim.read_text() == "precious\n"


def test_a_run_path_through_a_symlink_leaving_its_root_is_refused(tmp_path):
    """Directory links were followed too. A component of the run directory, or an entry in
    it (its images/), that links outside paths.outputs is refused naming it; a link inside the root is fine."""
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    elsewhere.mkdir()
    (out / "default").mkdir(parents=True)
    (out / "default" / "nvf-argmax-none").symlink_to(elsewhere)
    directory = out / "default" / "nvf-argmax-none" / "smoke" / "seed_100"
    parent = re.escape(str(out / "default" / "nvf-argmax-none"))
    link = rf"{parent} is a symbolic link to {re.escape(str(elsewhere))}, outside"
    with pytest.raises(RecordError, match=link):
        with RunLock(directory, out):
            pass
    (out / "default" / "nvf-argmax-none").unlink()
    directory.mkdir(parents=True)
    (directory / "images").symlink_to(elsewhere)
    with pytest.raises(RecordError, match=rf"{re.escape(str(directory / 'images'))} is a symbolic link"):
        with RunLock(directory, out):
            pass
    (directory / "images").unlink()
    (out / "kept").mkdir()
    (directory / "images").symlink_to(out / "kept")  # inside the root: followed as usual
    with RunLock(directory, out):
        pass
    assert not list(elsewhere.iterdir())


def test_a_lock_that_is_a_directory_or_a_run_path_taken_by_a_file_is_one_line(tmp_path):
    """A lock file that is a directory, and a run directory path taken by a plain file,
    were tracebacks (IsADirectoryError, NotADirectoryError). Now each is one RecordError line."""
    out, directory = tmp_path / "out", tmp_path / "out" / "default" / "nvf-argmax-none" / "smoke" / "seed_100"
    lock = RunLock(directory, out).path
    lock.mkdir(parents=True)
    with pytest.raises(RecordError, match=rf"^{re.escape(str(lock))}: Is a directory, not the run's lock file"):
        with RunLock(directory, out):
            pass
    lock.rmdir()
    (out / "default").mkdir()
    (out / "default" / "nvf-argmax-none").write_text("a file where the run's folder belongs")
    parent = re.escape(str(out / "default" / "nvf-argmax-none"))
    taken = rf"^{parent} is a file, not a directory, so {re.escape(str(directory))}"
    with pytest.raises(RecordError, match=taken):
        with RunLock(directory, out):
            pass


def test_temp_files_are_per_writer_and_only_the_records_own_are_cleaned(tmp_path):
    record = _started(tmp_path)
    stale = record.directory / ".steps.jsonl.4242.deadbeef.tmp"  # a killed write of this run
    other = record.directory / ".summary.md.4243.cafebabe.tmp"  # someone else's file in the directory
    stale.write_text('{"step": 0')
    other.write_text("# half a summary")
    fd, tmp = temp_file(record.run_json)
    os.close(fd)
    assert tmp.name.startswith(f".run.json.{os.getpid()}.") and tmp.name.endswith(".tmp")
    assert temp_file(record.run_json)[1] != tmp  # unique per call
    record.start(_info(), repo=tmp_path)
    assert not stale.exists() and other.exists()


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_written_files_follow_the_umask(tmp_path, umask):
    previous = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o666 & ~umask


# -------------------------------------------------------------------------------- verify on read

HORIZON = 3


def _finished(tmp_path: Path, rows: int = HORIZON) -> RunRecord:
    record = RunRecord(run_dir(tmp_path, "lego_proxy", "nvf", "argmax", "none", "smoke", 100))
    record.start(_info(config={"budget": {"horizon": HORIZON}, "seed": 100}), repo=tmp_path)
    for step in range(rows):
        record.append_step(_row(step))
    record.mark_done()
    return record


def _lines(record: RunRecord) -> list[str]:
    return record.steps_path.read_text().splitlines(keepends=True)


def test_a_finished_record_verifies_and_carries_the_digest_of_its_config_and_rows(tmp_path):
    record = _finished(tmp_path)
    info, rows = verified(record)
    content = {k: v for k, v in info.items() if k != DIGEST_KEY}
    canonical = json.dumps(content, sort_keys=True, separators=(",", ":")).encode() + b"\n"
    assert info[DIGEST_KEY] == "sha256:" + hashlib.sha256(canonical + record.steps_path.read_bytes()).hexdigest()
    assert LEGACY_DIGEST_KEY not in info
    assert [r["step"] for r in rows] == [0, 1, 2]
    assert verified(RunRecord(tmp_path / "nothing")) == ({}, [])


def _lost_last_line(record):
    record.steps_path.write_text("".join(_lines(record)[:-1]))


def _changed_value(record):
    record.steps_path.write_text(record.steps_path.read_text().replace('"psnr":20.0', '"psnr":30.0', 1))


def _run_json_deleted(record):
    record.run_json.unlink()


def _run_json_and_rows_deleted(record):
    record.run_json.unlink()
    record.steps_path.unlink()


def _run_json_a_list(record):
    record.run_json.write_text("[1, 2]")


def _first_row_is_step_1_only(record):
    record.steps_path.write_text('{"step": 1}\n' + "".join(_lines(record)[1:]))


def _nan_pose(record):
    record.steps_path.write_text(
        record.steps_path.read_text().replace('"selected_pose":[0.0', '"selected_pose":[null', 1)
    )


def _missing_middle_row(record):
    lines = _lines(record)
    record.steps_path.write_text(lines[0] + lines[2])


def _seed_not_an_integer(record):
    info = json.loads(record.run_json.read_text())
    record.run_json.write_text(json.dumps({**info, "seed": "100"}))


def _edit_info(record, **changes):
    info = json.loads(record.run_json.read_text())
    record.run_json.write_text(json.dumps({**info, **changes}))


def _edit_last_row(record, old: str, new: str):
    lines = _lines(record)
    lines[-1] = lines[-1].replace(old, new, 1)
    record.steps_path.write_text("".join(lines))


def _case_3_seed_of_301_digits(record):
    _edit_info(record, seed=10**300)


def _case_3_metric_of_401_digits(record):
    _edit_last_row(record, '"psnr":20.0', f'"psnr":{10**400}')


def _case_3_metric_beyond_float(record):
    _edit_last_row(record, '"psnr":20.0', '"psnr":1e400')  # Python's json reads it as inf


def _case_3_a_middle_line_of_100000_nested_brackets(record):
    lines = _lines(record)
    record.steps_path.write_text(lines[0] + '{"step": 1, "x": ' + "[" * 100_000 + "]" * 100_000 + "}\n" + lines[2])


def _case_3_a_last_line_of_100000_nested_brackets(record):
    record.steps_path.write_text(
        "".join(_lines(record)[:2]) + '{"step": 2, "x": ' + "[" * 100_000 + "]" * 100_000 + "}\n"
    )


def _case_3_run_json_nested_40_deep(record):
    _edit_info(record, extra=json.loads("[" * 40 + "]" * 40))


def _case_3_run_json_of_100000_nested_brackets(record):
    record.run_json.write_text('{"scene": ' + "[" * 100_000 + "]" * 100_000 + "}")


def _case_3_a_name_of_200_characters(record):
    _edit_info(record, scene="s" * 200)


def _case_3_a_rank_that_is_text(record):
    info = json.loads(record.run_json.read_text())
    info["config"]["method"] = {"name": "nvf", "rank": "first"}
    record.run_json.write_text(json.dumps(info))


def _case_4_a_config_value_with_line_breaks(record):
    info = json.loads(record.run_json.read_text())
    info["config"]["planner"] = {"num_candidates": "a|b\n| injected | row |\n\\input{/etc/passwd}"}
    record.run_json.write_text(json.dumps(info))


def _case_9_method_relabelled_after_it_finished(record):
    _edit_info(record, method="air")


def _run_json_a_symbolic_link(record):
    copy = record.directory.parent / "elsewhere.json"
    record.run_json.rename(copy)
    record.run_json.symlink_to(copy)


def _steps_a_symbolic_link(record):
    copy = record.directory.parent / "elsewhere.jsonl"
    record.steps_path.rename(copy)
    record.steps_path.symlink_to(copy)


def _run_json_of_17_mib(record):
    os.truncate(record.run_json, 17 << 20)


MALFORMED = [
    (_lost_last_line, r"steps.jsonl: 2 rows, but the run is marked done with a horizon of 3 steps"),
    (_changed_value, r"seed_100: run.json or steps.jsonl differs from the digest run.json took when the run ended"),
    (_run_json_deleted, r"seed_100: steps.jsonl and DONE without run.json, so the settings .* are unknown"),
    (_run_json_and_rows_deleted, r"seed_100: DONE without run.json"),
    (_run_json_a_list, r"run.json: a JSON list, not an object"),
    (_first_row_is_step_1_only, r"steps.jsonl: line 1 holds step 1, expected step 0"),
    (_nan_pose, r"steps.jsonl: step 0 has selected_pose=\[None, .*\], not 7 finite numbers"),
    (_missing_middle_row, r"steps.jsonl: line 2 holds step 2, expected step 1 \(a step is missing or repeated\)"),
    (_seed_not_an_integer, r"run.json: seed '100' is not an integer from 0 to 2\^63-1"),
    (_case_3_seed_of_301_digits, r"run.json: holds seed: an integer of 301 digits, beyond int64"),
    (_case_3_metric_of_401_digits, r"steps.jsonl: step 2 holds metrics.psnr: an integer of 401 digits, beyond int64"),
    (_case_3_metric_beyond_float, r"steps.jsonl: step 2 holds metrics.psnr: inf, not a finite number"),
    (_case_3_a_middle_line_of_100000_nested_brackets, r"steps.jsonl: line 2 is corrupt and not the last one"),
    (
        _case_3_a_last_line_of_100000_nested_brackets,
        r"steps.jsonl: dropped a corrupt last line \(line 3\) of a finished run",
    ),
    (_case_3_run_json_nested_40_deep, r"run.json: holds extra\.0\.0(\.0)*: nested more than 32 levels deep"),
    (_case_3_run_json_of_100000_nested_brackets, r"run.json: not valid JSON \(nested deeper than a record may be\)"),
    (_case_3_a_name_of_200_characters, r"run.json: run key scene='s{64}'... has 200 characters, more than 64"),
    (_case_3_a_rank_that_is_text, r"run.json: config.method.rank is 'first', not int"),
    (
        _case_4_a_config_value_with_line_breaks,
        r"run.json: holds config.planner.num_candidates: a text with a control character",
    ),
    (
        _case_9_method_relabelled_after_it_finished,
        r"seed_100: run.json or steps.jsonl differs from the digest run.json took",
    ),
    (_run_json_a_symbolic_link, r"run.json: a symbolic link, not a record file"),
    (_steps_a_symbolic_link, r"steps.jsonl: a symbolic link, not a record file"),
    (_run_json_of_17_mib, r"run.json: more than 16777216 bytes, more than a record file may hold"),
]


@pytest.mark.parametrize(("damage", "problem"), MALFORMED, ids=[d.__name__.strip("_") for d, _ in MALFORMED])
def test_a_malformed_record_is_one_line_naming_the_file_and_the_problem(tmp_path, damage, problem):
    """Each way a record went wrong in practice fails verification with one line (never a traceback,
    never a silently shorter or mixed record)."""
    record = _finished(tmp_path)
    damage(record)
    with pytest.raises(RecordError, match=problem) as err:
        verified(record)
    assert "\n" not in str(err.value) and str(record.directory) in str(err.value)


def test_a_marker_that_is_a_symbolic_link_does_not_count(tmp_path):
    """DONE is read only as a regular file: a link planted in its place does not mark a run finished."""
    record = _started(tmp_path)
    record.append_step(_row(0))
    (tmp_path / "elsewhere").write_text("2026-01-01\n")
    (record.directory / "DONE").symlink_to(tmp_path / "elsewhere")
    assert record.status() == "unfinished"


def test_records_finished_before_the_record_digest_are_checked_against_their_rows_digest(tmp_path):
    """A record that ended with the older digest (``steps_digest``: steps.jsonl alone) still verifies, and its rows
    are still protected; its run.json is not (that form never covered it), as the module's docstring says."""
    record = _finished(tmp_path)
    info = json.loads(record.run_json.read_text())
    del info[DIGEST_KEY]
    info[LEGACY_DIGEST_KEY] = "sha256:" + hashlib.sha256(record.steps_path.read_bytes()).hexdigest()
    record.run_json.write_text(json.dumps(info))
    assert verified(record)[0] == info
    record.run_json.write_text(json.dumps({**info, "scene_source": "mesh"}))
    assert verified(record)[0]["scene_source"] == "mesh"  # an edit the older digest does not cover
    record.run_json.write_text(json.dumps({**info, "scene_source": "edited"}))
    with pytest.raises(RecordError, match="scene_source is 'edited', not 'procedural' or 'proxy'"):
        verified(record)  # a value no version writes is refused all the same
    record.run_json.write_text(json.dumps(info))
    _changed_value(record)
    with pytest.raises(
        RecordError, match=r"steps.jsonl: differs from the digest run.json took when the run finished \(steps_digest\)"
    ):
        verified(record)


def test_a_record_from_a_version_that_takes_a_digest_must_have_one(tmp_path):
    """A record whose ``record_digest`` was deleted and a metric edited was accepted as a legacy
    record. Which versions take a digest is read from the record itself: every one writes ``candidate_filters`` into
    run.json and none before did, so such a record without a digest is refused; an older one is still read."""
    record = RunRecord(run_dir(tmp_path, "lego_proxy", "nvf", "argmax", "none", "smoke", 100))
    record.start(_info(config={"budget": {"horizon": HORIZON}, "seed": 100}, candidate_filters=True), repo=tmp_path)
    for step in range(HORIZON):
        record.append_step(_row(step))
    record.mark_done()
    info = json.loads(record.run_json.read_text())
    del info[DIGEST_KEY]
    record.run_json.write_text(json.dumps(info))
    _changed_value(record)
    with pytest.raises(RecordError, match=r"run.json: no record_digest, though the version that wrote it"):
        verified(record)
    del info["candidate_filters"]  # a record made before the digests: the checks that were possible then
    record.run_json.write_text(json.dumps(info))
    assert verified(record)[1][0]["metrics"]["psnr"] == 30.0


@pytest.mark.parametrize(
    ("pose", "problem"),
    [
        ([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "a quaternion of norm 0, not a unit quaternion"),
        ([0.0, 0.0, 0.0, 1.0, 1e308, 0.0, 1.0], "at (1e+308, 0, 1), not within the scene's camera box"),
        ([0.0, 0.0, 0.0, 1.0, 3.0, 0.0, 1.0], "at (3, 0, 1), not within the scene's camera box"),
    ],
)
def test_a_recorded_pose_must_be_a_unit_quaternion_inside_the_camera_box(tmp_path, pose, problem):
    """A row's ``selected_pose`` (what a resumed run replays and the trajectory draws) is checked against the
    record's own camera box, widened by a tenth of its size; a pose inside the widened box is read."""
    config = {"budget": {"horizon": HORIZON}, "scene": {"camera_box": [[-2.0, -2.0, 0.0], [2.0, 2.0, 2.0]]}}
    record = RunRecord(run_dir(tmp_path, "lego_proxy", "nvf", "argmax", "none", "smoke", 100))
    record.start(_info(config=config), repo=tmp_path)
    record.append_step({**_row(0), "selected_pose": [0.0, 0.0, 0.0, 1.0, 2.3, -2.3, 2.15]})
    assert len(verified(record)[1]) == 1
    record.append_step({**_row(1), "selected_pose": pose})
    with pytest.raises(RecordError, match=rf"steps.jsonl: step 1 has selected_pose .*{re.escape(problem)}"):
        verified(record)


def test_every_committed_record_verifies():
    """The committed records (results/runs, pilots) pass every check, those with the older rows-only digest and
    those from before digests alike."""
    found = sorted((REPO / "results").rglob("run.json"))
    if not found:
        pytest.skip("no committed records in this checkout")
    for run_json in found:
        verified(RunRecord(run_json.parent))


def test_rows_without_run_json_are_never_adopted(tmp_path):
    record = _finished(tmp_path)
    for marker in ("DONE", "run.json"):
        (record.directory / marker).unlink()
    with pytest.raises(RecordError, match="rows without run.json"):
        record.start(_info(config={"budget": {"horizon": 5}, "seed": 100}), repo=tmp_path)


def test_an_unfinished_record_with_a_truncated_last_line_still_verifies(tmp_path):
    """A kill mid-write is not damage: the complete rows count, and the resume repairs the file."""
    record = _started(tmp_path)
    record.append_step(_row(0))
    with record.steps_path.open("a") as f:
        f.write('{"step": 1, "n_vi')
    info, rows = verified(record)
    assert info["status"] == "running" and [r["step"] for r in rows] == [0]


# ------------------------------------------------------------------------ keys added after records

COMMITTED = REPO / "results" / "runs"


def test_legacy_defaults_fill_only_keys_the_record_lacks_and_the_other_config_has():
    now = {
        "budget": {"gt_samples": 2},
        "planner": {"los_source": "mesh", "los_unobserved_free": True},
        "scene": {"name": "room"},
        "train": {"schedule": "paper", "target_samples": 16384},
    }
    old = {"scene": {"name": "room"}, "train": {"schedule": "paper"}}
    filled = with_legacy_defaults(old, now)
    assert filled["budget"]["gt_samples"] == LEGACY_DEFAULTS["budget.gt_samples"] == 1  # made with 1, not 2
    assert filled["planner"] == {"los_source": "model", "los_unobserved_free": False}  # Room's M29 acted
    assert filled["train"]["target_samples"] == 16384  # inert with schedule=paper: the same run
    assert "budget" not in old  # a copy
    hotdog = with_legacy_defaults({"scene": {"name": "hotdog"}}, now)
    assert hotdog["planner"] == now["planner"]  # no line-of-sight filter on hotdog: inert
    assert with_legacy_defaults({"seed": 1}, {"seed": 1}) == {"seed": 1}  # nothing the other has: nothing added


def _committed_and_today(relative: str, overrides: list[str]) -> tuple[dict, dict]:
    run_json = COMMITTED / relative / "run.json"
    if not run_json.is_file():
        pytest.skip(f"{run_json} is not in this checkout")
    info = json.loads(run_json.read_text())
    register_configs()
    with initialize_config_dir(str(CONF), version_base="1.3"):
        cfg = compose("config", overrides=overrides)
    today = {k: info[k] for k in IDENTITY_KEYS} | {"config": OmegaConf.to_container(cfg, resolve=True)}
    return info, today


def test_a_fresh_run_is_the_same_run_as_the_committed_default_scene_record():
    """The committed default-scene NVF records of seeds 101-102 predate four keys (budget.gt_samples,
    planner.los_source, planner.los_unobserved_free, train.target_samples): read as the values they were made
    with, a fresh run (default scene, NVF, cpu, that seed) is the same run, not one with other settings; seed 100,
    made again since, holds them and is the same run too."""
    for seed, holds in ((101, False), (100, True)):
        overrides = ["scene=default", "budget=cpu", f"seed={seed}"]
        info, today = _committed_and_today(f"default/nvf-argmax-none/cpu/seed_{seed}", overrides)
        assert ("gt_samples" in info["config"]["budget"]) == holds == ("los_source" in info["config"]["planner"])
        assert run_difference(info, today) is None
        assert NamedConfigs(CONF).overrides(info) == ()


def test_a_committed_room_record_made_before_los_source_reads_as_the_models_line_of_sight():
    """WD's Room record made before ``planner.los_source`` existed used the model's line of sight (M29);
    Random's, of the same time, filtered no candidate (METHOD 12), so the key could not act in it."""
    relative = "../pilots/room_model_los/room/wd-argmax-none/cpu/seed_100"
    info, today = _committed_and_today(relative, ["scene=room", "method=wd", "budget=cpu"])
    assert "los_source" not in info["config"]["planner"]
    assert run_difference(info, today) == 'config.planner.los_source ("model" in the record, "mesh" now)'
    assert NamedConfigs(CONF).overrides(info) == ("planner.los_source=model",)  # its own budget label in the tables
    info, today = _committed_and_today(
        "room/random-argmax-none/cpu/seed_100", ["scene=room", "method=random", "budget=cpu"]
    )
    assert "los_source" not in info["config"]["planner"]
    assert run_difference(info, today) is None and NamedConfigs(CONF).overrides(info) == ()
