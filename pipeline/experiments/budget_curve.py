"""``python -m pipeline.experiments.budget_curve [paths.results=DIR]``: the budget curve of the discrimination
experiments and the budget the selection rule picks from it.

Reads every ``${paths.results}/pilots/discriminate/<label>/summary.csv``
(``python -m pipeline.experiments.discriminate``) and writes beside them ``curve.csv`` (each label's rows
with ``label`` added), ``curve.png`` (each lead with its 95% interval against minutes per episode, one panel
per comparison) and ``choice.md``.

The rule (docs/BUDGETS.md): among the settings run on every scene of the experiment (hotdog, hubble,
default), the cheapest one where NVF beats both w/o Vis. and the best baseline with the paired 95%
interval above zero on at least two of the three scenes, within ``MAX_MINUTES`` per episode. Where none
does, the plain budget (the setting without overrides) stays, and the report names the setting with the
widest positive lead per minute (lead: the mean over scenes of NVF's smaller final-PSNR lead over the two)
as the nearest candidate, not as a choice: a lead the intervals do not establish picks nothing.

Each ``summary.csv`` is read back checked (``SUMMARY``'s columns; never through a symbolic link): one that fails
is one ``error:`` line naming the file, the row and the column, and nothing is written.
"""

import sys
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure

from pipeline.atomic_write import atomic_write_text
from pipeline.cli import fail, help_page, run_command
from pipeline.config.catalog import study_defaults
from pipeline.config.paths import paths_from_args
from pipeline.records.checked_files import read_csv
from pipeline.records.experiment_columns import DISCRIMINATE_SUMMARY_COLUMNS
from pipeline.records.files import check_directory, escaping_link
from pipeline.records.images import save_figure
from pipeline.tables.escape import as_csv
from pipeline.tables.table_formats import markdown_table

SCENES = tuple(study_defaults("budget_curve")["scenes"])  # conf/study/budget_curve.yaml
RULE_COMPARISONS = ("nvf-wo_vis", "nvf-best_baseline")
MAX_MINUTES = 15.0
SUMMARY = DISCRIMINATE_SUMMARY_COLUMNS  # a discrimination experiment's summary.csv, as its writer declares it


@dataclass(frozen=True)
class Setting:
    """One discrimination experiment's verdict under the rule."""

    label: str
    scenes: tuple[str, ...]
    minutes: float  # mean minutes per episode over its summary rows
    scenes_won: int  # scenes where every RULE_COMPARISONS interval lies above zero
    lead: float  # mean over scenes of the smaller RULE_COMPARISONS mean difference, dB

    @property
    def complete(self) -> bool:
        return set(SCENES) <= set(self.scenes)

    @property
    def meets_rule(self) -> bool:
        return self.complete and self.scenes_won >= 2 and self.minutes <= MAX_MINUTES


def read_curve(root: Path) -> pd.DataFrame:
    """Every ``<label>/summary.csv`` under ``root`` (``SUMMARY``'s columns checked; ``n`` a whole number, as
    written), with a ``label`` column."""
    paths = [path for path in sorted(root.glob("*/summary.csv")) if escaping_link(root, path.parent) is None]
    frames = [frame.assign(label=path.parent.name) for path in paths if (frame := read_csv(path, SUMMARY)) is not None]
    if not frames:
        fail(f"no {root}/<label>/summary.csv; run python -m pipeline.experiments.discriminate first")
    return pd.concat(frames, ignore_index=True).astype({"n": int})


def settings(curve: pd.DataFrame) -> list[Setting]:
    out = []
    for label, rows in curve.groupby("label", sort=True):
        rule = rows[rows["comparison"].isin(RULE_COMPARISONS)]
        per_scene = rule.groupby("scene")
        won = sum(len(g) == len(RULE_COMPARISONS) and bool((g["ci_low"] > 0).all()) for _, g in per_scene)
        leads = [g["mean_diff"].min() for _, g in per_scene if len(g) == len(RULE_COMPARISONS)]
        out.append(
            Setting(
                label=str(label),
                scenes=tuple(sorted(rows["scene"].unique())),
                minutes=float(rows["minutes_per_episode"].mean()),
                scenes_won=won,
                lead=float(sum(leads) / len(leads)) if leads else float("nan"),
            )
        )
    return out


