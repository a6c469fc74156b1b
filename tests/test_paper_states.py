"""pipeline/experiments/paper_states.py and paper_states_summary.py: decisions at states of the committed cpu
episodes, trained at another budget (the smoke budget here, the paper's in use)."""

import json
import shutil
from pathlib import Path

import pytest

from pipeline.experiments import paper_states, paper_states_folder, paper_states_summary, row_files
from pipeline.records.checked_files import read_json_lines
from pipeline.records.store import run_dir


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--scenes", "default", "seed=3"], "seed=3: the contenders, states and budgets are the command's own"),
        (["--scenes", "default", "budget=paper"], "budget=paper"),
        (["--scenes", "default", "--budgets", "bogus"], "budget 'bogus'"),
        (["--scenes", "default", "--outcomes", "nvf"], "--outcomes nvf"),
        (["--scenes", "default", "--threads", "0"], "--threads 0"),
        (["--scenes", "default", "--steps", "25"], "--steps asks for step 25"),
        (["--scenes", "nosuch"], "nosuch"),
    ],
)
def test_bad_input_is_one_line(argv, says, capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        paper_states.main([*argv, f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("error: ") and says in err and err.count("\n") == 1
    assert not (tmp_path / "pilots").exists()  # nothing written


def test_states_of_cpu_records_at_another_budget_resume_and_summarise(tmp_path, capsys, monkeypatch):
    """Two states of the committed cpu episodes on the default scene (NVF's record at step 2, w/o Vis.'s at step 8),
    trained at the smoke budget: a row per state with every contender's pick and spread, the comparisons with NVF,
    the visibility AUCs and the outcomes asked for; a second call adds nothing; the summary reads them back. A call
    with another thread count than the folder's (its setting's; its rows' where the setting predates it) is one
    line naming both, before anything is written."""
    argv = ["--scenes", "default", "--steps", "2,8", "--budgets", "smoke", "--outcomes", "wo_vis,fisherrf"]
    paper_states.main([*argv, f"paths.results={tmp_path}"])
    folder = tmp_path / "pilots" / "paper_states"
    rows, _ = read_json_lines(folder / "states.jsonl", paper_states_summary.STATE)
    assert [(r["step"], r["source"], r["budget"], r["state_budget"]) for r in rows] == [
        (2, "nvf", "smoke", "cpu"),
        (8, "wo_vis", "smoke", "cpu"),
    ]
    for row in rows:
        assert row["views"] == 3 + row["step"] and row["candidates"] == 8
        assert set(row["contenders"]) == {"nvf", "wo_vis", "fisherrf", "activenerf", "fvs_facing", "cover", "warprf"}
        assert set(row["against_nvf"]) == {"wo_vis", "fisherrf", "activenerf", "fvs_facing", "cover", "warprf"}
        assert all(len(found["pose"]) == 7 and not found["reused"] for found in row["contenders"].values())
        made = row["made_with"]
        assert made["threads"] == 1 and made["budget"] == "smoke" and made["ground_truth"] == "pyrender"
        assert made["sizes"]["image"] == 24 and made["differs_from_budget"] == {}
        owner = {"nvf": "nvf-argmax-none", "wo_vis": "nvf-argmax-wo_vis"}[row["source"]]
        assert row["source_record"]["run"] == f"default/{owner}/cpu/seed_100"
        assert row["source_record"]["digest"].startswith("sha256:")
        assert row["contenders"]["wo_vis"]["shared_training"] and not row["contenders"]["activenerf"]["shared_training"]
        assert 0.0 <= row["visibility"]["auc_head"] <= 1.0 and 0.0 < row["visibility"]["seen_fraction"] < 1.0
        for name, outcome in row["outcomes"].items():
            assert name in ("wo_vis", "fisherrf") and not row["against_nvf"][name]["same_pick"]
            assert outcome["gain"] == pytest.approx(outcome["nvf_psnr"] - outcome["rival_psnr"])
        for name, found in row["against_nvf"].items():
            if not found["same_pick"] and name in ("wo_vis", "fisherrf"):
                assert name in row["outcomes"]
    setting = json.loads((folder / "setting.json").read_text())
    assert setting == {"overrides": [], "state_budget": "cpu", "vis_points": 4096, "threads": 1}
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1, 2, 3})
    for made in (setting, {"overrides": [], "state_budget": "cpu", "vis_points": 4096}):
        (folder / "setting.json").write_text(json.dumps(made))
        before = {path.name: path.read_bytes() for path in folder.iterdir() if path.is_file()}
        with pytest.raises(SystemExit) as exit_:
            paper_states.main([*argv, "--threads", "2", f"paths.results={tmp_path}"])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and "was made with --threads 1, not --threads 2" in err and err.count("\n") == 1
        assert {path.name: path.read_bytes() for path in folder.iterdir() if path.is_file()} == before
    capsys.readouterr()
    paper_states.main([*argv, f"paths.results={tmp_path}"])
    assert "step" not in capsys.readouterr().out.split("wrote")[0]  # nothing left to measure
    again, _ = read_json_lines(folder / "states.jsonl", paper_states_summary.STATE)
    assert again == rows
    summary = (folder / "summary.csv").read_text().splitlines()
    assert summary[0].split(",") == list(paper_states_summary.COLUMNS)
    rivals = len(paper_states.CONTENDERS) - 1  # every contender the states hold but NVF
    assert len(summary) == 1 + 2 * rivals  # (default, all) x the rivals
    assert sum(len(r["outcomes"]) for r in rows) == sum(int(line.split(",")[12]) for line in summary[1 : 1 + rivals])


def test_correlation_interval_stays_inside_its_range():
    import numpy as np

    mean, low, high = paper_states_summary.correlation_interval(np.array([0.2, 0.99, 0.999, 1.0]))
    assert -1.0 <= low < mean < high <= 1.0
    assert np.isnan(paper_states_summary.correlation_interval(np.array([np.nan]))[0])


def test_one_writer_per_scene_and_seed_and_no_state_twice(tmp_path, capsys):
    """A second process on a scene and seed another holds is refused in one line; a row repeating a state is
    refused on write, and a file holding one twice is refused on read (the summary names it)."""
    from pipeline.cli import run_command
    from pipeline.experiments.row_files import JsonLines
    from pipeline.records.files import RecordError
    from pipeline.records.lock import RunLock

    folder = tmp_path / "pilots" / "paper_states"
    folder.mkdir(parents=True)
    argv = ["--scenes", "default", "--steps", "2", "--budgets", "smoke", f"paths.results={tmp_path}"]
    with RunLock(folder / "default" / "seed_100", folder), pytest.raises(SystemExit) as exit_:
        run_command(paper_states.main, argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "is being written by" in err and err.count("\n") == 1
    paper_states.main(argv)
    states = JsonLines(folder / "states.jsonl", paper_states_summary.STATE, paper_states_summary.state_key)
    with pytest.raises(RecordError, match="already holds the row"):
        states.add([states.rows[0]])
    text = (folder / "states.jsonl").read_text()
    (folder / "states.jsonl").write_text(text + text)
    with pytest.raises(RecordError, match="line 2 repeats the row"):
        paper_states_summary.write_summary(folder)


def test_a_state_is_never_read_from_a_record_linked_from_outside_its_records(tmp_path, capsys):
    """A state's record that is a symbolic link leaving ``--records`` is one ``error:`` line naming its target and
    exit 2, before anything is written (the duel's rule, ``decisions.recorded_steps``)."""
    records = tmp_path / "runs"
    source = Path("results/runs/default/nvf-argmax-none/cpu/seed_100").resolve()
    link = run_dir(records, "default", "nvf", "argmax", "none", "cpu", 100)
    link.parent.mkdir(parents=True)
    link.symlink_to(source)
    argv = ["--scenes", "default", "--seeds", "100", "--steps", "2", "--budgets", "smoke", "--records", str(records)]
    with pytest.raises(SystemExit) as exit_:
        paper_states.main([*argv, f"paths.results={tmp_path / 'results'}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and f"{source}, outside {records}" in err
    assert not (tmp_path / "results").exists()


def test_a_setting_another_process_wrote_meanwhile_is_refused_not_overwritten(tmp_path, monkeypatch, capsys):
    """``setting.json`` was checked, then written without a lock: a second command with other overrides starting at
    the same time replaced the first one's setting, and the folder mixed states of both. Now it is checked again
    under the folder's lock before it is written: the setting another process wrote in between stays, one line."""
    root = tmp_path / "pilots"
    theirs = {"overrides": ["render.backend=pyrender"], "state_budget": "cpu", "threads": 1}
    made = paper_states_folder.make_directory

    def racing(under, folder):
        made(under, folder)
        (folder / "setting.json").write_text(json.dumps(theirs))

    monkeypatch.setattr(paper_states_folder, "make_directory", racing)
    with pytest.raises(SystemExit) as exit_:
        paper_states_folder.open_folder(
            root, {"overrides": [], "state_budget": "cpu", "threads": 1}, ["python", "-m", "x"]
        )
    err = capsys.readouterr().err
    folder = root / "paper_states"
    assert exit_.value.code == 2 and err.count("\n") == 1 and "made with overrides ['render.backend=pyrender']" in err
    assert json.loads((folder / "setting.json").read_text()) == theirs and not (folder / "command.txt").exists()


def test_a_state_killed_after_its_training_resumes_after_it_with_the_same_row(tmp_path, monkeypatch, capsys):
    """A state killed after its models were trained (and its one-step outcomes taken) lost them: the next run trained
    again, two of a paper state's hours. Now they are kept under ``paths.outputs`` (``StateProgress``): the next run
    loads the models and outcomes instead of training, writes the row an uninterrupted run writes (the seconds
    apart), and removes what it kept."""
    argv = ["--scenes", "default", "--steps", "2", "--budgets", "smoke", "--outcomes", "wo_vis,fisherrf"]
    whole = tmp_path / "whole"
    calls = {"whole": 0}
    measure = paper_states.heldout_psnr

    def counted(*args):
        calls["whole"] += 1
        return measure(*args)

    class Killed(Exception):
        pass

    def killed_after_one(*args):
        if calls.setdefault("killed", 0) == 1:
            raise Killed
        calls["killed"] += 1
        return measure(*args)

    monkeypatch.setattr(paper_states, "heldout_psnr", counted)
    paper_states.main([*argv, f"paths.results={whole}", f"paths.outputs={whole / 'out'}"])
    expected = read_json_lines(whole / "pilots" / "paper_states" / "states.jsonl", paper_states_summary.STATE)[0]
    assert calls["whole"] >= 2  # an outcome at least: both picks trained
    outputs = tmp_path / "out"
    monkeypatch.setattr(paper_states, "heldout_psnr", killed_after_one)
    with pytest.raises(Killed):
        paper_states.main([*argv, f"paths.results={tmp_path}", f"paths.outputs={outputs}"])
    kept = list((outputs / "paper_states").glob("*/default/seed_100/step_2_smoke/nvf-*/trained.pt"))
    assert len(kept) == 1

    def refused(*args, **kwargs):
        raise AssertionError("a resumed state trains nothing it kept")

    calls["resumed"] = 0

    def resumed(*args):
        calls["resumed"] += 1
        return measure(*args)

    monkeypatch.setattr(paper_states, "train_models", refused)
    monkeypatch.setattr(paper_states, "heldout_psnr", resumed)
    paper_states.main([*argv, f"paths.results={tmp_path}", f"paths.outputs={outputs}"])
    rows = read_json_lines(tmp_path / "pilots" / "paper_states" / "states.jsonl", paper_states_summary.STATE)[0]
    assert _without_seconds(rows) == _without_seconds(expected)
    assert calls["resumed"] == calls["whole"] - 1  # the kept outcome is not taken again
    assert not kept[0].parent.parent.exists()


def _without_seconds(rows: list[dict]) -> list[dict]:
    """``rows`` without the wall-clock seconds they hold (the row's, each contender's and each outcome's)."""
    out = []
    for row in rows:
        row = json.loads(json.dumps(row))
        row.pop("seconds")
        for found in row["contenders"].values():
            found.pop("seconds")
        for found in row["outcomes"].values():
            found.pop("seconds")
        row.pop("made_with")
        out.append(row)
    return out


def test_pooled_tables_join_another_settings_states_and_refuse_a_state_twice(tmp_path, capsys):
    """``--pool``: the committed Cycles states (default) with pyrender's (hubble) in ``pooled.csv``, the folder's
    own ``summary.csv`` as without it; a state in both folders is refused, a folder without states is one line."""
    import csv

    from pipeline.cli import run_command
    from pipeline.records.files import RecordError

    folder, other = tmp_path / "pilots" / "paper_states", tmp_path / "pyrender"
    folder.mkdir(parents=True)
    other.mkdir()
    for name in ("states.jsonl", "setting.json"):
        shutil.copy(f"results/pilots/paper_states/{name}", folder)
        shutil.copy(f"results/pilots/paper_states_pyrender/{name}", other)
    paper_states_summary.main([f"paths.results={tmp_path}"])
    alone = (folder / "summary.csv").read_text()
    assert not (folder / "pooled.csv").exists()
    paper_states_summary.main([f"paths.results={tmp_path}", "--pool", str(other)])
    assert (folder / "summary.csv").read_text() == alone
    pooled = list(csv.DictReader((folder / "pooled.csv").open()))
    counts = {(r["budget"], r["scene"]): int(r["states"]) for r in pooled if r["rival"] == "wo_vis"}
    mine = paper_states_summary.read_states(folder)  # the current rows: an extended row counts once
    theirs = paper_states_summary.read_states(other)
    for budget in ("paper", "cpu"):
        expected = sum(r["budget"] == budget for r in mine + theirs)
        assert counts[(budget, "all")] == expected and counts[(budget, "hubble")] >= 1
    assert "pyrender" in (folder / "pooled.md").read_text()
    setting = json.loads((other / "setting.json").read_text())
    (other / "setting.json").write_text(json.dumps(setting | {"state_budget": "smoke"}))
    with pytest.raises(RecordError, match="made with state_budget smoke, .* with cpu: their states do not pool"):
        paper_states_summary.write_pooled(folder, [other])
    (other / "setting.json").write_text(json.dumps(setting))
    (other / "states.jsonl").write_text((folder / "states.jsonl").read_text())
    with pytest.raises(RecordError, match="twice"):
        paper_states_summary.write_pooled(folder, [other])
    with pytest.raises(SystemExit) as exit_:
        run_command(paper_states_summary.main, [f"paths.results={tmp_path}", "--pool", str(tmp_path / "none")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "--pool" in err and "no states.jsonl" in err and err.count("\n") == 1


def test_a_state_is_extended_with_new_contenders_and_outcomes_as_a_fresh_run_measures_it(tmp_path):
    """A state measured with some contenders is extended by a call naming more: its candidate draw rebuilt from
    NVF's stage 1 alone, the backbone-only contenders scored again (FisherRF's pick as the row had it), NVF's and
    w/o Vis.'s picks kept (``reused``), the new rivals' outcomes trained; the new row names the old one
    (``extends``), the file keeps both, and the current row's picks, poses and outcomes are those of a fresh run
    with every contender."""
    argv = ["--scenes", "default", "--steps", "2", "--budgets", "smoke"]
    paper_states.main(
        [*argv, "--contenders", "nvf,wo_vis,fisherrf", "--outcomes", "wo_vis", f"paths.results={tmp_path / 'a'}"]
    )
    paper_states.main([*argv, f"paths.results={tmp_path / 'a'}"])
    paper_states.main([*argv, f"paths.results={tmp_path / 'b'}"])
    lines, _ = read_json_lines(tmp_path / "a" / "pilots" / "paper_states" / "states.jsonl", paper_states_summary.STATE)
    first, extended = lines
    assert extended["extends"] == row_files.row_digest(first)
    assert [name for name, c in extended["contenders"].items() if c["reused"]] == ["nvf", "wo_vis"]
    fresh = paper_states_summary.read_states(tmp_path / "b" / "pilots" / "paper_states")[0]
    for name, found in fresh["contenders"].items():
        assert (extended["contenders"][name]["pick"], extended["contenders"][name]["pose"]) == (
            found["pick"],
            found["pose"],
        )
    assert {n: (o["nvf_psnr"], o["rival_psnr"]) for n, o in extended["outcomes"].items()} == {
        n: (o["nvf_psnr"], o["rival_psnr"]) for n, o in fresh["outcomes"].items()
    }
    kept = first["against_nvf"]["fisherrf"]["spearman"]  # NVF's scores were not computed again: the earlier row's
    assert kept is not None and extended["against_nvf"]["fisherrf"]["spearman"] == kept
    assert kept == pytest.approx(fresh["against_nvf"]["fisherrf"]["spearman"])
    folder = tmp_path / "a" / "pilots" / "paper_states"
    assert paper_states_summary.read_states(folder) == [extended]
    without = extended | {"against_nvf": extended["against_nvf"] | {"fisherrf": {"spearman": None, "same_pick": False}}}
    (folder / "states.jsonl").write_text("".join(json.dumps(row) + "\n" for row in (first, without)))
    [read] = paper_states_summary.read_states(folder)  # an extension row written without it reads the earlier's
    assert read["against_nvf"]["fisherrf"] == {"spearman": kept, "same_pick": False}


@pytest.mark.parametrize(
    ("made", "says"),
    [
        ({"state_budget": "smoke"}, "made with state_budget smoke, not cpu"),
        ({"vis_points": 64}, "made with vis_points 64, not 4096"),
    ],
)
def test_another_setting_is_refused_before_anything_is_written(made, says, tmp_path, capsys):
    """A folder of another states' budget or label points took the rows of both (the setting compared overrides and
    threads only); now such a call is one line and the folder is left as it was."""
    folder = tmp_path / "pilots" / "paper_states"
    folder.mkdir(parents=True)
    setting = {"overrides": [], "state_budget": "cpu", "threads": 1} | made
    (folder / "setting.json").write_text(json.dumps(setting))
    with pytest.raises(SystemExit) as exit_:
        paper_states.main(["--scenes", "default", "--steps", "2", "--budgets", "smoke", f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and says in err and err.count("\n") == 1
    assert sorted(p.name for p in folder.iterdir()) == ["setting.json"]


def test_a_run_refused_for_its_renderer_or_asset_writes_nothing(tmp_path, capsys):
    """A missing Blender (the paper budget's ground truth) or a missing asset is one line before any file is written
    (before, ``setting.json`` and ``command.txt`` locked the folder to a setting that produced nothing)."""
    for argv, says in (
        (["--scenes", "default", "--budgets", "paper", f"paths.blender_python={tmp_path / 'none'}"], "Blender"),
        (["--scenes", "hubble", "--budgets", "smoke", f"paths.assets={tmp_path / 'empty'}"], "hubble"),
    ):
        with pytest.raises(SystemExit) as exit_:
            paper_states.main([*argv, "--steps", "2", f"paths.results={tmp_path}"])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and says in err and err.count("\n") == 1
        assert not (tmp_path / "pilots").exists()


def test_progress_is_kept_by_what_the_state_is(tmp_path, monkeypatch):
    """Progress was kept by setting, scene, seed and step: with ``--steps 8,2`` step 2 is w/o Vis.'s state, yet it
    loaded the models NVF's state of ``--steps 2`` had left, and its row claimed a source it was not made from. Now
    the kept folder is named by the state's owner and the digest of its views."""
    argv = [
        "--scenes",
        "default",
        "--budgets",
        "smoke",
        f"paths.results={tmp_path}",
        f"paths.outputs={tmp_path / 'out'}",
    ]

    class Killed(Exception):
        pass

    def killed(*args):
        raise Killed

    monkeypatch.setattr(paper_states, "candidate_set", killed)
    with pytest.raises(Killed):
        paper_states.main(["--steps", "2", *argv])
    kept = list((tmp_path / "out" / "paper_states").glob("*/default/seed_100/step_2_smoke/nvf-*/trained.pt"))
    assert len(kept) == 1
    trained = []
    monkeypatch.setattr(paper_states, "train_models", lambda *a: trained.append(1) or killed())
    with pytest.raises(Killed):
        paper_states.main(["--steps", "8,2", "--state-budget", "cpu", *argv])
    assert trained  # w/o Vis.'s state trains its own models


def test_corrupt_progress_is_one_line(tmp_path, monkeypatch, capsys):
    argv = [
        "--scenes",
        "default",
        "--steps",
        "2",
        "--budgets",
        "smoke",
        f"paths.results={tmp_path}",
        f"paths.outputs={tmp_path / 'out'}",
    ]

    class Killed(Exception):
        pass

    def killed(*args):
        raise Killed

    monkeypatch.setattr(paper_states, "candidate_set", killed)
    with pytest.raises(Killed):
        paper_states.main(argv)
    (kept,) = (tmp_path / "out" / "paper_states").glob("*/default/seed_100/step_2_smoke/nvf-*")
    monkeypatch.undo()
    for name, text in (("trained.pt", b"\x8b\x07not a model"), ("progress.json", b"[" * 100_000 + b"]" * 100_000)):
        saved = (kept / name).read_bytes()
        (kept / name).write_bytes(text)
        with pytest.raises(SystemExit) as exit_:
            paper_states.main(argv)
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and err.count("\n") == 1 and f"remove {kept}" in err
        (kept / name).write_bytes(saved)


def test_a_row_without_nvf_or_naming_a_rival_it_lacks_is_refused(tmp_path):
    from pipeline.records.files import RecordError

    folder = tmp_path / "paper_states"
    folder.mkdir()
    row = json.loads(Path("results/pilots/paper_states/states.jsonl").read_text().splitlines()[0])
    for broken, says in (
        (
            {**row, "contenders": {k: v for k, v in row["contenders"].items() if k != "nvf"}},
            "contenders.nvf is missing",
        ),
        (
            {**row, "contenders": {k: v for k, v in row["contenders"].items() if k != "fisherrf"}},
            "against_nvf.fisherrf",
        ),
    ):
        (folder / "states.jsonl").write_text(json.dumps(broken) + "\n")
        with pytest.raises(RecordError, match=says):
            paper_states_summary.read_states(folder)


def test_a_record_planned_otherwise_than_its_budget_is_refused(tmp_path, capsys):
    """A record made with other planner settings than its budget's file (here 2 candidates) was taken as NVF's state
    without comment; now it is one line naming the setting."""
    records = tmp_path / "runs"
    source = Path("results/runs_superseded/default/nvf-argmax-none/cpu/seed_100")  # from before records' digests
    target = run_dir(records, "default", "nvf", "argmax", "none", "cpu", 100)
    shutil.copytree(source, target)
    info = json.loads((target / "run.json").read_text())
    info["config"]["planner"]["num_candidates"] = 2
    (target / "run.json").write_text(json.dumps(info))
    argv = ["--scenes", "default", "--seeds", "100", "--steps", "2", "--budgets", "smoke", "--records", str(records)]
    with pytest.raises(SystemExit) as exit_:
        paper_states.main([*argv, f"paths.results={tmp_path / 'results'}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "planner.num_candidates=2" in err and err.count("\n") == 1
    assert not (tmp_path / "results").exists()
