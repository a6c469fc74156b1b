"""The discrimination experiment (``pipeline.experiments.discriminate``): paired differences and their Student-t
intervals, the best-baseline choice, the summary's columns, and bad input."""

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from pipeline.experiments import discriminate
from pipeline.experiments.discriminate import SUMMARY_COLUMNS, compare, mean_spearman
from pipeline.tables.escape import as_csv
from pipeline.tables.stats import Interval


def test_interval_is_the_paired_student_t_interval():
    diffs = np.array([1.0, 2.0, 4.0])
    interval = Interval.of(diffs)
    half = stats.t.ppf(0.975, 2) * np.std(diffs, ddof=1) / math.sqrt(3)
    assert interval.n == 3 and interval.mean == pytest.approx(7 / 3)
    assert interval.low == pytest.approx(7 / 3 - half) and interval.high == pytest.approx(7 / 3 + half)
    assert interval.low < 0 < interval.high  # 3 seeds: a spread this wide does not establish a lead
    one = Interval.of(np.array([0.5, math.nan]))
    assert one.n == 1 and one.mean == 0.5 and math.isnan(one.low) and math.isnan(one.high)


def test_an_interval_as_text_and_whether_it_excludes_zero():
    """The text the tables and the site show, and the mark: below zero counts as above does; undefined never."""
    assert Interval(0.214, 0.012, 0.418, 5).text() == "+0.21 [+0.01, +0.42]"
    assert Interval(0.214, 0.012, 0.418, 5).excludes_zero and Interval(-0.3, -0.5, -0.1, 5).excludes_zero
    assert not Interval(0.1, -0.2, 0.4, 5).excludes_zero and not Interval(0.5, math.nan, math.nan, 1).excludes_zero
    assert Interval(0.5, math.nan, math.nan, 1).text() == "+0.50" and Interval(*[math.nan] * 3, 0).text() == "-"


def runs_frame() -> pd.DataFrame:
    """Two scenes, three seeds; NVF 1 dB over w/o Vis. on every seed; NeurAR the better baseline on 'a'."""
    rows = []
    psnr = {
        ("nvf", "none"): 20.0,
        ("nvf", "wo_vis"): 19.0,
        ("nvf", "ind_rays"): 19.5,
        ("wd", "none"): 17.0,
        ("activenerf", "none"): 18.0,
        ("neurar", "none"): 18.5,
    }
    for scene in ("a", "b"):
        for (method, ablation), value in psnr.items():
            for seed, noise in zip((100, 101, 102), (0.0, 0.3, -0.3), strict=True):
                rows.append(
                    {
                        "scene": scene,
                        "method": method,
                        "ablation": ablation,
                        "seed": seed,
                        "final_psnr": value + noise * (method == "neurar"),
                        "mean_psnr": value - 2.0,
                        "minutes": 5.0 + (method == "nvf"),
                        "spearman": math.nan,
                        "same_choice": math.nan,
                    }
                )
    return pd.DataFrame(rows)


def test_compare_pairs_seeds_and_picks_the_best_baseline():
    details = compare(runs_frame())
    final = details[details["measure"] == "final_psnr"].set_index(["scene", "comparison"])
    assert final.loc[("a", "nvf-wo_vis"), "mean_diff"] == pytest.approx(1.0)
    assert final.loc[("a", "nvf-wo_vis"), "ci_low"] == pytest.approx(1.0)  # identical differences: no spread
    assert final.loc[("a", "nvf-best_baseline"), "against"] == "neurar-none"
    assert final.loc[("a", "nvf-best_baseline"), "mean_diff"] == pytest.approx(1.5)
    assert (final["n"] == 3).all() and final.loc[("b", "nvf-best_baseline"), "minutes_per_episode"] == pytest.approx(
        5.5
    )
    summary = details.loc[details["measure"] == "final_psnr", list(SUMMARY_COLUMNS)]
    assert list(summary.columns) == [
        "scene",
        "comparison",
        "mean_diff",
        "ci_low",
        "ci_high",
        "n",
        "minutes_per_episode",
    ]
    assert set(summary["comparison"]) == {"nvf-wo_vis", "nvf-ind_rays", "nvf-best_baseline"}


