"""The budget curve and the selection rule of docs/BUDGETS.md (pipeline.experiments.budget_curve)."""

import pandas as pd
import pytest

from pipeline.experiments.budget_curve import main

SCENES = ("hotdog", "hubble", "default")


def write_summary(root, label, diffs, minutes, scenes=SCENES):
    """One experiment's summary.csv: ``diffs[comparison] = (mean, ci_low)`` on every scene."""
    rows = [
        {
            "scene": scene,
            "comparison": comparison,
            "mean_diff": mean,
            "ci_low": low,
            "ci_high": mean + 1.0,
            "n": 3,
            "minutes_per_episode": minutes,
        }
        for scene in scenes
        for comparison, (mean, low) in diffs.items()
    ]
    folder = root / "pilots" / "discriminate" / label
    folder.mkdir(parents=True)
    pd.DataFrame(rows).to_csv(folder / "summary.csv", index=False)


WIN = {"nvf-wo_vis": (0.8, 0.2), "nvf-ind_rays": (0.5, -0.1), "nvf-best_baseline": (1.0, 0.3)}
TIE = {"nvf-wo_vis": (0.3, -0.4), "nvf-ind_rays": (0.5, -0.1), "nvf-best_baseline": (0.6, -0.2)}
LOSE = {"nvf-wo_vis": (-0.5, -1.0), "nvf-ind_rays": (0.5, -0.1), "nvf-best_baseline": (-0.2, -0.9)}


def choice(tmp_path, capsys):
    assert main([f"paths.results={tmp_path}"]) == 0
    root = tmp_path / "pilots" / "discriminate"
    assert (root / "curve.png").stat().st_size > 0 and len(pd.read_csv(root / "curve.csv")) > 0
    return (root / "choice.md").read_text().splitlines()[-1]


def test_the_cheapest_setting_that_meets_the_rule_is_chosen(tmp_path, capsys):
    write_summary(tmp_path, "cpu", TIE, 5.0)
    write_summary(tmp_path, "slow_win", WIN, 14.0)
    write_summary(tmp_path, "fast_win", WIN, 9.0)
    write_summary(tmp_path, "too_slow_win", WIN, 20.0)
    assert choice(tmp_path, capsys) == "Chosen: **fast_win** (the cheapest setting that meets the rule)."


def test_a_setting_measured_on_fewer_scenes_cannot_be_chosen(tmp_path, capsys):
    write_summary(tmp_path, "cpu", LOSE, 10.0)
    write_summary(tmp_path, "hotdog_only", WIN, 5.0, scenes=("hotdog",))
    assert "**cpu**" in choice(tmp_path, capsys)


def test_without_a_winner_the_plain_budget_stays_and_the_nearest_is_named(tmp_path, capsys):
    write_summary(tmp_path, "cpu", TIE, 10.0)  # lead 0.3 dB: 0.030 per minute
    write_summary(tmp_path, "cpu+b=1", TIE | {"nvf-wo_vis": (0.5, -0.1)}, 12.0)  # lead 0.5: 0.042 per minute
    assert choice(tmp_path, capsys) == (
        "Chosen: **cpu** (no setting meets the rule, so the plain budget stays; nearest: cpu+b=1, the widest "
        "positive lead per minute (+0.50 dB))."
    )


def test_without_a_winner_or_a_plain_budget_nothing_is_chosen_and_it_says_so(tmp_path, capsys):
    write_summary(tmp_path, "cpu+a=1", LOSE, 12.0)
    write_summary(tmp_path, "cpu+a=2", LOSE, 6.0)
    line = choice(tmp_path, capsys)
    assert line.startswith("Chosen: none") and "none has a positive lead" in line


@pytest.mark.parametrize("argv", [["paths.outputs=x"], ["oops"]])
def test_bad_arguments_and_a_missing_curve_are_one_line_and_status_2(tmp_path, capsys, argv):
    for args in (argv, [f"paths.results={tmp_path}"]):
        with pytest.raises(SystemExit) as exit_:
            main(args)
        assert exit_.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1


CORRUPT = [
    ("not_a_number", lambda text: text.replace(",3,", ",many,", 1), "row 1, column n is 'many', not a number"),
    (
        "column_missing",
        lambda text: text.replace("minutes_per_episode", "minutes", 1),
        "lacks the column(s) minutes_per",
    ),
    ("infinite_minutes", lambda text: text.rsplit(",", 1)[0] + ",inf\n", "minutes_per_episode is inf, not a finite"),
    ("binary", lambda text: "\udcff\udcfe" * 8, "not UTF-8 text"),
]


@pytest.mark.parametrize(("case", "damage", "problem"), CORRUPT, ids=[c[0] for c in CORRUPT])
def test_a_corrupt_summary_is_one_line_and_nothing_is_written(tmp_path, command, case, damage, problem):
    """The budget curve on a corrupt summary.csv gave a traceback. Now the file is read back
    checked: one line naming the file, the row and the column, exit 2, no curve written."""
    write_summary(tmp_path, "cpu", WIN, 5.0)
    write_summary(tmp_path, "smoke", WIN, 1.0)
    path = tmp_path / "pilots" / "discriminate" / "smoke" / "summary.csv"
    path.write_bytes(damage(path.read_text()).encode("utf-8", "surrogateescape"))
    status, err = command("pipeline.experiments.budget_curve", [f"paths.results={tmp_path}"])
    assert status == 2 and len(err) == 1 and err[0].startswith(f"error: {path}: ") and problem in err[0], err
    assert not (tmp_path / "pilots" / "discriminate" / "curve.csv").exists()


def test_a_scene_a_spreadsheet_would_read_as_a_formula_is_written_as_text(tmp_path, capsys):
    write_summary(tmp_path, "cpu", WIN, 5.0, scenes=("=HYPERLINK(1)", *SCENES))
    assert main([f"paths.results={tmp_path}"]) == 0
    text = (tmp_path / "pilots" / "discriminate" / "curve.csv").read_text()
    assert "\n'=HYPERLINK(1),nvf-wo_vis," in text and "\n=" not in text
