"""pipeline/experiments/visibility_study.py and pipeline/experiments/visibility_summary.py: paired one-step
gains of NVF's picks over w/o Vis.'s on recorded NVF states, and the study's summary table."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from nvf.cameras import Intrinsics, look_at
from pipeline.experiments import visibility_study
from pipeline.experiments.row_files import JsonLines
from pipeline.experiments.visibility_summary import (
    COLUMNS,
    DECISION,
    SURFACE_COLUMNS,
    summary_frame,
    surface_frame,
    write_summary,
)
from pipeline.records.store import RunRecord, run_dir
from pipeline.scenes.mesh_renderer import MeshRays


def decision_row(scene, step, gain=None, spearman=0.99, decisive="unknown", share=0.9):
    row = {
        "scene": scene,
        "seed": 100,
        "step": step,
        "set": 0,
        "spearman": spearman,
        "same_argmax": gain is None,
        "terms": {"nvf": {"decisive": decisive, "terms": {"unknown": {"share": share}}}},
        "ties_at_max": {"nvf": 1, "wo_vis": 1 + step % 2},
    }
    if gain is not None:
        row["gain"] = gain
    return row


def write_setting(folder, name, rows, diagnostics=None):
    folder.mkdir(parents=True)
    (folder / "setting.json").write_text(json.dumps({"name": name, "visibility_source": "head"}))
    (folder / "decisions.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    for scene, report in (diagnostics or {}).items():
        (folder / f"{scene}_diagnostic.json").write_text(json.dumps(report))


def test_summary_pairs_the_disagreements_per_scene_and_over_scenes(tmp_path):
    """A row per scene and one over all scenes; the gain's interval is the Student-t interval of the
    disagreements alone (agreements carry no paired outcome)."""
    gains = [0.5, 0.3, 0.7, 0.1]
    rows = [decision_row("hotdog", k, g) for k, g in enumerate(gains[:2])] + [decision_row("hotdog", 9)]
    rows += [decision_row("default", k, g) for k, g in enumerate(gains[2:])]
    diagnostic = {"sources": {"head": {"auc_mean": 0.7}, "labels": {"auc_mean": 0.8}}}
    write_setting(tmp_path / "c1", "c1", rows, {"hotdog": diagnostic, "default": diagnostic})
    path = write_summary(tmp_path)
    frame = summary_frame(tmp_path)
    assert list(frame.columns) == list(COLUMNS) and path.read_text().startswith(",".join(COLUMNS))
    assert list(frame["scene"]) == ["hotdog", "default", "all"]
    hotdog, _, pooled = (frame.iloc[i] for i in range(3))
    assert hotdog["n"] == 2 and hotdog["decisions"] == 3 and hotdog["same_argmax_fraction"] == pytest.approx(1 / 3)
    assert pooled["n"] == 4 and pooled["onestep_gain_mean"] == pytest.approx(np.mean(gains))
    half = 3.182446 * np.std(gains, ddof=1) / 2  # t(0.975, 3) s / sqrt(4)
    assert pooled["onestep_ci_low"] == pytest.approx(np.mean(gains) - half, rel=1e-5)
    assert hotdog["label_auc"] == 0.8 and hotdog["head_auc"] == 0.7 and hotdog["nvf_decisive_term"] == "unknown"
    assert math.isnan(hotdog["minutes_per_episode"])
    assert hotdog["nvf_tied_fraction"] == 0.0 and hotdog["wo_vis_tied_fraction"] == pytest.approx(2 / 3)


def test_a_name_a_spreadsheet_would_read_as_a_formula_is_written_as_text(tmp_path):
    rows = [decision_row("=HYPERLINK(1)", 0, 0.5), decision_row("=HYPERLINK(1)", 1, 0.2)]
    write_setting(tmp_path / "c1", "+cmd", rows)
    text = write_summary(tmp_path).read_text()
    assert "\n'+cmd,'=HYPERLINK(1)," in text and "\n+" not in text and ",=" not in text


def test_minutes_per_episode_come_from_the_settings_discrimination_experiment(tmp_path):
    """NVF's and w/o Vis.'s mean minutes per episode in ``pilots/discriminate/<the setting's label>/per_seed.csv``;
    the baselines' runs (reused from other budgets' records) are left out; a setting without one stays empty."""
    study = tmp_path / "pilots" / "visibility_study"
    rows = [decision_row("hotdog", 0, 0.5), decision_row("default", 0, 0.2)]
    for name, overrides in (("c1", ["nvf.entropy.logdet_coeff=1.0", "paths.results=x"]), ("plain", [])):
        write_setting(study / name, name, rows)
        setting = json.loads((study / name / "setting.json").read_text()) | {"overrides": overrides, "budget": "cpu"}
        (study / name / "setting.json").write_text(json.dumps(setting))
    experiment = tmp_path / "pilots" / "discriminate" / "cpu+nvf.entropy.logdet_coeff=1.0"
    experiment.mkdir(parents=True)
    (experiment / "per_seed.csv").write_text(
        "scene,method,ablation,seed,minutes\n"
        "hotdog,nvf,none,100,4\nhotdog,nvf,wo_vis,100,6\nhotdog,wd,none,100,60\ndefault,nvf,none,100,3\n"
    )
    frame = summary_frame(study).set_index(["setting", "scene"])
    assert frame.loc[("c1", "hotdog"), "minutes_per_episode"] == 5.0
    assert frame.loc[("c1", "default"), "minutes_per_episode"] == 3.0
    assert frame.loc[("c1", "all"), "minutes_per_episode"] == pytest.approx(13 / 3)
    assert frame.loc["plain", "minutes_per_episode"].isna().all()


def write_finished_run(root: Path, method: str, ablation: str, seed: int, vis_area: list[float]) -> None:
    """A finished smoke record on 'hotdog' whose step ``k`` logs ``vis_area[k]`` (3 steps: smoke's horizon)."""
    record = RunRecord(run_dir(root, "hotdog", method, "argmax", ablation, "smoke", seed))
    keys = {"scene": "hotdog", "method": method, "planner": "argmax", "ablation": ablation, "budget": "smoke"}
    config = {"budget": {"horizon": len(vis_area)}}
    record.start({**keys, "seed": seed, "scene_source": "mesh", "field": "hashgrid", "config": config}, repo=root)
    for step, area in enumerate(vis_area):
        metrics = {"psnr": 20.0, "vis_area": area}
        record.append_step(
            {
                "step": step,
                "n_views": 3 + step,
                "status": "ok",
                "metrics": metrics,
                "selected_pose": [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0],
            }
        )
    record.mark_done()


def test_surface_table_pairs_nvf_with_wo_vis_over_seeds_at_every_step(tmp_path):
    """Surface.csv: per step the mean uncovered surface of NVF, w/o Vis. and Random, and NVF minus w/o Vis.
    paired by seed (the seeds where both have a record)."""
    for seed, lead in ((100, 0.15), (101, 0.2), (102, 0.25)):
        write_finished_run(tmp_path, "nvf", "none", seed, [0.2, 0.3, 0.4 + lead])
        write_finished_run(tmp_path, "nvf", "wo_vis", seed, [0.2, 0.3, 0.4])
    write_finished_run(tmp_path, "random", "none", 100, [0.2, 0.2, 0.25])
    table = surface_frame(tmp_path, budget="smoke")
    assert tuple(table.columns) == SURFACE_COLUMNS and set(table["scene"]) == {"hotdog"}
    frame = table.set_index("step")
    assert frame.loc[0, "nvf_minus_wo_vis"] == 0.0 and frame.loc[2, "nvf_minus_wo_vis"] == pytest.approx(0.2)
    assert frame.loc[2, "ci_low"] > 0.0 and frame.loc[2, "n"] == 3
    assert frame.loc[2, "nvf_vis_area"] == pytest.approx(0.6) and frame.loc[2, "random_vis_area"] == 0.25
    assert surface_frame(tmp_path, budget="cpu").empty  # another budget's records are not mixed in


def test_a_state_misses_the_sets_its_rows_lack(tmp_path):
    """The study keeps its rows in the duel's ``JsonLines`` (whole rows, a cut one dropped; a state's rows in one
    write): a killed study resumes at its first state without rows, and a larger ``--sets`` measures the new sets
    of the states it has (``--sets 3`` on a folder made with ``--sets 2``: set 2 alone)."""
    decisions = JsonLines(tmp_path / "decisions.jsonl", DECISION)
    decisions.add([decision_row("hotdog", 0), decision_row("hubble", 6), decision_row("hubble", 6) | {"set": 1}])
    assert visibility_study.missing_sets(decisions, "hubble", 100, 6, 2) == []
    assert visibility_study.missing_sets(decisions, "hubble", 100, 6, 3) == [2]
    assert visibility_study.missing_sets(decisions, "hubble", 100, 0, 2) == [0, 1]
    assert visibility_study.missing_sets(decisions, "hotdog", 101, 0, 1) == [0]


def test_study_refuses_a_bad_setting_name(capsys):
    with pytest.raises(SystemExit) as exit_:
        visibility_study.main(["--setting", "../x"])
    assert exit_.value.code == 2 and "--setting='../x'" in capsys.readouterr().err


def test_mesh_line_of_sight_margin():
    """A point just inside a box is hidden from a camera outside it; with a margin larger than its depth the
    segment stops in front of the face and reads as seen, as M17's ``train.label_margin`` does."""
    rays = MeshRays(trimesh.creation.box(extents=(1.0, 1.0, 1.0)))
    cam = look_at(torch.tensor([0.0, -3.0, 0.0]), torch.zeros(3))[None]
    intr = Intrinsics.from_fov(16, 16)
    points = torch.tensor([[0.0, -0.45, 0.0], [0.0, 0.45, 0.0]])  # 0.05 behind the front face; near the back face
    assert rays.line_of_sight(points, cam, intr).tolist() == [False, False]
    assert rays.line_of_sight(points, cam, intr, margin=0.1).tolist() == [True, False]


@pytest.mark.slow
def test_study_on_a_smoke_record(tmp_path):
    """End to end at the smoke budget: a 2-step NVF record, then the study on its steps 0 and 1 with 2 candidate
    sets each: a row per state and set, every row's terms, and a finite gain wherever the picks differ."""
    records = tmp_path / "runs"
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pipeline.run",
            "budget=smoke",
            "budget.horizon=2",
            f"paths.outputs={records}",
            "save_images=false",
        ],
        check=True,
        capture_output=True,
    )
    results = tmp_path / "results"
    study = ["budget=smoke", f"paths.results={results}", "--setting", "smoke", "--scenes", "default"]
    study += ["--seeds", "100", "--steps", "0,1", "--sets", "2", "--records", str(records)]
    visibility_study.main(study)
    folder = results / "pilots" / "visibility_study" / "smoke"
    rows = [json.loads(line) for line in (folder / "decisions.jsonl").read_text().splitlines()]
    assert [(r["step"], r["set"]) for r in rows] == [(0, 0), (0, 1), (1, 0), (1, 1)]
    for row in rows:
        assert row["made_with"]["budget"] == "smoke" and row["made_with"]["sizes"]["image"] == 24
        assert row["source_record"]["run"] == "default/nvf-argmax-none/smoke/seed_100"
        assert row["terms"]["wo_vis"]["terms"]["unknown"]["std"] == 0.0
        assert row["same_argmax"] or math.isfinite(row["gain"])
    assert (folder / "default_diagnostic.json").is_file() and (
        results / "pilots" / "visibility_study" / "summary.csv"
    ).is_file()
    before = (folder / "decisions.jsonl").read_text()
    visibility_study.main(study)
    assert (folder / "decisions.jsonl").read_text() == before  # finished states are not measured again
    visibility_study.main([*study, "--sets", "3"])  # the folder made with --sets 2: the new set alone
    added = [json.loads(line) for line in (folder / "decisions.jsonl").read_text().splitlines()][len(rows) :]
    assert (folder / "decisions.jsonl").read_text().startswith(before)
    assert [(r["step"], r["set"]) for r in added] == [(0, 2), (1, 2)]