def test_a_missing_seed_is_left_out_of_the_pairing():
    runs = runs_frame()
    runs = runs[~((runs["method"] == "wd") | ((runs["ablation"] == "wo_vis") & (runs["seed"] == 101)))]
    final = compare(runs).query("measure == 'final_psnr'").set_index(["scene", "comparison"])
    assert final.loc[("a", "nvf-wo_vis"), "n"] == 2 and final.loc[("a", "nvf-ind_rays"), "n"] == 3


@pytest.mark.parametrize(
    "argv, says",
    [
        (["method=wd"], "experiment's own"),
        (["--seeds", "x"], "--seeds"),
        (["--jobs", "0"], "--jobs 0: must be 1.."),
        (["--jobs", "4097"], "--jobs 4097: must be 1.."),
    ],
)
def test_bad_input_is_one_line_and_status_2(argv, says, capsys):
    with pytest.raises(SystemExit) as info:
        discriminate.main(argv)
    err = capsys.readouterr().err
    assert info.value.code == 2 and len(err.strip().splitlines()) == 1 and says in err


def test_its_csv_files_write_a_name_a_spreadsheet_would_read_as_a_formula_as_text():
    runs = runs_frame().replace({"scene": {"a": "=HYPERLINK(1)"}, "method": {"wd": "@wd"}})
    for frame in (runs, compare(runs)):
        text = as_csv(frame, discriminate.TEXT)
        assert "'=HYPERLINK(1)," in text and "\n=" not in text
    assert ",'@wd," in as_csv(runs, discriminate.TEXT)


def test_entries_a_setting_cannot_change_are_reused_not_rerun(tmp_path):
    """``nvf.entropy.logdet_coeff=1.0`` acts on NVF and its ablations, not on the baselines: their label stays the
    plain budget's, and their finished plain-budget records are reused; sweeps record PSNR alone before the
    last step, and only NVF's sweep measures w/o Vis.'s ranking."""
    overrides = ["budget=smoke", "nvf.entropy.logdet_coeff=1.0"]
    labels = discriminate.entry_labels(overrides)
    assert labels[("wd", "none")] == labels[("neurar", "none")] == "smoke"
    assert labels[("nvf", "none")] == labels[("nvf", "wo_vis")] == "smoke+nvf.entropy.logdet_coeff=1.0"
    for seed in (100, 101):  # finished as committed records are: run.json says so (no DONE marker)
        done = discriminate.run_dir(tmp_path, "hotdog", "wd", "argmax", "none", "smoke", seed)
        done.mkdir(parents=True)
        (done / "run.json").write_text('{"status": "done"}')
    assert discriminate.reusable(tmp_path, ("wd", "none"), "smoke", "smoke", "hotdog", (100, 101))
    assert not discriminate.reusable(tmp_path, ("wd", "none"), "smoke", "smoke", "hotdog", (100, 101, 102))
    assert not discriminate.reusable(tmp_path, ("nvf", "none"), labels[("nvf", "none")], "smoke", "hotdog", (100,))
    commands = discriminate.sweep_commands(
        overrides, [("hotdog", ("nvf", "none")), ("hotdog", ("wd", "none"))], (100,), tmp_path, 2
    )
    assert all("step_metrics=psnr" in c for c in commands)
    assert ["diagnostics.rank_against=wo_vis" in c for c in commands] == [True, False]


def test_mean_spearman_leaves_out_steps_where_the_rival_score_was_flat():
    """A rival score constant over the candidates (w/o Vis. with c = 1 on Hubble) has no rank correlation: the
    step records None, which the mean leaves out instead of failing on it."""
    steps = [{"spearman": 0.5, "same_choice": True}, {"spearman": None, "same_choice": False}, {"spearman": 0.7}]
    assert mean_spearman(steps) == pytest.approx(0.6)
    assert math.isnan(mean_spearman([{"spearman": None}])) and math.isnan(mean_spearman([]))