def choose(candidates: list[Setting]) -> tuple[Setting | None, str]:
    """The rule's pick and why, in one sentence."""
    complete = [s for s in candidates if s.complete]
    if not complete:
        return None, f"no setting is measured on all of {', '.join(SCENES)}, so the rule picks none"
    meeting = [s for s in complete if s.meets_rule]
    if meeting:
        best = min(meeting, key=lambda s: s.minutes)
        return best, "the cheapest setting that meets the rule"
    positive = [s for s in complete if s.lead > 0]
    nearest = (
        f"; nearest: {widest.label}, the widest positive lead per minute ({widest.lead:+.2f} dB)"
        if (widest := max(positive, key=lambda s: s.lead / s.minutes, default=None))
        else "; none has a positive lead over both w/o Vis. and the best baseline"
    )
    plain = next((s for s in complete if "+" not in s.label), None)
    if plain is None:
        return None, "no setting meets the rule and the plain budget has not run" + nearest
    return plain, "no setting meets the rule, so the plain budget stays" + nearest


def plot(curve: pd.DataFrame) -> Figure:
    """One panel per comparison of the summaries (``pipeline.experiments.discriminate.COMPARISONS``), in their order."""
    comparisons = list(dict.fromkeys(curve["comparison"]))
    figure = Figure(figsize=(4.2 * len(comparisons), 3.6))
    axes = figure.subplots(1, len(comparisons), sharey=True, squeeze=False)[0]
    markers = {scene: "osD^v<>"[i % 7] for i, scene in enumerate(SCENES)}
    for ax, comparison in zip(axes, comparisons, strict=True):
        rows = curve[curve["comparison"] == comparison]
        for i, (label, group) in enumerate(rows.groupby("label", sort=True)):
            for _, row in group.iterrows():
                ax.errorbar(
                    row["minutes_per_episode"],
                    row["mean_diff"],
                    yerr=[[row["mean_diff"] - row["ci_low"]], [row["ci_high"] - row["mean_diff"]]],
                    fmt=markers.get(row["scene"], "^"),
                    color=f"C{i}",
                    capsize=3,
                    label=f"{label} / {row['scene']}",
                )
        ax.axhline(0.0, color="grey", linewidth=0.8)
        ax.set_title(comparison)
        ax.set_xlabel("minutes per episode")
    axes[0].set_ylabel("final PSNR difference, dB (95% CI)")
    axes[-1].legend(fontsize=6, loc="best")
    figure.tight_layout()
    return figure


def report(candidates: list[Setting], chosen: Setting | None, why: str) -> str:
    lines = [
        "# Budget curve",
        "",
        f"Rule: among settings measured on {', '.join(SCENES)}, the cheapest where NVF beats w/o Vis. and the best "
        f"baseline with the paired 95% interval above zero on at least two scenes, within {MAX_MINUTES:g} minutes per "
        "episode; else the widest positive lead per minute.",
        "",
        *markdown_table(
            ["setting", "scenes", "min/episode", "scenes won", "lead (dB)", "lead per minute"],
            [
                [
                    s.label,
                    ", ".join(s.scenes),
                    f"{s.minutes:.1f}",
                    s.scenes_won,
                    f"{s.lead:+.2f}",
                    f"{s.lead / s.minutes:+.3f}",
                ]
                for s in candidates
            ],
            left=2,
        ),
    ]
    verdict = f"Chosen: **{chosen.label}** ({why})." if chosen else f"Chosen: none ({why})."
    return "\n".join([*lines, "", verdict, ""])


def main(argv: list[str]) -> int:
    if any(arg in ("-h", "--help") for arg in argv):
        print(help_page(__doc__))
        return 0
    try:
        results = paths_from_args(argv, ("paths.results",))["results"]
    except ValueError as err:
        fail(str(err))
    root = results / "pilots" / "discriminate"
    check_directory(results, root)
    curve = read_curve(root)
    candidates = settings(curve)
    text = report(candidates, *choose(candidates))
    atomic_write_text(root / "curve.csv", as_csv(curve, ("scene", "comparison", "label")))
    save_figure(plot(curve), root / "curve.png")
    atomic_write_text(root / "choice.md", text)
    print(text, end="")
    print(f"pipeline.experiments.budget_curve: wrote {root / 'curve.csv'}, {root / 'curve.png'}, {root / 'choice.md'}")
    return 0


if __name__ == "__main__":
    run_command(main, sys.argv[1:])
