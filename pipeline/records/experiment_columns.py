"""The columns of the experiments' CSV files, declared once: each file's columns in order, each with the shape its
values have (``pipeline.records.checked_files``: a ``Number`` range, a ``Text``). The experiment that writes a file
takes its columns from here, and whatever reads one back (another experiment, the results site) checks it against
the same declaration (``read_csv``; a reader that uses some columns only checks those, ``only``), so a column added,
renamed or given another range changes the writer and its readers together.

- ``DUEL_SUMMARY_COLUMNS``, ``DUEL_DETAIL_COLUMNS``: ``pilots/duel/summary.csv`` and ``details.csv``
  (``pipeline.experiments.duel_summary``; the site's duel page reads the summary);
- ``STUDY_SUMMARY_COLUMNS``, ``STUDY_SURFACE_COLUMNS``: ``pilots/visibility_study/summary.csv`` and ``surface.csv``
  (``pipeline.experiments.visibility_summary``);
- ``DISCRIMINATE_SUMMARY_COLUMNS``, ``DISCRIMINATE_PER_SEED_COLUMNS``: ``pilots/discriminate/<label>/summary.csv``
  and ``per_seed.csv`` (``pipeline.experiments.discriminate``; ``budget_curve`` reads the summaries, the visibility
  study's summary and the discrimination experiment against its plain budget read ``per_seed.csv``).

A column missing from the oldest files of its kind is ``Optional`` (read as empty). No heavy imports.
"""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pipeline.records.checked_files import Number, Optional, Text
from pipeline.records.schema import MAX_HORIZON
from pipeline.records.store import MAX_SEED

COUNT = Number(0, 2**31, integer=True)
SHARE = Number(0.0, 1.0, null=True)  # a fraction of decisions, states, sets or runs; empty where there is none
DB = Number(-100.0, 100.0, null=True)  # a PSNR difference in dB, or none
# A 95% Student-t bound over differences in [-100, 100] dB: at two values t = 12.7 times their spread, so up to
# about +-1400 dB; the writer's intervals are read back as it wrote them.
INTERVAL_DB = Number(-2000.0, 2000.0, null=True)
PSNR = Number(0.0, 100.0)
HOURS = Number(0.0, null=True)
AUC = Number(0.0, 1.0, null=True)
SPEARMAN = Number(-1.0, 1.0, null=True)

DUEL_MIN_SEEDS = 3  # a duel's row compares episodes only with this many paired seeds on every scene it covers
EPISODES_MISSING = (
    "An episodes cell reads '-' where the pair lacks finished episodes of both contenders for "
    f"{DUEL_MIN_SEEDS} seeds on every scene of its row (the committed records, --records)."
)
DUEL_SUMMARY_COLUMNS = {
    "method": Text(),
    "rival": Text(),
    "scene": Text(),
    "budget": Optional(Text(null=True)),  # the pair's (its setting's); empty in summaries made before it
    "n": COUNT,  # decisions whose picks differ
    "gain_mean": DB,  # the method's pick's held-out PSNR minus the rival's, over those n
    "ci_low": INTERVAL_DB,
    "ci_high": INTERVAL_DB,
    "same_pick": SHARE,
    "episode_diff": DB,  # the method's final PSNR minus the rival's in their episodes, paired by seed
    "episode_ci_low": INTERVAL_DB,
    "episode_ci_high": INTERVAL_DB,
    "cpu_hours": HOURS,  # the duel's own
}
TRANSFER_TABLE = Path("pilots", "paper_states", "transfer.csv")  # under paths.results: pipeline.experiments.transfer's
TRANSFER_COLUMNS = {  # TRANSFER_TABLE's (the site's pages and the duel's summary.md read it)
    "rival": Text(),
    "label": Text(),
    "states": COUNT,
    "paper_differ": COUNT,
    "paper_gain": DB,
    "paper_low": INTERVAL_DB,
    "paper_high": INTERVAL_DB,
    "cpu_differ": COUNT,
    "cpu_gain": DB,
    "cpu_low": INTERVAL_DB,
    "cpu_high": INTERVAL_DB,
    "sign_agrees": COUNT,
    "verdict": Text(),
}
DUEL_DETAIL_COLUMNS = {
    "method": Text(),
    "rival": Text(),
    "scene": Text(),
    "decisions": COUNT,
    "states": COUNT,
    "state_n": COUNT,  # states with a decision whose picks differ
    "state_gain_mean": DB,  # over the states' mean gains
    "state_ci_low": INTERVAL_DB,
    "state_ci_high": INTERVAL_DB,
    "source_pick_recorded": SHARE,
    "episode_n": COUNT,
    "episode_cpu_hours": HOURS,  # of the episodes compared
}

STUDY_SUMMARY_COLUMNS = {
    "setting": Text(),
    "scene": Text(),
    "visibility_source": Text(),
    "label_auc": AUC,  # the initial views' separation of seen from unseen object pixels
    "head_auc": AUC,
    "spearman_nvf_wo_vis": SPEARMAN,
    "onestep_gain_mean": DB,  # NVF's pick minus w/o Vis.'s in held-out PSNR where they differ
    "onestep_ci_low": INTERVAL_DB,
    "onestep_ci_high": INTERVAL_DB,
    "n": COUNT,
    "minutes_per_episode": Number(0.0, null=True),  # empty without a discrimination experiment of the setting
    "decisions": COUNT,
    "same_argmax_fraction": SHARE,
    "nvf_decisive_term": Text(null=True),
    "nvf_unknown_share": Number(null=True),  # of NVF's reward variance: a covariance ratio, may leave [0, 1]
    "nvf_tied_fraction": SHARE,
    "wo_vis_tied_fraction": SHARE,
}
STUDY_SURFACE_COLUMNS = {
    "scene": Text(),
    "step": Number(0, MAX_HORIZON, integer=True),
    "nvf_vis_area": SHARE,  # the area-weighted share of the surface the training views see, mean over seeds
    "wo_vis_vis_area": SHARE,
    "random_vis_area": SHARE,
    "nvf_minus_wo_vis": Number(-1.0, 1.0, null=True),
    "ci_low": Number(-100.0, 100.0, null=True),
    "ci_high": Number(-100.0, 100.0, null=True),
    "n": COUNT,
}

DISCRIMINATE_SUMMARY_COLUMNS = {
    "scene": Text(),
    "comparison": Text(),  # nvf-wo_vis, nvf-ind_rays, nvf-best_baseline
    "mean_diff": DB,  # final PSNR, paired by seed; an interval of one seed is empty
    "ci_low": DB,
    "ci_high": DB,
    "n": COUNT,
    "minutes_per_episode": Number(0.0),
}
DISCRIMINATE_PER_SEED_COLUMNS = {
    "scene": Text(),
    "method": Text(),
    "ablation": Text(),
    "seed": Number(0, MAX_SEED, integer=True),
    "final_psnr": PSNR,
    "mean_psnr": PSNR,  # over the steps
    "minutes": Number(0.0),  # the steps' train + eval + plan seconds
    "spearman": SPEARMAN,  # mean rank agreement with diagnostics.rank_against, where recorded
    "same_choice": SHARE,
    "flat_steps": Optional(SHARE),  # not in the oldest files
}


def only(columns: Mapping[str, Any], *names: str) -> dict[str, Any]:
    """The declared ``columns`` named ``names``, in that order: what a reader that uses only those checks."""
    return {name: columns[name] for name in names}
