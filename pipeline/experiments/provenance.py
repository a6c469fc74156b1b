"""What a study row was made with (the duel's, the paper states', the visibility study's), and where its state
came from.

``made_with``: the checkout (commit and dirty flag), torch threads, the budget, every resolved config value the
command's overrides change in that budget (``differs_from_budget``: dotted key -> value, the ``paths`` group
left out) and the sizes its numbers depend on (``SIZES``: image and planning size, candidates, iterations, table
size, grid, label samples). ``source_record``: the identity of the record a state's views came from, by its
content (the digest of its ``run.json`` and ``steps.jsonl``, not its path) and the settings it was made with
(commit, dirty flag, threads, scene build, candidate count, planner, M29's line of sight).
"""

import hashlib
from pathlib import Path
from typing import Any

from pipeline.config.catalog import searchpath_override
from pipeline.config.validation import compose_run
from pipeline.records.checked_files import Anything, Entries, Flag, Number, Text
from pipeline.records.files import read_plain_file
from pipeline.records.store import MAX_RECORD_BYTES, git_state
from pipeline.repo import REPO

SIZES = {  # a row's name -> the config key it reads
    "image": "budget.image_size",
    "eval_image": "budget.eval_size",
    "planning": "planner.resolution",
    "candidates": "planner.num_candidates",
    "backbone_iters": "train.backbone.iters",
    "backbone_batch": "train.backbone.batch",
    "variance_iters": "train.variance.iters",
    "visibility_iters": "train.visibility.iters",
    "log2_table": "field.log2_hashmap_size",
    "grid": "sampler.grid_resolution",
    "label_samples": "train.label_samples",
    "label_lattice": "train.label_lattice",
}
MADE_WITH = {
    "commit": Text(null=True),
    "dirty": Flag(null=True),
    "threads": Number(1, 4096, integer=True),
    "budget": Text(),
    "ground_truth": Text(),
    "differs_from_budget": Entries(Anything()),
    "sizes": Entries(Number(0, 1 << 31, integer=True)),
}
SOURCE_RECORD = {
    "run": Text(),
    "digest": Text(),
    "commit": Text(null=True),
    "dirty": Flag(null=True),
    "threads": Number(1, 4096, integer=True, null=True),
    "scene_source": Text(null=True),
    "candidates": Number(0, 1 << 31, integer=True, null=True),
    "los_source": Text(null=True),
}


def flat(value: Any, prefix: str = "") -> dict[str, Any]:
    """A nested dict as dotted keys -> leaf values (lists are leaves)."""
    if not isinstance(value, dict):
        return {prefix: value}
    out: dict[str, Any] = {}
    for key, item in value.items():
        out |= flat(item, f"{prefix}.{key}" if prefix else str(key))
    return out


def checkout() -> dict:
    """The commit and dirty flag of the repository a command runs from, read once when it starts (before it writes
    its own files, which would make the checkout dirty)."""
    return git_state(REPO)


def made_with(git: dict, scene: str, budget: str, overrides: list[str], threads: int) -> dict:
    """The provenance of a row made from the checkout ``git`` (``checkout``) at ``budget`` on ``scene`` with
    ``overrides`` (a scene of the user's own found through their ``hydra.searchpath``)."""
    base = [f"scene={scene}", f"budget={budget}", *searchpath_override(overrides)]
    plain, run = compose_run(base), compose_run([*base, *overrides])
    before, after = flat(plain.composed), flat(run.composed)
    return {
        "commit": git["commit"],
        "dirty": git["dirty"],
        "threads": threads,
        "budget": budget,
        "ground_truth": str(run.render.backend),
        "differs_from_budget": {
            key: value
            for key, value in after.items()
            if not key.startswith("paths.") and (key not in before or before[key] != value)
        },
        "sizes": {name: int(run.setting(key)) for name, key in SIZES.items()},
    }


def record_digest_of(directory: Path) -> str:
    """``sha256:<hex>`` of a record's ``run.json`` and ``steps.jsonl`` bytes (a record's identity by content)."""
    digest = hashlib.sha256()
    for name in ("run.json", "steps.jsonl"):
        digest.update((read_plain_file(directory / name, MAX_RECORD_BYTES) or b"") + b"\0")
    return "sha256:" + digest.hexdigest()


def source_record(records: Path, directory: Path, info: dict) -> dict:
    """The identity and settings of the record at ``directory`` (below ``records``; ``info``: its run.json)."""
    config = info.get("config") or {}
    planner = config.get("planner") or {}
    git = info.get("git") or {}
    return {
        "run": directory.relative_to(records).as_posix(),
        "digest": record_digest_of(directory),
        "commit": git.get("commit"),
        "dirty": git.get("dirty"),
        "threads": info.get("torch_threads"),
        "scene_source": info.get("scene_source"),
        "candidates": planner.get("num_candidates"),
        "los_source": planner.get("los_source"),
    }
