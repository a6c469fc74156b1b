"""pipeline/experiments/duel.py, decisions.py and duel_summary.py: paired one-step decisions between two methods
on the states of their recorded episodes, and the duel's tables."""

import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from nvf.cameras import matrix_to_pose
from pipeline.cli import run_command
from pipeline.config.validation import compose_run
from pipeline.episode import shared_training
from pipeline.episode.loop import Episode
from pipeline.episode.runner import run_episode
from pipeline.episode.settings import EpisodeSettings
from pipeline.experiments import decisions, duel, duel_summary, row_files
from pipeline.metrics.image import LpipsMetric
from pipeline.records.checked_files import Number, Text
from pipeline.records.experiment_columns import TRANSFER_TABLE
from pipeline.records.files import RecordError
from pipeline.records.lock import RunLock
from pipeline.records.store import RunRecord, run_dir
from pipeline.scenes.loading import load_scene
from pipeline.tables.site import DUEL_COLUMNS

SMOKE = ["budget=smoke", "scene=default"]
REPO = Path(__file__).resolve().parents[1]


def test_contenders_are_methods_or_nvf_ablations():
    assert decisions.contender("wd") == decisions.Contender("wd", "wd", "none")
    assert decisions.contender("wo_vis") == decisions.Contender("wo_vis", "nvf", "wo_vis")
    assert decisions.contender("wo_vis").overrides == ["method=nvf", "ablation=wo_vis"]
    for bad, says in (("none", "unknown contender"), ("bogus", "conf/method"), ("../x", "plain name")):
        with pytest.raises(ValueError, match=says):
            decisions.contender(bad)


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["method=nvf"], "name both contenders"),
        (["method=nvf", "rival=bogus"], "unknown contender 'bogus'"),
        (["method=nvf", "rival=wd/../x"], "not a plain name"),
        (["method=nvf", "rival=wd", "seed=3"], "seed=3: the contenders and states are the duel's own"),
        (["method=nvf", "rival=wd", "ablation=wo_vis"], "ablation=wo_vis"),
        (["method=nvf", "rival=wd", "--steps", "0,x"], "--steps: '0,x'"),
        (["method=nvf", "rival=wd", "planner=opt"], "argmax"),
        (["method=nvf", "rival=wd,nvf"], "rival=nvf: a contender against itself"),
        (["method=nvf", "rival=wd", "--sets", "0"], "--sets 0: must be 1..64"),
        (["method=nvf", "rival=wd", "--sets", "99999999999999999999"], "--sets 99999999999999999999"),
        (["method=nvf", "rival=wd", "--threads", "4097"], "--threads 4097: must be 1.."),
        (["method=nvf", "rival=wd", "--scenes", "default", "--records", "/nonexistent"], "no usable record of"),
        (
            [
                "method=nvf",
                "rival=wd",
                "--scenes",
                "default",
                "--steps",
                "25",
                "--records",
                "results/runs",
                "budget=cpu",
            ],
            "--steps asks for step 25",
        ),
    ],
)
def test_bad_input_is_one_line(argv, says, capsys, tmp_path):
    with pytest.raises(SystemExit) as exit_:
        duel.main([*argv, f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.startswith("error: ") and says in err and err.count("\n") == 1
    assert not (tmp_path / "pilots").exists()  # nothing written


def settings_of(name: str, *overrides: str) -> EpisodeSettings:
    who = decisions.contender(name)
    cfg = compose_run([*SMOKE, *who.overrides, *overrides])
    return EpisodeSettings.of(cfg, load_scene(cfg.scene, Path(cfg.paths.assets)))


def test_contenders_share_a_model_where_their_training_agrees():
    """A plan serves another when its stages begin with the other's: NVF's (backbone, variance, visibility)
    serves WD's, FisherRF's and Random's (backbone, no auxiliary loss) and w/o Vis.'s (backbone, variance: the
    head it skips comes last), not ActiveNeRF's (its backbone trains with M25); a shorter plan serves no longer
    one, and with the visibility head trained first w/o Vis. trains it too and shares again."""
    plans = {name: shared_training.training_plan(settings_of(name)) for name in ("nvf", "wd", "fisherrf", "random")}
    plans |= {name: shared_training.training_plan(settings_of(name)) for name in ("activenerf", "wo_vis")}
    for name in ("wd", "fisherrf", "random", "wo_vis", "nvf"):
        assert shared_training.serves(plans["nvf"], plans[name]), name
    assert not shared_training.serves(plans["nvf"], plans["activenerf"])
    assert not shared_training.serves(plans["activenerf"], plans["wd"])
    assert not shared_training.serves(plans["wd"], plans["nvf"])
    vis_first = [
        shared_training.training_plan(settings_of(n, "train.stage_order=vis_first")) for n in ("nvf", "wo_vis")
    ]
    assert shared_training.serves(vis_first[0], vis_first[1])
    other_seed = shared_training.training_plan(settings_of("wd", "seed=7"))
    assert not shared_training.serves(plans["nvf"], other_seed)


@pytest.mark.parametrize("rival", ["wd", pytest.param("fisherrf", marks=pytest.mark.slow)])
def test_a_shared_model_is_bitwise_the_model_of_the_shorter_training(rival):
    """NVF's training trains the rival's model on the way: the rival's own training gives the same backbone and
    occupancy grid bit for bit, and its scores of the same candidates are equal on both models."""
    quick = ["train.backbone.iters=8", "train.variance.iters=2", "train.visibility.iters=2"]
    cfg = compose_run([*SMOKE, *quick])
    scene = load_scene(cfg.scene, Path(cfg.paths.assets))
    lpips = LpipsMetric()
    episodes = {name: Episode(settings_of(name, *quick), scene, torch.device("cpu"), lpips) for name in ("nvf", rival)}
    try:
        obs = episodes["nvf"].observations()
        trained = shared_training.train_models(episodes, obs, 2)
        assert trained["nvf"] is trained[rival]
        own, _ = episodes[rival].train(obs, 2)
        shared = trained["nvf"].model
        heads = {id(p) for group in ("variance", "visibility") for p in shared.field.parameter_groups()[group]}
        state = {n: p for n, p in shared.named_parameters() if id(p) not in heads} | dict(shared.named_buffers())
        theirs = dict(own.named_parameters()) | dict(own.named_buffers())
        assert any("grid" in name for name in state)
        for name, value in state.items():
            assert torch.equal(value, theirs[name]), name
        variance = zip(*(m.field.parameter_groups()["variance"] for m in (shared, own)), strict=True)
        assert not all(torch.equal(a, b) for a, b in variance)  # NVF's variance head is trained, the rival's not
        candidates = decisions.candidate_set(episodes["nvf"], shared, 2, 1)[:4]
        episode = episodes[rival]
        scores = [
            decisions.pick(episode, m, decisions.prepared_scorer(episode, m, obs, 2), candidates, 2, 1).scores
            for m in (shared, own)
        ]
        np.testing.assert_array_equal(scores[0], scores[1])
    finally:
        for episode in episodes.values():
            episode.close()


def test_a_backbone_trained_with_an_auxiliary_loss_serves_the_plan_without_it():
    """ActiveNeRF's M25 trains only the variance head beside stage 1: NVF's model continued from ActiveNeRF's
    backbone (its variance head reset, the generator where stage 1 left it) is bitwise NVF's own model, and
    ActiveNeRF's is bitwise its own; stage 1 ran once."""
    quick = ["train.backbone.iters=8", "train.variance.iters=2", "train.visibility.iters=2"]
    cfg = compose_run([*SMOKE, *quick])
    scene = load_scene(cfg.scene, Path(cfg.paths.assets))
    lpips = LpipsMetric()
    names = ("nvf", "activenerf", "wo_vis")
    episodes = {name: Episode(settings_of(name, *quick), scene, torch.device("cpu"), lpips) for name in names}
    try:
        obs = episodes["nvf"].observations()
        trained = shared_training.train_models(episodes, obs, 2)
        assert trained["activenerf"].continuation is not None and trained["nvf"].continuation is None
        assert trained["wo_vis"] is trained["nvf"]
        for name in ("nvf", "activenerf"):
            own, _ = episodes[name].train(obs, 2)
            ours = trained[name].model
            theirs = dict(own.named_parameters()) | dict(own.named_buffers())
            for key, value in (dict(ours.named_parameters()) | dict(ours.named_buffers())).items():
                assert torch.equal(value, theirs[key]), (name, key)
    finally:
        for episode in episodes.values():
            episode.close()


def test_json_lines_keep_whole_rows_and_drop_a_cut_one(tmp_path):
    path = tmp_path / "decisions.jsonl"
    shape = {"scene": Text(), "step": Number(0, 20, integer=True)}
    first, second = row_files.JsonLines(path, shape), row_files.JsonLines(path, shape)
    first.add([{"scene": "hotdog", "step": 0, "spearman": math.nan}])
    second.add([{"scene": "hubble", "step": 0}, {"scene": "hubble", "step": 3}])
    path.write_text(path.read_text() + '{"scene": "hub')
    reopened = row_files.JsonLines(path, shape)
    assert [(r["scene"], r["step"]) for r in reopened.rows] == [("hotdog", 0), ("hubble", 0), ("hubble", 3)]
    assert reopened.rows[0]["spearman"] is None and path.read_text().endswith("\n")


def test_a_second_setting_under_the_same_folder_is_refused(tmp_path, capsys):
    folder = tmp_path / "pilots" / "duel" / "nvf_vs_wd"
    folder.mkdir(parents=True)
    (folder / "setting.json").write_text(json.dumps({"method": "nvf", "overrides": ["budget=smoke"]}))
    with pytest.raises(SystemExit) as exit_:
        duel.main(["method=nvf", "rival=wd", "budget=cpu", "--scenes", "default", f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "holds a duel with overrides ['budget=smoke']" in err and err.count("\n") == 1
    assert sorted(p.name for p in folder.iterdir()) == ["setting.json"]


def test_a_committed_pair_resumes_with_its_thread_count_and_refuses_another(tmp_path, capsys, monkeypatch):
    """A committed pair folder (its setting predates the thread count; its rows say 1) resumes with ``--threads 1``:
    a state it holds is not decided again and nothing is written to it. Another count is one line naming both,
    before anything is written, as is another count than a setting records."""
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1, 2, 3})
    folder = tmp_path / "pilots" / "duel" / "nvf_vs_wd"
    shutil.copytree(Path("results/pilots/duel/nvf_vs_wd"), folder)
    files = {path.name: path.read_bytes() for path in folder.iterdir()}
    argv = ["method=nvf", "rival=wd", "budget=cpu", "--scenes", "default", "--seeds", "100", "--steps", "0"]
    argv += [f"paths.results={tmp_path}"]
    duel.main([*argv, "--threads", "1"])
    assert "step 0" not in capsys.readouterr().out
    assert {path.name: path.read_bytes() for path in folder.iterdir() if path.name != ".locks"} == files
    for threads, made in (("2", None), ("1", 2)):
        if made is not None:
            setting = json.loads(files["setting.json"]) | {"threads": made}
            (folder / "setting.json").write_text(json.dumps(setting))
        before = {path.name: path.read_bytes() for path in folder.iterdir() if path.is_file()}
        with pytest.raises(SystemExit) as exit_:
            duel.main([*argv, "--threads", threads])
        err = capsys.readouterr().err
        assert exit_.value.code == 2 and err.count("\n") == 1
        assert f"was made with --threads {made or 1}, not --threads {threads}" in err
        assert {path.name: path.read_bytes() for path in folder.iterdir() if path.is_file()} == before


def test_a_duel_refused_by_another_writer_writes_no_setting_or_command(tmp_path, capsys):
    """The setting and the command are written under the pair's lock once its scene and seed are held: a duel
    refused because another process holds them leaves neither behind."""
    folder = tmp_path / "pilots" / "duel" / "nvf_vs_wd"
    argv = ["method=nvf", "rival=wd", "budget=cpu", "--scenes", "default", "--seeds", "100", "--steps", "0"]
    with RunLock(folder / "default" / "seed_100", folder), pytest.raises(SystemExit) as exit_:
        run_command(duel.main, [*argv, f"paths.results={tmp_path}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "is being written by" in err and err.count("\n") == 1
    assert sorted(p.name for p in folder.iterdir()) == [".locks"]


def write_episode(root: Path, method: str, seed: int, final_psnr: float, seconds: float, scene: str = "hotdog") -> None:
    """A finished two-step smoke record on ``scene`` ending at ``final_psnr``, each step taking ``seconds``."""
    record = RunRecord(run_dir(root, scene, method, "argmax", "none", "smoke", seed))
    keys = {"scene": scene, "method": method, "planner": "argmax", "ablation": "none", "budget": "smoke"}
    info = {**keys, "seed": seed, "scene_source": "mesh", "field": "hashgrid", "torch_threads": 2}
    record.start(info | {"config": {"budget": {"horizon": 2}}}, repo=root)
    for step, value in enumerate((10.0, final_psnr)):
        row = {"step": step, "n_views": 3 + step, "status": "ok", "metrics": {"psnr": value}}
        record.append_step(row | {"selected_pose": [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 2.0], "seconds": {"train": seconds}})
    record.mark_done()


def decision(step: int, gain: float | None, shared: bool = False, recorded: bool | None = None) -> dict:
    seconds = {"train": 100.0, "prepare": 10.0, "score": 20.0} | ({"outcome": 30.0} if gain is not None else {})
    row = {"scene": "hotdog", "seed": 100, "step": step, "same_pick": gain is None, "shared_training": shared}
    row |= {"threads": 1, "seconds": {"method": seconds, "rival": seconds}, "source_pick_recorded": recorded}
    return row | ({"gain": gain} if gain is not None else {})


def test_summary_pairs_decisions_and_episodes(tmp_path):
    """summary.csv's columns; the gain's interval over the decisions whose picks differ; the state interval
    over per-state means; the episodes' final PSNR paired by seed (3 seeds) and their cpu hours; the duel's
    cpu hours counting a state's training once (twice when not shared) and each decision's outcomes; the
    summary's counts of rows separated, signs agreeing and the cost ratio."""
    root, records = tmp_path / "duel", tmp_path / "runs"
    for seed, lead in ((100, 0.5), (101, 0.7), (102, 0.9)):
        write_episode(records, "nvf", seed, 20.0 + lead, 60.0)
        write_episode(records, "wd", seed, 20.0, 30.0)
    folder = root / "nvf_vs_wd"
    folder.mkdir(parents=True)
    contenders = {n: {"method": n, "ablation": "none"} for n in ("nvf", "wd")}
    setting = {"method": "nvf", "rival": "wd", "overrides": ["budget=smoke"], "budget": "smoke"}
    (folder / "setting.json").write_text(json.dumps(setting | {"contenders": contenders}))
    rows = [decision(0, 0.2, recorded=True), decision(0, 0.4), decision(3, None, True, False), decision(3, 0.9, True)]
    (folder / "decisions.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows) + '{"cut')
    paths = duel_summary.write_summaries(root, records)
    summary = duel_summary.pd.read_csv(paths[0])
    assert tuple(summary.columns) == duel_summary.COLUMNS == tuple(DUEL_COLUMNS)  # the site reads what this writes
    assert list(summary["scene"]) == ["hotdog", "all"]
    row, details = summary.iloc[0], duel_summary.pd.read_csv(paths[1]).iloc[0]
    assert row["n"] == 3 and row["gain_mean"] == pytest.approx(0.5) and row["same_pick"] == 0.25
    half = 4.302653 * np.std([0.2, 0.4, 0.9], ddof=1) / math.sqrt(3)  # t(0.975, 2) s / sqrt(3)
    assert row["ci_low"] == pytest.approx(0.5 - half, rel=1e-3)
    assert row["episode_diff"] == pytest.approx(0.7) and row["episode_ci_low"] > 0
    # states: step 0 trains both (200 s) and step 3 once (100 s), each +20 s preparing; 4 rows x 40 s scoring;
    # 3 rows x 60 s of outcomes
    assert row["cpu_hours"] == pytest.approx((220 + 120 + 160 + 180) / 3600, rel=1e-3)
    assert details["states"] == 2 and details["state_n"] == 2 and details["state_gain_mean"] == pytest.approx(0.6)
    assert details["episode_cpu_hours"] == pytest.approx(3 * 2 * (120 + 60) / 3600, rel=1e-3)
    assert details["source_pick_recorded"] == 0.5  # of the states' set-0 rows
    text = paths[2].read_text()
    assert "**+0.70 [" in text and "the duel separates 0 and the episodes 1" in text
    assert "same sign in 1 of 1" in text and "cpu hours 1.6 times the duel's" in text  # 3 x 2 x 180 s / 680 s
    write_episode(records, "wd", 103, 20.0, 30.0)  # a seed NVF lacks is not paired
    assert duel_summary.pd.read_csv(duel_summary.write_summaries(root, records)[0]).iloc[0]["episode_diff"] == 0.7
    for seed in (101, 102):
        shutil.rmtree(run_dir(records, "hotdog", "wd", "argmax", "none", "smoke", seed))
    assert math.isnan(duel_summary.tables(root, records)[0].iloc[0]["episode_diff"])  # one seed in common


def test_pooled_rows_cover_the_scenes_every_pair_holds(tmp_path):
    """scene=all pools the same scenes for every pair: a scene only one pair holds (Room beside the three every
    pair has) is its own row there and stays out of that pair's pooled row, and summary.md says so."""
    root, records = tmp_path / "duel", tmp_path / "runs"
    for scene in ("hotdog", "room"):
        for method in ("nvf", "wd", "fvs"):
            write_episode(records, method, 100, 20.0, 30.0, scene)
    contenders = {n: {"method": n, "ablation": "none"} for n in ("nvf", "wd", "fvs", "air")}
    decided = {"wd": [("hotdog", 0, 0.2)], "fvs": [("hotdog", 0, 0.2), ("room", 0, 0.2), ("room", 3, 1.0)]}
    for rival, made in decided.items():
        folder = root / f"nvf_vs_{rival}"
        folder.mkdir(parents=True)
        setting = {"method": "nvf", "rival": rival, "overrides": ["budget=smoke"], "budget": "smoke"}
        (folder / "setting.json").write_text(json.dumps(setting | {"contenders": contenders}))
        rows = [decision(step, gain) | {"scene": scene} for scene, step, gain in made]
        (folder / "decisions.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (root / "nvf_vs_air").mkdir()  # a pair just started, no decisions yet: it pools nothing away
    (root / "nvf_vs_air" / "setting.json").write_text(
        json.dumps({"method": "nvf", "rival": "air", "overrides": [], "budget": "smoke", "contenders": contenders})
    )
    summary = duel_summary.tables(root, records)[0].set_index(["rival", "scene"])
    assert summary.loc[("fvs", "room"), "n"] == 2 and summary.loc[("fvs", "all"), "n"] == 1
    assert summary.loc[("fvs", "all"), "gain_mean"] == pytest.approx(0.2) == summary.loc[("wd", "all"), "gain_mean"]
    text = duel_summary.write_summaries(root, records)[2].read_text()
    assert "Rows `all` pool hotdog, the scenes every pair holds; room in per-scene rows only." in text
    assert "| not measured |" in text and "| hotdog | smoke | 1 |" in text  # no transfer table yet


def test_the_summary_says_which_verdicts_hold_at_the_papers_scale(tmp_path):
    """summary.md's rows over the scenes carry the transfer table's verdict for their rival ("not measured" for a
    rival the paper states lack); a scene's row carries none."""
    root, records = tmp_path / "pilots" / "duel", tmp_path / "runs"
    contenders = {n: {"method": n, "ablation": "none"} for n in ("nvf", "wd", "fvs")}
    for rival in ("wd", "fvs"):
        write_episode(records, rival, 100, 20.0, 30.0)
        folder = root / f"nvf_vs_{rival}"
        folder.mkdir(parents=True)
        setting = {"method": "nvf", "rival": rival, "overrides": ["budget=smoke"], "budget": "smoke"}
        (folder / "setting.json").write_text(json.dumps(setting | {"contenders": contenders}))
        (folder / "decisions.jsonl").write_text(json.dumps(decision(0, 0.2)) + "\n")
    write_episode(records, "nvf", 100, 21.0, 60.0)
    transfer = {"states": 5, "paper_differ": 3, "paper_gain": -0.2, "paper_low": -0.4, "paper_high": -0.05}
    transfer |= {"cpu_differ": 2, "cpu_gain": 0.2, "cpu_low": 0.1, "cpu_high": 0.3, "sign_agrees": 1}
    (tmp_path / TRANSFER_TABLE).parent.mkdir(parents=True)
    duel_summary.pd.DataFrame([transfer | {"rival": "wd", "label": "WD", "verdict": "flips"}]).to_csv(
        tmp_path / TRANSFER_TABLE, index=False
    )
    lines = duel_summary.write_summaries(root, records)[2].read_text().splitlines()
    rows = {tuple(cell.strip() for cell in line.split("|")[2:4]): line for line in lines if line.startswith("| NVF")}
    assert rows[("WD", "all")].endswith("| flips |") and rows[("FVS", "all")].endswith("| not measured |")
    assert rows[("WD", "hotdog")].endswith("| - |")


def test_the_summary_refuses_what_it_cannot_pair(tmp_path):
    """A pair folder without its setting, a setting naming no contender, a wrong --records (none there, or none of
    the contenders whose records gave the states) and a linked pair folder are each one RecordError (never a blank
    column or a vanished pair); a text cell that a spreadsheet would read as a formula is written as text."""
    root, records = tmp_path / "duel", tmp_path / "runs"
    for seed in (100, 101, 102):
        write_episode(records, "nvf", seed, 21.0, 60.0)
        write_episode(records, "wd", seed, 20.0, 30.0)
    folder = root / "nvf_vs_wd"
    folder.mkdir(parents=True)
    (folder / "decisions.jsonl").write_text(json.dumps(decision(0, 0.2) | {"source": "=HYPERLINK(1)"}) + "\n")
    with pytest.raises(RecordError, match="setting.json: missing or incomplete"):
        duel_summary.write_summaries(root, records)
    contenders = {"nvf": {"method": "nvf", "ablation": "none"}}
    setting = {"method": "nvf", "rival": "=HYPERLINK(1)", "overrides": [], "budget": "smoke"}
    (folder / "setting.json").write_text(json.dumps(setting | {"contenders": contenders}))
    with pytest.raises(RecordError, match="names no contender '=HYPERLINK"):
        duel_summary.write_summaries(root, records)
    contenders["=HYPERLINK(1)"] = {"method": "wd", "ablation": "none"}
    (folder / "setting.json").write_text(json.dumps(setting | {"contenders": contenders}))
    with pytest.raises(RecordError, match="--records .*: no run records there"):
        duel_summary.write_summaries(root, tmp_path / "nowhere")
    paths = duel_summary.write_summaries(root, records)
    assert "'=HYPERLINK(1)" in paths[0].read_text() and ",=HYPERLINK" not in paths[0].read_text()
    other = tmp_path / "other"  # records, but not those of the pair's states: refused, not blank columns
    write_episode(other, "nvf", 100, 21.0, 60.0)
    with pytest.raises(RecordError, match=r"--records .*other: no episode of =HYPERLINK\(1\) on hotdog at budget"):
        duel_summary.write_summaries(root, other)
    (folder / "decisions.jsonl").write_text(json.dumps(decision(0, 0.2) | {"source": "nvf"}) + "\n")
    assert math.isnan(duel_summary.tables(root, other)[0].iloc[0]["episode_diff"])  # the states' records are there
    (root / "linked").symlink_to(folder)
    with pytest.raises(RecordError, match="a link"):
        duel_summary.write_summaries(root, records)


def test_the_summary_never_reads_a_record_through_a_link_leaving_records(tmp_path):
    """An episode record linked from outside ``--records`` is one RecordError naming the link, never a record the
    columns are computed from; a link staying inside ``--records`` is read."""
    root, records, outside = tmp_path / "duel", tmp_path / "runs", tmp_path / "elsewhere"
    for seed in (100, 101, 102):
        write_episode(records, "nvf", seed, 21.0, 60.0)
        write_episode(records if seed != 102 else outside, "wd", seed, 20.0, 30.0)
    folder = root / "nvf_vs_wd"
    folder.mkdir(parents=True)
    contenders = {n: {"method": n, "ablation": "none"} for n in ("nvf", "wd")}
    setting = {"method": "nvf", "rival": "wd", "overrides": [], "budget": "smoke", "contenders": contenders}
    (folder / "setting.json").write_text(json.dumps(setting))
    (folder / "decisions.jsonl").write_text(json.dumps(decision(0, 0.2)) + "\n")
    link = run_dir(records, "hotdog", "wd", "argmax", "none", "smoke", 102)
    link.symlink_to(run_dir(outside, "hotdog", "wd", "argmax", "none", "smoke", 102))
    with pytest.raises(RecordError, match=f"{link} is a symbolic link to .*, outside {records}"):
        duel_summary.write_summaries(root, records)
    link.unlink()
    shutil.move(run_dir(outside, "hotdog", "wd", "argmax", "none", "smoke", 102), records / "kept")
    link.symlink_to(records / "kept")  # inside --records: read as usual
    assert duel_summary.tables(root, records)[0].iloc[0]["episode_diff"] == pytest.approx(1.0)


def test_the_duel_never_reads_through_a_link_leaving_its_folders(tmp_path, capsys):
    """A state's record linked from outside ``--records``, and a pair folder linked from elsewhere under
    ``pilots/duel`` (whose ``outcomes.jsonl`` a duel of the same setting would reuse), are each one ``error:`` line
    and exit 2 before anything is written."""
    records = tmp_path / "runs"
    source = Path("results/runs/default/nvf-argmax-none/cpu/seed_100").resolve()
    run_dir(records, "default", "nvf", "argmax", "none", "cpu", 100).parent.mkdir(parents=True)
    run_dir(records, "default", "nvf", "argmax", "none", "cpu", 100).symlink_to(source)
    argv = ["method=nvf", "rival=wd", "budget=cpu", "--scenes", "default", "--seeds", "100", "--steps", "0"]
    results = tmp_path / "results"
    with pytest.raises(SystemExit) as exit_:
        run_command(duel.main, [*argv, "--records", str(records), f"paths.results={results}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and f"{source}, outside {records}" in err
    assert not results.exists()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "setting.json").write_text(json.dumps({"method": "nvf", "overrides": ["budget=cpu"]}))
    (results / "pilots" / "duel").mkdir(parents=True)
    (results / "pilots" / "duel" / "nvf_vs_fisherrf").symlink_to(elsewhere)
    with pytest.raises(SystemExit) as exit_:
        run_command(duel.main, [*argv, "--records", "results/runs", f"paths.results={results}"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1 and "nvf_vs_fisherrf: a link" in err
    assert sorted(p.name for p in (results / "pilots" / "duel").iterdir()) == ["nvf_vs_fisherrf"]


def test_the_summary_reads_the_committed_records_from_any_folder(tmp_path, monkeypatch):
    """``--records`` defaults to the repository's ``results/runs`` wherever the command runs: a committed pair's
    rows come out as committed, episode columns included, from a folder holding no records."""
    committed = Path("results/pilots/duel").resolve()
    shutil.copytree(committed / "nvf_vs_wo_vis", tmp_path / "pilots" / "duel" / "nvf_vs_wo_vis")
    monkeypatch.chdir(tmp_path)
    duel_summary.main([f"paths.results={tmp_path}"])
    rows = [line for line in (committed / "summary.csv").read_text().splitlines() if line.startswith("nvf,wo_vis,")]
    assert (tmp_path / "pilots" / "duel" / "summary.csv").read_text().splitlines()[1:] == rows and len(rows) == 4


def test_one_step_outcome_of_a_pick():
    """``with_view`` adds the ground truth at a pose to the observations; ``heldout_psnr`` trains the plain
    backbone as the next step would (same seed: the same PSNR twice) and measures it on the evaluation views."""
    cfg = compose_run(["budget=smoke", "train.backbone.iters=5"])
    scene = load_scene(cfg.scene, Path(cfg.paths.assets))
    episode = Episode(EpisodeSettings.of(cfg, scene), scene, torch.device("cpu"), LpipsMetric())
    try:
        obs = episode.observations()
        pose = matrix_to_pose(scene.eval_poses[0].to(torch.float32))
        more = decisions.with_view(obs, episode, pose)
        assert more.num_images == obs.num_images + 1
        torch.testing.assert_close(more.c2w[-1], scene.eval_poses[0].to(torch.float32), atol=1e-5, rtol=0)
        first, _ = decisions.heldout_psnr(episode, more, 1)
        again, _ = decisions.heldout_psnr(episode, more, 1)
        assert math.isfinite(first) and first == again
    finally:
        episode.close()


@pytest.fixture(scope="module")
def smoke_records(tmp_path_factory) -> Path:
    """Two-step smoke episodes of NVF, ActiveNeRF and WD (seed 100) on the default scene."""
    outputs = tmp_path_factory.mktemp("records")
    for method in ("nvf", "activenerf", "wd"):
        cfg = compose_run([*SMOKE, "budget.horizon=2", f"method={method}", f"paths.outputs={outputs}"])
        run_episode(cfg)
    return outputs


def read(folder: Path) -> list[dict]:
    return [json.loads(line) for line in (folder / "decisions.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_duel_on_smoke_records_resumes_after_a_kill(smoke_records, tmp_path, capsys):
    """NVF against ActiveNeRF (trained apart), WD (sharing NVF's model) and itself on steps 0 and 1 of seed 100
    (step 0 from NVF's record, step 1 from the rival's), 2 sets each; then a kill-like cut of one folder's last
    state: the same command measures that state alone and writes the same rows."""
    argv = ["method=nvf", "rival=activenerf,wd", "budget=smoke", f"paths.results={tmp_path}", "--scenes"]
    argv += ["default", "--seeds", "100", "--steps", "0,1", "--records", str(smoke_records)]
    duel.main(argv)
    root = tmp_path / "pilots" / "duel"
    rows = {rival: read(root / f"nvf_vs_{rival}") for rival in ("activenerf", "wd")}
    for rival, found in rows.items():
        assert [(r["step"], r["set"], r["source"]) for r in found] == [
            (0, 0, "nvf"), (0, 1, "nvf"), (1, 0, rival), (1, 1, rival)
        ]  # fmt: skip
        assert all(r["source_pick_recorded"] for r in found if r["set"] == 0)
        for r in found:
            assert r["made_with"]["budget"] == "smoke" and r["made_with"]["threads"] == 1
            assert r["source_record"]["run"].startswith("default/") and r["source_record"]["digest"].startswith(
                "sha256:"
            )
            assert r["same_pick"] == (r["method_pick"] == r["rival_pick"])
            assert r["same_pick"] or (math.isfinite(r["gain"]) and r["gain"] == r["method_psnr"] - r["rival_psnr"])
    assert not any(r["shared_training"] for r in rows["activenerf"])
    assert all(r["shared_training"] for r in rows["wd"])
    summary = duel_summary.pd.read_csv(root / "summary.csv")
    assert tuple(summary.columns) == duel_summary.COLUMNS
    capsys.readouterr()
    folder = root / "nvf_vs_activenerf"
    lines = (folder / "decisions.jsonl").read_text().splitlines(keepends=True)
    (folder / "decisions.jsonl").write_text("".join(lines[:2]) + lines[2][:40])  # killed while writing step 1
    duel.main(argv)
    out = capsys.readouterr().out
    assert "step 0" not in out and "step 1 (activenerf's state): activenerf:" in out

    def without_seconds(found):
        return [{k: v for k, v in r.items() if k != "seconds"} for r in found]

    assert without_seconds(read(folder)) == without_seconds(rows["activenerf"])
    lines = (folder / "decisions.jsonl").read_text().splitlines(keepends=True)
    (folder / "decisions.jsonl").write_text("".join(lines[:3]))  # killed between the two rows of step 1's state
    capsys.readouterr()
    duel.main(argv)
    assert "step 1 (activenerf's state)" in capsys.readouterr().out
    assert without_seconds(read(folder)) == without_seconds(rows["activenerf"])  # set 1 decided again, alone
    with RunLock(folder / "default" / "seed_100", folder), pytest.raises(SystemExit) as exit_:
        run_command(duel.main, argv)  # a second duel on the same pair, scene and seed
    assert exit_.value.code == 2 and "is being written by" in capsys.readouterr().err
    pair = row_files.JsonLines(folder / "decisions.jsonl", decisions.DECISION, decisions.decision_key)
    with pytest.raises(RecordError, match="already holds the row"):
        pair.add([pair.rows[0]])
    (folder / "decisions.jsonl").write_text("".join(lines[:3] + lines[:1]))
    with pytest.raises(RecordError, match="repeats the row"):
        duel.main(argv)


def test_states_can_come_from_records_of_another_budget(tmp_path, monkeypatch, capsys):
    """``--state-budget cpu``: the committed cpu episodes' states (here step 2 of seed 100 on the default scene,
    NVF's record, found by the default ``--records`` from any folder), trained and scored at the run's budget
    (smoke here, the paper's in use); the setting says so, and the threads. ``--sets 3`` on the folder made with
    ``--sets 2`` decides the new set alone, and both commands are in ``command.txt``."""
    monkeypatch.chdir(tmp_path)
    argv = ["method=nvf", "rival=wd", "budget=smoke", "--state-budget", "cpu", "--scenes", "default"]
    argv += ["--seeds", "100", "--steps", "2", f"paths.results={tmp_path}"]
    duel.main([*argv, "--sets", "2"])
    folder = tmp_path / "pilots" / "duel" / "nvf_vs_wd"
    rows = read(folder)
    assert [(r["step"], r["set"], r["source"], r["candidates"]) for r in rows] == [(2, 0, "nvf", 8), (2, 1, "nvf", 8)]
    assert json.loads((folder / "setting.json").read_text()) | {"contenders": None} == {
        "method": "nvf", "overrides": ["budget=smoke"], "budget": "smoke", "threads": 1, "state_budget": "cpu",
        "rival": "wd", "contenders": None,
    }  # fmt: skip
    capsys.readouterr()
    duel.main([*argv, "--sets", "3"])
    assert "step 2 (nvf's state): wd: " in capsys.readouterr().out
    assert read(folder)[:2] == rows and [(r["step"], r["set"]) for r in read(folder)[2:]] == [(2, 2)]
    commands = (folder / "command.txt").read_text().splitlines()
    assert [line.split()[-1] for line in commands] == ["2", "3"] and len(commands) == 2
    with pytest.raises(SystemExit):
        duel.main(["method=nvf", "rival=wd", "budget=smoke", "--state-budget", "bogus", f"paths.results={tmp_path}/o"])


def test_nvf_duels_coverage_and_laplace_on_the_same_states(tmp_path, monkeypatch):
    """``rival=fvs,bayesrays`` (METHOD 18 and 19, not in the paper): both decide from NVF's state (step 2 of seed
    100's committed cpu record, smoke's training) and its candidate sets, each pair in its own folder; FVS trains
    nothing, so it shares NVF's model and picks by the distance to the observed views."""
    monkeypatch.chdir(tmp_path)
    argv = ["method=nvf", "rival=fvs,bayesrays", "budget=smoke", "--state-budget", "cpu", "--scenes", "default"]
    duel.main([*argv, "--seeds", "100", "--steps", "2", "--sets", "1", f"paths.results={tmp_path}"])
    folders = {rival: tmp_path / "pilots" / "duel" / f"nvf_vs_{rival}" for rival in ("fvs", "bayesrays")}
    rows = {rival: read(folder) for rival, folder in folders.items()}
    assert {rival: [(r["step"], r["source"], r["candidates"]) for r in found] for rival, found in rows.items()} == {
        "fvs": [(2, "nvf", 8)],
        "bayesrays": [(2, "nvf", 8)],
    }
    assert rows["fvs"][0]["method_pick"] == rows["bayesrays"][0]["method_pick"]  # one NVF, one candidate set
    for row in (*rows["fvs"], *rows["bayesrays"]):
        assert 0 <= row["rival_pick"] < row["candidates"]
        assert ("gain" in row) == (row["method_pick"] != row["rival_pick"])


def test_a_state_is_never_taken_from_a_record_made_on_another_build_of_its_scene(tmp_path, capsys):
    """A record whose run.json says it was made on another build of the scene (here ``scene_source: mesh`` for
    the procedural default scene; Room's OBJ against its .blend in practice) is one ``error:`` line naming
    both and scene.asset, exit 2: its views are not replayed on this build (``decisions.recorded_steps``)."""
    source = Path("results/runs_superseded/default/nvf-argmax-none/cpu/seed_100")  # from before records' digests
    copy = run_dir(tmp_path, "default", "nvf", "argmax", "none", "cpu", 100)
    shutil.copytree(source, copy)
    scene = load_scene("default")
    assert len(decisions.recorded_steps(tmp_path, "default", decisions.contender("nvf"), 100, "cpu", 2, scene).rows) > 2
    info = json.loads((copy / "run.json").read_text())
    (copy / "run.json").write_text(json.dumps(info | {"scene_source": "mesh"}))
    with pytest.raises(SystemExit) as exit_:
        decisions.recorded_steps(tmp_path, "default", decisions.contender("nvf"), 100, "cpu", 2, scene)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and err.count("\n") == 1
    assert "scene source (mesh in the record, procedural now); set scene.asset" in err


def test_the_help_gives_every_default_and_steps_follow_the_states_budget(capsys):
    """``--help`` gave no default for ``--steps`` and ``--sets``, and the default steps (0..18) did not fit smoke
    records (3 steps); the default is now every third step the states' records hold."""
    with pytest.raises(SystemExit):
        duel.main(["--help"])
    text = " ".join(capsys.readouterr().out.split()).split("options:")[1]
    for option in ("--scenes", "--seeds", "--steps", "--sets", "--records", "--state-budget", "--threads"):
        assert re.search(re.escape(option) + r" [A-Z_]+ [^(]*\(default", text), option
    with pytest.raises(SystemExit) as exit_:  # a smoke duel on the committed cpu records: the cpu budget's steps
        duel.main(
            [
                "method=nvf",
                "rival=wd",
                "budget=smoke",
                "--state-budget",
                "cpu",
                "--scenes",
                "default",
                "--seeds",
                "100",
                "--records",
                "/nonexistent",
            ]
        )
    assert exit_.value.code == 2 and "no usable record" in capsys.readouterr().err


def test_a_fan_out_unit_is_the_studys_own_command_on_one_scene_and_seed():
    """pipeline.experiments.fan_out: each study that fans out is one nvf-bench knows by the same module; a unit's
    command is the study's with its scene and seed; a study without units, or args naming the unit's own options,
    is one line."""
    from pipeline import commands
    from pipeline.experiments import fan_out

    known = {name: module for name, (module, _) in (commands.COMMANDS | commands.STUDIES).items()}
    assert all(known[name] == module for name, module in fan_out.UNITS.items())
    command = fan_out.unit_command("duel", "hotdog", 101, ["method=nvf", "rival=fvs", "--steps", "0,3"])
    assert command[1:] == ["-m", "pipeline.experiments.duel", "method=nvf", "rival=fvs", "--steps", "0,3"] + [
        "--scenes", "hotdog", "--seeds", "101"
    ]  # fmt: skip
    with pytest.raises(ValueError, match="not one that fans out; choose one of duel"):
        fan_out.unit_command("tables", "hotdog", 100, [])
    with pytest.raises(ValueError, match="--seeds=100 is the unit's own; sweep scene= and seed= instead"):
        fan_out.unit_command("duel", "hotdog", 100, ["--seeds=100"])


@pytest.mark.slow
def test_a_duel_fans_out_over_seeds_through_hydras_joblib_launcher(tmp_path):
    """Two seeds' smoke records of NVF and WD; ``fan_out -m study=duel seed=100,101`` with the joblib launcher runs
    a duel per seed side by side into one pair folder, and reports both units done."""
    records = tmp_path / "records"
    for method in ("nvf", "wd"):
        for seed in (100, 101):
            run_episode(
                compose_run(
                    [*SMOKE, "budget.horizon=2", f"method={method}", f"seed={seed}", f"paths.outputs={records}"]
                )
            )
    study_args = ["method=nvf", "rival=wd", "budget=smoke", f"paths.results={tmp_path}", "--steps", "0"]
    args = "args=[" + ",".join(f'"{arg}"' for arg in [*study_args, "--records", str(records)]) + "]"
    found = subprocess.run(
        [sys.executable, "-m", "pipeline.experiments.fan_out", "-m", "study=duel", "scene=default", "seed=100,101"]
        + [args, "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", f"paths.outputs={tmp_path / 'outputs'}"],
        cwd=REPO,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        capture_output=True,
        text=True,
    )
    assert found.returncode == 0, found.stderr[-2000:]
    assert "sweep: 2 jobs: 2 done, 0 skipped, 0 failed" in found.stdout + found.stderr
    rows = read(tmp_path / "pilots" / "duel" / "nvf_vs_wd")
    assert sorted({(r["seed"], r["step"]) for r in rows}) == [(100, 0), (101, 0)]