# ----------------------------------------------------------------------------- hostile input

DIAGNOSTIC = {"sources": {"head": {"auc_mean": 0.7}, "labels": {"auc_mean": 0.8}}}
SUMMARY_DAMAGE = [
    ("decisions_type_corrupt", "c1/decisions.jsonl", "gain", "c1/decisions.jsonl: line 2 gain is 'x', not a number"),
    ("decisions_terms_null", "c1/decisions.jsonl", "terms", "c1/decisions.jsonl: line 2 terms is not an object"),
    ("decisions_bad_middle_line", "c1/decisions.jsonl", "{not json", "c1/decisions.jsonl: line 2 not valid JSON"),
    ("setting_not_json", "c1/setting.json", "{", "c1/setting.json: not valid JSON"),
    ("setting_without_name", "c1/setting.json", {"visibility_source": "head"}, "c1/setting.json: name is missing"),
    ("diagnostic_not_json", "c1/hotdog_diagnostic.json", "[1,", "c1/hotdog_diagnostic.json: not valid JSON"),
    (
        "diagnostic_auc_text",
        "c1/hotdog_diagnostic.json",
        {"sources": {"head": {"auc_mean": "high"}}},
        "c1/hotdog_diagnostic.json: sources.head.auc_mean is 'high', not a number",
    ),
]