def test_a_summary_without_nvf_runs_is_one_line_and_status_2(tmp_path, monkeypatch, capsys):
    """Only the reused baselines found (e.g. --summarize-only without paths.outputs=DIR of the runs): one line,
    not a KeyError from an empty comparison."""
    baselines = runs_frame().query("method != 'nvf'")
    monkeypatch.setattr(discriminate, "per_seed", lambda *args: baselines)
    with pytest.raises(SystemExit) as info:
        discriminate.summarize([tmp_path], tmp_path, "cpu", {}, "argmax", ("a", "b"), (100, 101, 102))
    err = capsys.readouterr().err
    assert info.value.code == 2 and len(err.strip().splitlines()) == 1 and "paths.outputs=DIR" in err
    assert not any(tmp_path.iterdir())


def test_flat_steps_count_the_steps_where_every_candidate_tied():
    steps = [{"candidate_scores": {"count": 4, "ties_at_max": t}} for t in (4, 1, 4, 2)]
    assert discriminate.flat_steps(steps) == 0.5
    assert math.isnan(discriminate.flat_steps([{"candidate_scores": {"count": 4}}]))  # made before ties were recorded
    assert math.isnan(discriminate.flat_steps([{"candidate_scores": None}]))  # Random: no scores


def test_against_plain_pairs_each_entry_the_setting_acts_on_with_the_plain_budgets_run():
    """A setting that leaves NVF as it was and makes w/o Vis. 1 dB worse says so entry by entry; the baselines,
    which it cannot change (their records are the plain budget's), are left out."""
    plain = runs_frame().assign(flat_steps=math.nan)
    setting = plain.copy()
    wo_vis = setting["ablation"] == "wo_vis"
    setting.loc[wo_vis, "final_psnr"] -= 1.0
    setting["flat_steps"] = np.where(wo_vis, 0.25, 0.0)
    changes = discriminate.against_plain(setting, plain, [("nvf", "none"), ("nvf", "wo_vis"), ("nvf", "ind_rays")])
    final = changes[changes["measure"] == "final_psnr"].set_index(["scene", "entry"])
    assert set(final.index.get_level_values("entry")) == {"nvf-none", "nvf-wo_vis", "nvf-ind_rays"}
    assert (
        final.loc[("a", "nvf-wo_vis"), "mean_diff"] == pytest.approx(-1.0)
        and final.loc[("a", "nvf-none"), "mean_diff"] == 0
    )
    assert final.loc[("a", "nvf-wo_vis"), "flat_steps"] == 0.25 and math.isnan(
        final.loc[("a", "nvf-wo_vis"), "plain_flat_steps"]
    )
    lines = discriminate.against_plain_markdown("cpu", changes)
    assert any(
        line.startswith("| a | nvf-wo_vis | -1.00 [-1.00, -1.00]") and line.endswith("| 0.25 | - |") for line in lines
    )


@pytest.mark.parametrize("label", ["../../../../escaped", "/tmp/nvf-bench-escaped", "a/b", ".."])
def test_a_label_is_a_plain_name(tmp_path, monkeypatch, capsys, label):
    """A ``--label`` climbing out of its folder (four ``..``) or an absolute path wrote the
    experiment's csv and md files outside ``paths.results``. A label is checked as a run key is: one line, status 2,
    nothing written."""
    monkeypatch.setattr(discriminate, "per_seed", lambda *args: runs_frame())
    results = tmp_path / "deep" / "er" / "results"
    argv = ["--summarize-only", "--reuse", "none", "--label", label, f"paths.results={results}"]
    with pytest.raises(SystemExit) as info:
        discriminate.main([*argv, f"paths.outputs={tmp_path / 'out'}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert info.value.code == 2 and len(err) == 1 and f"option --label={label!r} is not a plain name" in err[0]
    assert list(tmp_path.iterdir()) == [] and not Path("/tmp/nvf-bench-escaped").exists()