@pytest.mark.parametrize(("case", "name", "damage", "line"), SUMMARY_DAMAGE, ids=[d[0] for d in SUMMARY_DAMAGE])
def test_a_damaged_study_file_is_one_line_and_nothing_is_written(tmp_path, command, case, name, damage, line):
    """The visibility summary on a type-corrupt decisions.jsonl, a broken setting.json or a
    bad diagnostic gave a traceback in every variant. Now each is one ``error:`` line naming the file, the line and
    the key, exit 2, and no summary is written; a last line cut by a kill is left out (a study may be writing)."""
    study = tmp_path / "results" / "pilots" / "visibility_study"
    rows = [decision_row("hotdog", 0, 0.5), decision_row("hotdog", 3, 0.3), decision_row("hotdog", 6)]
    write_setting(study / "c1", "c1", rows, {"hotdog": DIAGNOSTIC})
    path = study / name
    if name.endswith("decisions.jsonl"):
        lines = path.read_text().splitlines(keepends=True)
        changed = {**rows[1], damage: "x" if damage == "gain" else None} if damage in ("gain", "terms") else None
        lines[1] = damage + "\n" if changed is None else json.dumps(changed) + "\n"
        path.write_text("".join(lines))
    else:
        path.write_text(damage if isinstance(damage, str) else json.dumps(damage))
    argv = [f"paths.results={tmp_path / 'results'}", "--records", str(tmp_path / "runs")]
    status, err = command("pipeline.experiments.visibility_summary", argv)
    assert status == 2 and len(err) == 1 and err[0].startswith(f"error: {study}/{line}"), err
    assert not (study / "summary.csv").exists()


def test_a_decisions_line_cut_by_a_kill_is_left_out_of_the_summary(tmp_path, command):
    study = tmp_path / "results" / "pilots" / "visibility_study"
    write_setting(study / "c1", "c1", [decision_row("hotdog", 0, 0.5), decision_row("hotdog", 3, 0.3)])
    (study / "c1" / "decisions.jsonl").write_text((study / "c1" / "decisions.jsonl").read_text() + '{"scene": "hot')
    status, err = command("pipeline.experiments.visibility_summary", [f"paths.results={tmp_path / 'results'}"])
    assert status == 0 and err == [] and list(summary_frame(study)["decisions"]) == [2]


def _study_folder(tmp_path: Path, overrides: list[str]) -> tuple[list[str], Path]:
    """A 3-step NVF record (smoke budget) and a study folder made with ``overrides`` whose state (default, seed 100,
    step 1) is measured already: a study run on it does no work. Returns the study's arguments and the folder."""
    from test_tables import make_run

    make_run(tmp_path / "runs", scene="default", seed=100, steps=3)
    folder = tmp_path / "results" / "pilots" / "visibility_study" / "s1"
    folder.mkdir(parents=True)
    (folder / "setting.json").write_text(json.dumps({"name": "s1", "overrides": overrides, "budget": "smoke"}))
    (folder / "decisions.jsonl").write_text(json.dumps(decision_row("default", 1)) + "\n")
    (folder / "default_diagnostic.json").write_text(json.dumps(DIAGNOSTIC))
    argv = ["budget=smoke", f"paths.results={tmp_path / 'results'}", "--setting", "s1", "--scenes", "default"]
    return [*argv, "--seeds", "100", "--steps", "1", "--sets", "1", "--records", str(tmp_path / "runs")], folder


@pytest.mark.parametrize(("made", "threads"), [(None, "2"), (2, "1")])
def test_a_study_folder_takes_rows_of_its_own_thread_count(tmp_path, command, monkeypatch, made, threads):
    """A study's numbers depend on its thread count: a folder made with one count (its setting's; one where the
    setting predates it, as the committed studies do) refuses another in one line naming both, before anything is
    written."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    argv, folder = _study_folder(tmp_path, ["budget=smoke"])
    if made is not None:
        setting = json.loads((folder / "setting.json").read_text()) | {"threads": made}
        (folder / "setting.json").write_text(json.dumps(setting))
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    status, err = command("pipeline.experiments.visibility_study", [*argv, "--threads", threads])
    assert status == 2 and len(err) == 1 and f"was made with --threads {made or 1}, not --threads {threads}" in err[0]
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == before


def test_a_study_refuses_a_bad_seed_and_a_bad_line_before_any_work(tmp_path, command):
    """The visibility study gave a traceback on a bad middle line of decisions.jsonl, and on
    ``--seeds -5`` after computing for minutes. Both are one line and exit 2 before any work."""
    argv, folder = _study_folder(tmp_path, ["budget=smoke"])
    status, err = command("pipeline.experiments.visibility_study", [*argv, "--seeds", "-5"])
    assert status == 2 and len(err) == 1 and "seed -5 is not an integer from 0 to 2^63-1" in err[0], err
    (folder / "decisions.jsonl").write_text(
        json.dumps(decision_row("default", 0)) + "\n{cut\n" + json.dumps(decision_row("default", 1)) + "\n"
    )
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    status, err = command("pipeline.experiments.visibility_study", argv)
    assert status == 2 and len(err) == 1 and err[0].startswith(f"error: {folder / 'decisions.jsonl'}: line 2"), err
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == before


def test_a_study_folder_takes_one_set_of_overrides_and_steps_the_record_holds(tmp_path, command):
    """``--setting s1`` run twice with other overrides appended rows of both settings to one folder
    and rewrote setting.json; ``--steps 50`` on a 3-step record wrote a "step 50" row. Both are refused in one line."""
    argv, folder = _study_folder(tmp_path, ["budget=smoke"])
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    status, err = command("pipeline.experiments.visibility_study", [*argv, "nvf.entropy.logdet_coeff=1.0"])
    assert status == 2 and len(err) == 1 and "holds a study made with the overrides ['budget=smoke']" in err[0], err
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == before
    (folder / "decisions.jsonl").write_text(json.dumps(decision_row("default", 50)) + "\n")
    status, err = command("pipeline.experiments.visibility_study", [*argv, "--steps", "50"])
    assert (
        status == 2
        and len(err) == 1
        and "--steps asks for step 50: the record" in err[0]
        and "holds steps 0 to 2" in err[0]
    )


def test_a_decisions_file_linked_elsewhere_is_neither_read_nor_appended_to(tmp_path, command):
    """A decisions.jsonl that is a symbolic link to a file outside the study was read and appended
    to. Now it is one line, exit 2, and the file it points to is unchanged."""
    argv, folder = _study_folder(tmp_path, ["budget=smoke"])
    outside = tmp_path / "elsewhere.jsonl"
    outside.write_text(json.dumps(decision_row("default", 1)) + "\n")
    (folder / "decisions.jsonl").unlink()
    (folder / "decisions.jsonl").symlink_to(outside)
    status, err = command("pipeline.experiments.visibility_study", argv)
    assert status == 2 and len(err) == 1 and err[0].startswith(f"error: {folder / 'decisions.jsonl'}: a symbolic link")
    assert outside.read_text() == json.dumps(decision_row("default", 1)) + "\n"


def test_a_study_never_reads_a_record_linked_from_outside_its_records(tmp_path, command):
    """A state's NVF record that is a symbolic link to a record outside ``--records`` was read as if it were one of
    them. Now it is one line naming the link's target, exit 2, and the study folder is unchanged."""
    argv, folder = _study_folder(tmp_path, ["budget=smoke"])
    record = tmp_path / "runs" / "default" / "nvf-argmax-none" / "smoke" / "seed_100"
    outside = tmp_path / "outside_seed_100"
    record.rename(outside)
    record.symlink_to(outside)
    before = {path.name: path.read_bytes() for path in folder.iterdir()}
    status, err = command("pipeline.experiments.visibility_study", argv)
    assert status == 2 and len(err) == 1 and f"{outside}, outside {tmp_path / 'runs'}" in err[0], err
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == before
